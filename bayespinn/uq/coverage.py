"""Posterior coverage: does a central `level` interval hold the true EI that often?

Each replicate draws fresh sample points and noise (and, for simulation-based calibration, a fresh
true EI from the prior), runs one method, and records whether the interval holds the truth and the
rank of the truth among the posterior draws. Replicates are seeded by study seed, SNR level and index,
so the result does not depend on the executor or the number of workers, the datasets of two SNR levels
are independent, and all methods at one level see the same datasets (so each can be set beside the
reference posterior of the very same data). Every replicate's record carries the git commit of the code
that computed it (`bayespinn.provenance`), so a study resumed over several sessions says which commits
contributed how many replicates.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import sys
import time
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import stats

from .. import methods, seeding
from ..config import Config, snr_label
from ..data.synthetic import simulate
from ..errors import InputError
from ..executor import Executor, task_resources
from ..options import RunOptions
from ..provenance import commits, provenance, record_commit
from .replicates import Checkpoint, earlier_records

log = logging.getLogger(__name__)


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


#: how replicate seeds are derived; files without it shared their datasets across SNR levels
SEEDING = "seed/snr/index"


def replicate_seed(seed: int, snr_db: float | None, index: int) -> np.random.SeedSequence:
    """The seed of replicate `index` at `snr_db`: independent across levels and replicates."""
    level = zlib.crc32(snr_label(snr_db).encode())
    return seeding.child(seeding.child(seed, "coverage", level), "coverage", index)


def _dataset(task: Replicate):
    """(girder with this replicate's truth, its simulated data, its seed)."""
    seq = replicate_seed(task.seed, task.snr_db, task.index)
    cfg = task.cfg
    if task.truth == "prior":
        from .priors import EIPrior

        ei = float(
            EIPrior.from_spec(cfg.prior).sample(np.random.default_rng(seeding.stream(seq, "init")))
        )
        cfg = dataclasses.replace(cfg, beam=dataclasses.replace(cfg.beam, EI=ei))
    return cfg, simulate(cfg, task.snr_db, seq), seq


def run_replicate(task: Replicate) -> dict:
    """Simulate one dataset, infer, and score the interval against the truth."""
    cfg, data, seq = _dataset(task)
    from ..pipeline import analyse

    m = methods.build(task.method, task.opts)
    res = analyse(data, cfg, methods=[m], seed=seq, snr_db=task.snr_db, opts=task.opts, argv=[])
    return _score(task, cfg, res.posteriors[m.key])


def _batches(m) -> bool:
    """Does this method train many datasets as one batch (`infer_many`, e.g. the ensemble on a GPU)?"""
    return bool(getattr(m, "batches", lambda: False)())


def run_replicates_batched(tasks: list[Replicate], executor: Executor | None = None) -> list[dict]:
    """Replicates whose method trains many datasets as one batch (its `batches()`, e.g. the ensemble on a
    GPU): simulate every dataset, infer them together (its `infer_many`), score each as `run_replicate`
    does. Every task must share method, options and girder model (one study's). A batch whose training
    diverges is run again one replicate at a time, so that one bad dataset cannot sink the others."""
    from ..errors import TrainingDiverged

    if not tasks:
        return []
    sets = [_dataset(t) for t in tasks]
    m = methods.build(tasks[0].method, dataclasses.replace(tasks[0].opts, executor=executor))
    for cfg, data, _ in sets:
        m.check(data, cfg)
    datas, seeds = [d for _, d, _ in sets], [q for _, _, q in sets]
    try:
        if hasattr(m, "infer_many"):
            posts = m.infer_many(datas, tasks[0].cfg, seeds=seeds)
        else:
            posts = [m.infer(d, tasks[0].cfg, seed=q) for d, q in zip(datas, seeds, strict=True)]
    except TrainingDiverged as exc:
        if len(tasks) == 1:
            raise
        log.warning(
            "a batch of %d replicates diverged (%s): running them one by one", len(tasks), exc
        )
        return [run_replicate(t) for t in tasks]
    return [_score(t, cfg, p) for t, (cfg, _, _), p in zip(tasks, sets, posts, strict=True)]


def _score(task: Replicate, cfg: Config, post) -> dict:
    true = cfg.beam.EI
    lo, hi = post.interval(task.level)
    d = post.EI.ravel()
    out = {
        "index": task.index,
        "EI_true": true,
        "hit": bool(lo <= true <= hi),
        "interval": [lo, hi],
        "rank": float(np.mean(d < true)),
        "rel_error_pct": float(100 * (d.mean() - true) / true),
        "sd_rel_pct": float(100 * d.std(ddof=1) / true),
        # the method's own verdict (None: it has none)
        "converged": post.diagnostics.get("converged"),
        **record_commit(),
    }
    rho = ar1_draws(post, cfg)
    if rho is not None:  # the AR(1) coefficient the likelihood infers, against the one simulated
        from .posterior import central_interval

        t = cfg.data.noise_ar1
        r_lo, r_hi = central_interval(rho, task.level)
        out["noise_ar1"] = {
            "true": t,
            "hit": bool(r_lo <= t <= r_hi),
            "interval": [r_lo, r_hi],
            "rank": float(np.mean(rho < t)),
            "mean": float(rho.mean()),
            "sd": float(rho.std(ddof=1)),
        }
    return out


def converged_fraction(recs: list[dict]) -> float | None:
    """The share of replicates whose method said it converged, of those that gave a verdict."""
    v = [bool(r["converged"]) for r in recs if r.get("converged") is not None]
    return float(np.mean(v)) if v else None


def ar1_draws(post, cfg: Config) -> np.ndarray | None:
    """The posterior draws of the noise's AR(1) coefficient when the analysis infers it, else None."""
    if cfg.model.noise != "ar1":
        return None
    rho = getattr(post, "noise_ar1", None)
    return None if rho is None else np.asarray(rho, float).ravel()


def parameter_coverage(recs: list[dict], key: str, level: float) -> dict | None:
    """Hits, coverage, acceptance region and rank uniformity of a further parameter's intervals (`key` in
    every record, e.g. noise_ar1), or None when some record lacks it."""
    if not recs or any(key not in r for r in recs):
        return None
    n = len(recs)
    hits = int(sum(r[key]["hit"] for r in recs))
    ranks = np.array([r[key]["rank"] for r in recs])
    return {
        "true": recs[0][key]["true"],
        "replicates": n,
        "hits": hits,
        "coverage": hits / n,
        "coverage_ci95": list(clopper_pearson(hits, n)),
        "acceptance_99": list(binomial_acceptance(n, level)),
        "verdict": verdict(hits, n, level),
        "rank_uniformity_p": float(stats.kstest(ranks, "uniform").pvalue) if n > 1 else None,
        "mean": float(np.mean([r[key]["mean"] for r in recs])),
        "mean_sd": float(np.mean([r[key]["sd"] for r in recs])),
    }


def clopper_pearson(k: int, n: int, conf: float = 0.95) -> tuple[float, float]:
    """Exact (Clopper-Pearson) binomial confidence interval for a proportion k/n (scipy's binomtest)."""
    ci = stats.binomtest(int(k), int(n)).proportion_ci(confidence_level=conf, method="exact")
    return float(ci.low), float(ci.high)


def binomial_acceptance(n: int, level: float, false_failure: float = 0.01) -> tuple[int, int]:
    """Central acceptance region [lo, hi] for hits ~ Binomial(n, level) at the given false-failure rate."""
    lo = int(stats.binom.ppf(false_failure / 2, n, level))
    hi = int(stats.binom.isf(false_failure / 2, n, level))
    return lo, hi


#: the miscalibration each study states its power against: intervals that hold the truth this often
POWER_AGAINST = 0.8


def power(
    n: int, level: float, against: float = POWER_AGAINST, false_failure: float = 0.01
) -> float:
    """Probability that n replicates of a method whose intervals really cover `against` put its hits outside
    the acceptance region of `level` (the chance the study notices that miscalibration)."""
    lo, hi = binomial_acceptance(n, level, false_failure)
    return float(stats.binom.cdf(lo - 1, n, against) + stats.binom.sf(hi, n, against))


def verdict(hits: int, n: int, level: float, false_failure: float = 0.01) -> str:
    """'consistent with 90 %' when the hits lie in the acceptance region, else 'not consistent with 90 %'."""
    lo, hi = binomial_acceptance(n, level, false_failure)
    pct = f"{100 * level:g} %"
    return f"consistent with {pct}" if lo <= hits <= hi else f"not consistent with {pct}"


def law_constants(method: str) -> dict:
    """The constants of a method's statistical model that neither the configuration nor the options hold
    (the PINNs' pseudo-observation and weight-prior factors), so that a study resumed after one of them
    changed starts afresh instead of pooling replicates of two models. The reference's model is all in
    its configuration: none."""
    if methods.get(method).reference:
        return {}
    from . import girder_lastlayer, lastlayer

    return {
        "pde_sd_factor": lastlayer.PDE_SD_FACTOR,
        "girder_pde_sd_factor": girder_lastlayer.GIRDER_PDE_SD_FACTOR,
        "weight_prior_factor": lastlayer.WEIGHT_PRIOR_FACTOR,
        "min_pseudo_sd": lastlayer.MIN_PSEUDO_SD,
    }


def fingerprint(
    method: str, cfg: Config, snr_db, seed: int, level: float, truth: str, opts: RunOptions
) -> str:
    """What decides a replicate's result: method, configuration, noise level, seed, level, truth, the
    method's options and its model's constants (`law_constants`); not the executor, the worker count or
    the number of replicates."""
    from .posterior import jsonable

    spec = {
        "method": method,
        "cfg": jsonable(cfg.identity()),
        "snr_db": snr_db,
        "seed": seed,
        "level": level,
        "truth": truth,
        "profile": opts.profile,
        "members": opts.members,
        "device": opts.device,
        "noise_prior": opts.noise_prior,
        "mcmc": repr(opts.mcmc),
        "bpinn_variant": opts.bpinn_variant,
        "seeding": SEEDING,
    }
    if law := law_constants(method):  # none for the reference: its studies' keys stay as they were
        spec["law"] = law
    return hashlib.sha256(json.dumps(spec, sort_keys=True, default=repr).encode()).hexdigest()[:16]


def study_options(method: str, snr_db, opts: RunOptions | None) -> RunOptions:
    """The options every replicate of a study runs with. The replicates are the parallel tasks: inside one,
    an ensemble's members train one after another in that worker (same results as any other executor; no
    pool nested in a pool). The modal reference uses the coverage sampler settings unless given others."""
    opts = dataclasses.replace(
        opts or RunOptions(), snr_db=snr_db, progress=False, executor=Executor("local", workers=1)
    )
    if methods.get(method).reference and opts.mcmc is None:
        from .sampler import MCMCSettings

        opts = dataclasses.replace(opts, mcmc=MCMCSettings.for_coverage())
    return opts


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
    checkpoint: str | Path | None = None,
    resume_from: str | Path | None = None,
) -> dict:
    """Run the study; returns the contract's coverage JSON (plus per-replicate records and the study's
    `fingerprint`).

    checkpoint : a file that keeps every finished replicate; a study started again with the same settings
        reuses them and runs only the rest (the caller removes it once the result is written)
    resume_from : a study file written earlier (this function's JSON); its replicates are reused when it is
        the same study (`earlier_records`), e.g. to run 30 replicates over two sessions, whichever commit
        computed them: each record names its own (`commits` counts them)
    """
    t0 = time.perf_counter()
    methods.get(method)  # InputError naming --method for an unknown one
    if isinstance(replicates, bool) or not isinstance(replicates, int) or replicates < 1:
        raise InputError("--replicates", replicates, "an integer >= 1")
    if not (isinstance(level, float | int) and 0.0 < level < 1.0):
        raise InputError("--level", level, "a credible level in (0, 1), e.g. 0.9")
    if truth not in ("fixed", "prior"):
        raise InputError("truth", truth, "fixed or prior")
    opts = study_options(method, snr_db, opts)
    key = fingerprint(method, cfg, snr_db, seed, level, truth, opts)
    earlier = earlier_records(resume_from, key) if resume_from is not None else {}
    ck = Checkpoint(checkpoint, key, earlier) if checkpoint else None
    have = ck.done if ck else earlier
    tasks = [
        Replicate(i, method, cfg, snr_db, seed, level, truth, opts)
        for i in range(replicates)
        if i not in have
    ]
    if _batches(methods.build(method, opts)):  # a GPU: many replicates as one network
        new = _batched_study(tasks, method, opts, executor, progress, ck)
    else:
        new = (executor or Executor()).map(
            run_replicate,
            tasks,
            desc=f"coverage {method}",
            progress=progress,
            resources=task_resources(opts.device if method != "modal" else "cpu"),
            on_result=(lambda i, r: ck.add(r)) if ck else None,
        )
    recs = sorted([have[i] for i in range(replicates) if i in have] + new, key=lambda r: r["index"])
    hits = int(sum(r["hit"] for r in recs))
    ranks = np.array([r["rank"] for r in recs])
    p = float(stats.kstest(ranks, "uniform").pvalue) if replicates > 1 else float("nan")
    from .posterior import jsonable

    extra = {}
    rho = parameter_coverage(recs, "noise_ar1", level)
    if rho is not None:
        extra["noise_ar1"] = rho
    return {
        "schema": "bayespinn.coverage/1",
        "method": methods.get(method).key,
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
        "converged_fraction": converged_fraction(recs),
        "resumed_replicates": sum(1 for i in range(replicates) if i in have),
        "commits": commits(recs),
        "seeding": SEEDING,
        "power_vs_80": power(replicates, level),
        "verdict": verdict(hits, replicates, level),
        "fingerprint": key,
        **extra,
        "config": jsonable(cfg.to_dict()),
        # who wrote this file: the command, commit, machine and date of the run that finished it (each
        # replicate's own commit is in its record)
        "provenance": {"command": list(sys.argv), **provenance(str(opts.device or "cpu"))},
        "records": recs,
    }


def _batched_study(tasks, method, opts, executor, progress, ck) -> list[dict]:
    """The replicates in batches as large as the device's memory allows (`pinn.networks_per_batch`),
    each batch one network; every record is checkpointed as its batch ends. The members' last-layer models
    go to `executor` when it is a pool of several workers, else to a local pool of one per core."""
    from tqdm.auto import tqdm

    from ..pinn import Problem, TrainSettings, networks_per_batch

    if not tasks:
        return []
    if executor is None or (executor.kind == "local" and (executor.workers or 0) <= 1):
        executor = Executor("local")
    cfg, data, _ = _dataset(tasks[0])
    settings = TrainSettings.for_profile(opts.profile)
    nets = networks_per_batch(Problem.from_config(cfg, data), settings, opts.device)
    per = max(1, nets // opts.members)
    out: list[dict] = []
    todo = list(tasks)
    bar = tqdm(total=len(todo), desc=f"coverage {method}", disable=not progress, unit="replicate")
    try:
        while todo:
            batch = todo[:per]
            try:
                recs = run_replicates_batched(batch, executor)
            except MemoryError_ as exc:
                if per == 1:
                    raise
                per = max(1, per // 2)
                import torch

                torch.cuda.empty_cache()
                log.warning("out of device memory (%s): batches of %d replicates now", exc, per)
                continue
            for r in recs:
                if ck:
                    ck.add(r)
            out += recs
            todo = todo[len(batch) :]
            bar.update(len(batch))
    finally:
        bar.close()
    return out


try:  # what a device that runs out of memory raises
    from torch.cuda import OutOfMemoryError as MemoryError_
except ImportError:  # pragma: no cover - older torch
    MemoryError_ = MemoryError


#: the issues' band for an approximate posterior's sd against the reference's
SD_RATIO_BAND = (0.67, 1.5)


def paired_with_reference(study: dict, reference: dict) -> dict | None:
    """Each replicate of `study` against the reference posterior of the same dataset.

    Two coverage studies share their datasets when they share seed, SNR, case and truth ('fixed'):
    replicate i simulates the same sample points and noise whatever the method. On each shared
    dataset, z = (mean - reference mean) / reference sd and r = sd / reference sd judge the method's
    posterior against the reference one, free of the luck of that dataset (a miss of both says the
    dataset was extreme, not that the method failed). Returns None when the studies do not share
    datasets.
    """
    same = all(
        study.get(k) == reference.get(k) for k in ("seed", "snr_db", "case", "truth", "seeding")
    )
    if not same or study.get("truth") != "fixed":
        return None
    ref = {r["index"]: r for r in reference["records"]}
    pairs = [(r, ref[r["index"]]) for r in study["records"] if r["index"] in ref]
    if not pairs:
        return None
    z = np.array([(r["rel_error_pct"] - q["rel_error_pct"]) / q["sd_rel_pct"] for r, q in pairs])
    ratio = np.array([r["sd_rel_pct"] / q["sd_rel_pct"] for r, q in pairs])
    lo, hi = SD_RATIO_BAND
    return {
        "reference": reference["method"],
        "datasets": len(pairs),
        "mean_z": float(z.mean()),
        "sd_z": float(z.std(ddof=1)) if len(z) > 1 else None,
        "max_abs_z": float(np.abs(z).max()),
        "median_sd_ratio": float(np.median(ratio)),
        "sd_ratio_range": [float(ratio.min()), float(ratio.max())],
        "sd_ratio_in_band": float(np.mean((ratio >= lo) & (ratio <= hi))),
        "sd_ratio_band": list(SD_RATIO_BAND),
        "hits": int(sum(r["hit"] for r, _ in pairs)),
        "reference_hits": int(sum(q["hit"] for _, q in pairs)),
        "misses_of_both": int(sum((not r["hit"]) and (not q["hit"]) for r, q in pairs)),
    }
