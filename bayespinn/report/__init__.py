"""Reports: read posteriors and write documents and figures. Never trains.

- `write_reports(result, cfg, folder)`: a run folder's figures, report.md and report.html;
- `write_sweep_reports(doc, results, out)`: the sweep's Table 4 report and its figure;
- `table5(result, cfg, method)`: the paper's Table 5 with uncertainty (and `table5_markdown`);
- `agreement(methods)`: PINN posteriors against the modal reference.
"""

from ..uq.agreement import agreement
from .table5 import table5, table5_markdown
from .writer import write_reports

__all__ = ["agreement", "table5", "table5_markdown", "write_reports", "write_sweep_reports"]


def write_sweep_reports(doc, results, out):
    """See `bayespinn.report.sweep.write_sweep_reports`."""
    from .sweep import write_sweep_reports as w

    return w(doc, results, out)
