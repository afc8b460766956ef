"""`write_reports`: a run folder's figures, report.md and report.html, from a `pipeline.RunResult`."""

from __future__ import annotations

import json
import logging
from pathlib import Path

from ..config import Config
from ..uq import predictive as pv
from ..uq.table5 import table5
from .content import run_document, title
from .figures import make_figures
from .files import write_text
from .html import render_html
from .markdown import render_markdown

log = logging.getLogger(__name__)


def run_table5s(result, cfg: Config) -> tuple[list[dict], list[str]]:
    """Table 5 for every method with a predictor when the truth is known; notes for those left out."""
    if result.truth is None:
        return [], []
    out, notes = [], []
    for key in pv.with_predictor(result.posteriors):
        try:
            out.append(table5(result, cfg, key))
        except Exception as exc:  # the table is an extra: never lose the report for it
            log.warning(
                "warning: Table 5 for %s failed and is left out: %s: %s",
                key,
                type(exc).__name__,
                exc,
            )
            notes.append(f"Table 5 for {key} left out: {type(exc).__name__}: {exc}.")
    return out, notes


#: the run folder's Table 5 metrics in SI units (written when the truth is known), so that a study can
#: collect them without inferring again (a PINN's network is not stored)
TABLE5_FILE = "table5.json"
TABLE5_SCHEMA = "bayespinn.run_table5/1"


def write_table5_json(folder: Path, result, t5s: list[dict]) -> Path:
    from ..uq.posterior import jsonable

    s = result.summary
    doc = {
        "schema": TABLE5_SCHEMA,
        "case": s.get("case"),
        "snr_db": s.get("snr_db"),
        "seed": s.get("seed"),
        "profile": s.get("profile"),
        "methods": {t5["method"]: t5 for t5 in t5s},
    }
    return write_text(folder / TABLE5_FILE, json.dumps(jsonable(doc), indent=2) + "\n")


def write_reports(
    result, cfg: Config, folder: str | Path, *, figures: bool = True
) -> dict[str, Path]:
    """Write the figures (PNG), report.md and report.html into `folder`.

    A figure or table that fails is logged as a warning and left out, with a note in the reports.
    Returns the paths written, by kind ('report.md', 'report.html', and each figure's file name).
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    figs, fig_notes = make_figures(result, cfg, folder) if figures else ([], [])
    t5s, t5_notes = run_table5s(result, cfg)
    blocks = run_document(result, cfg, figs, fig_notes, t5s, t5_notes)
    if t5s:
        write_table5_json(folder, result, t5s)
    write_text(folder / "report.md", render_markdown(blocks))
    write_text(folder / "report.html", render_html(blocks, folder, title(result.summary)))
    paths = {f.name: folder / f.name for f in figs}
    paths.update({"report.md": folder / "report.md", "report.html": folder / "report.html"})
    if t5s:
        paths["table5.json"] = folder / TABLE5_FILE
    return paths
