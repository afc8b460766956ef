"""`sweep`: `run` at several SNR levels and one combined report (the paper's Table 4 with intervals).

The levels are independent tasks of the run's executor (`RunOptions.executor`: the local process pool by
default, or Ray), each writing its own run folder; inside a level everything runs in that one worker
(an ensemble's members one after another, one thread), so a level's result is the same whichever executor
ran it and with any number of workers. The combined report is written once all levels are back.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, replace
from pathlib import Path

from .config import Config, snr_label
from .data.measurements import atomic_write_text
from .options import RunOptions
from .pipeline import RunResult, run
from .uq.posterior import jsonable

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Level:
    """One sweep level: a full `run` into its own folder."""

    cfg: Config
    snr_db: float | None
    methods: tuple[str, ...]
    seed: int
    out: Path
    opts: RunOptions


def run_level(task: Level) -> RunResult:
    log.info("sweep: SNR %s", snr_label(task.snr_db))
    return run(
        task.cfg,
        methods=list(task.methods),
        snr_db=task.snr_db,
        seed=task.seed,
        out=task.out,
        opts=task.opts,
    )


def sweep(
    cfg: Config, *, levels: list, methods: list[str], seed: int, out: Path, opts: RunOptions
) -> dict:
    """Run every level into out/snr<level>/ (levels spread over `opts.executor`), then write sweep.json and
    the combined reports."""
    from .executor import Executor, task_resources

    out = Path(out)
    executor = opts.executor or Executor()
    inner = replace(opts, executor=Executor("local", workers=1), progress=False)
    tasks = [
        Level(cfg, snr, tuple(methods), seed, out / f"snr{snr_label(snr)}", inner) for snr in levels
    ]
    results = executor.map(
        run_level,
        tasks,
        desc="sweep levels",
        progress=opts.progress,
        resources=task_resources(opts.device),
    )
    entries = [
        {"snr_db": t.snr_db, "folder": t.out.name, "methods": r.summary["methods"]}
        for t, r in zip(tasks, results, strict=True)
    ]
    doc = {"schema": "bayespinn.sweep/1", "case": cfg.case, "seed": seed, "levels": entries}
    from .report.sweep import write_sweep_reports

    write_sweep_reports(doc, results, out, cfg=cfg)
    atomic_write_text(out / "sweep.json", json.dumps(jsonable(doc), indent=2) + "\n")
    return doc
