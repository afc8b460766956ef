"""Reports: read posteriors and write documents and figures. Never trains."""

from .markdown import write_reports

__all__ = ["write_reports"]
