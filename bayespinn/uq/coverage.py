"""Posterior coverage: does a central `level` interval hold the true EI that often?

Each replicate draws fresh sample points and noise (and, for simulation-based calibration, a fresh
true EI from the prior), runs one method, and records whether the interval holds the truth and the
rank of the truth among the posterior draws. Replicates are seeded by index, so the result does not
depend on the executor or the number of workers.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np
from scipy import stats

from .. import seeding
from ..config import Config
from ..data.synthetic import simulate
from ..executor import Executor, task_resources
from .methods import KEYS, RunOptions, infer


@dataclass(frozen=True)
class Replicate:
    """One coverage task (picklable)."""

    index: int
    method: str
    cfg: Config
    snr_db: float | None
    seed: int
    level: float
    truth: str  # 'fixed' or 'prior'
    opts: RunOptions


def run_replicate(task: Replicate) -> dict:
    """Simulate one dataset, infer, and score the interval against the truth."""
    seq = seeding.child(task.seed, "coverage", task.index)
    cfg = task.cfg
    if task.truth == "prior":
        from .priors import EIPrior

        ei = float(EIPrior.from_spec(cfg.prior).sample(np.random.default_rng(seeding.stream(seq, "init"))))
        cfg = dataclasses.replace(cfg, beam=dataclasses.replace(cfg.beam, EI=ei))
    data = simulate(cfg, task.snr_db, seq)
    post = infer(task.method, data, cfg, seq, task.opts)
    true = cfg.beam.EI
    lo, hi = post.interval(task.level)
    d = post.EI.ravel()
    return {
        "index": task.index,
        "EI_true": true,
        "hit": bool(lo <= true <= hi),
        "interval": [lo, hi],
        "rank": float(np.mean(d < true)),
        "rel_error_pct": float(100 * (d.mean() - true) / true),
        "sd_rel_pct": float(100 * d.std(ddof=1) / true),
        "converged": bool(post.diagnostics.get("converged", True)),
    }


def clopper_pearson(k: int, n: int, conf: float = 0.95) -> tuple[float, float]:
    """Exact binomial confidence interval for a proportion k/n."""
    a = 1 - conf
    lo = 0.0 if k == 0 else float(stats.beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(stats.beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi


def binomial_acceptance(n: int, level: float, false_failure: float = 0.01) -> tuple[int, int]:
    """Central acceptance region [lo, hi] for hits ~ Binomial(n, level) at the given false-failure rate."""
    lo = int(stats.binom.ppf(false_failure / 2, n, level))
    hi = int(stats.binom.isf(false_failure / 2, n, level))
    return lo, hi


def coverage_study(
    method: str,
    cfg: Config,
    snr_db: float | None,
    *,
    replicates: int = 100,
    level: float = 0.9,
    seed: int = 0,
    truth: str = "fixed",
    opts: RunOptions | None = None,
    executor: Executor | None = None,
    progress: bool = True,
) -> dict:
    """Run the study; returns the contract's coverage JSON (plus per-replicate records)."""
    t0 = time.perf_counter()
    # the replicates are the parallel tasks: inside one, an ensemble's members train one after another in
    # that worker (same results as any other executor; no pool nested in a pool)
    opts = dataclasses.replace(opts or RunOptions(), snr_db=snr_db, progress=False,
                               executor=Executor("local", workers=1))
    if method == "modal" and opts.mcmc is None:
        from .sampler import MCMCSettings

        opts = dataclasses.replace(opts, mcmc=MCMCSettings.for_coverage())
    tasks = [Replicate(i, method, cfg, snr_db, seed, level, truth, opts) for i in range(replicates)]
    recs = (executor or Executor()).map(run_replicate, tasks, desc=f"coverage {method}", progress=progress,
                                        resources=task_resources(opts.device if method != "modal" else "cpu"))
    hits = int(sum(r["hit"] for r in recs))
    ranks = np.array([r["rank"] for r in recs])
    p = float(stats.kstest(ranks, "uniform").pvalue) if replicates > 1 else float("nan")
    return {
        "schema": "bayespinn.coverage/1",
        "method": KEYS[method],
        "snr_db": snr_db,
        "level": level,
        "replicates": replicates,
        "hits": hits,
        "coverage": hits / replicates,
        "coverage_ci95": list(clopper_pearson(hits, replicates)),
        "rank_uniformity_p": p,
        "mean_rel_error_pct": float(np.mean([r["rel_error_pct"] for r in recs])),
        "mean_sd_rel_pct": float(np.mean([r["sd_rel_pct"] for r in recs])),
        "runtime_s": time.perf_counter() - t0,
        "case": cfg.case,
        "seed": seed,
        "truth": truth,
        "acceptance_99": list(binomial_acceptance(replicates, level)),
        "converged_fraction": float(np.mean([r["converged"] for r in recs])),
        "records": recs,
    }
