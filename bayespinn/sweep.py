"""`sweep`: `run` at several SNR levels and one combined report (the paper's Table 4 with intervals)."""

from __future__ import annotations

import json
import logging
from pathlib import Path

from .config import Config, snr_label
from .data.measurements import atomic_write_text
from .pipeline import run
from .uq.methods import RunOptions
from .uq.posterior import jsonable

log = logging.getLogger(__name__)


def sweep(cfg: Config, *, levels: list, methods: list[str], seed: int, out: Path, opts: RunOptions) -> dict:
    """Run every level into out/snr<level>/, then write sweep.json and the combined reports."""
    out = Path(out)
    entries = []
    results = []
    for snr in levels:
        folder = f"snr{snr_label(snr)}"
        log.info("sweep: SNR %s", snr_label(snr))
        res = run(cfg, methods=methods, snr_db=snr, seed=seed, out=out / folder, opts=opts)
        results.append(res)
        entries.append({"snr_db": snr, "folder": folder, "methods": res.summary["methods"]})
    doc = {"schema": "bayespinn.sweep/1", "case": cfg.case, "seed": seed, "levels": entries}
    from .report.sweep import write_sweep_reports

    write_sweep_reports(doc, results, out, cfg=cfg)
    atomic_write_text(out / "sweep.json", json.dumps(jsonable(doc), indent=2) + "\n")
    return doc
