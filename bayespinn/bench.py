"""`bayespinn bench`: performance figures (contract schema bayespinn.bench/1)."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from .config import preset

log = logging.getLogger(__name__)

#: walkers evaluated per vectorised likelihood call in the benchmark (emcee with 2 x 16 walkers)
BENCH_BATCH = 32


def bench_modal(
    n_points: int = 100, n_modes: int = 10, batch: int = BENCH_BATCH, seconds: float = 2.0
) -> dict:
    """Gaussian log-likelihood evaluations per second of the modal surrogate, one EI value per evaluation,
    `batch` EI values per vectorised call (as emcee calls it)."""
    from .physics.modal import ModalModel

    cfg = preset("deflection")
    rng = np.random.default_rng(0)
    x = rng.uniform(0, cfg.beam.length, n_points)
    t = rng.uniform(0, cfg.duration, n_points)
    m = ModalModel(cfg.beam, cfg.vehicle, x, t, n_modes=n_modes)
    y = m.predict(cfg.beam.EI) + 1e-4 * rng.standard_normal(n_points)

    def loglik(ei, sig):
        r = y[None, :] - m.predict(ei)
        return -0.5 * np.einsum("wp,wp->w", r, r) / sig**2 - n_points * np.log(sig)

    out = {"points": n_points, "modes": n_modes, "batch": batch}
    for name, w in (("likelihood_evals_per_s", batch), ("unbatched_evals_per_s", 1)):
        ei = cfg.beam.EI * np.exp(0.05 * rng.standard_normal(w))
        loglik(ei, 1e-4)
        n, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < seconds / 2:
            loglik(ei, 1e-4)
            n += w
        out[name] = n / (time.perf_counter() - t0)
    return out


#: the run that `bench --run` times: the README's quick start (`bayespinn run --snr 10`, seed 0)
QUICK_START = {"case": "deflection", "snr_db": 10.0, "seed": 0, "methods": "all", "profile": "fast"}


def bench_run(device: str = "cpu", progress: bool = True, profile: str | None = None) -> dict:
    """Where the time of the quick start goes: `QUICK_START` analysed in memory, its wall time and each
    method's share (`pipeline.time_breakdown`: training, summed over worker processes where they run in
    parallel, and the rest), then its run folder written to a temporary folder (`report_s`: the figures,
    tables and reports, which draw on every method's posterior predictive). ``profile`` overrides the
    quick start's (tests use 'smoke')."""
    import tempfile

    from .options import RunOptions
    from .pipeline import analyse, load_data, write_run

    q = {**QUICK_START, **({"profile": profile} if profile else {})}
    cfg = preset(q["case"])
    t0 = time.perf_counter()
    data, truth = load_data(cfg, None, q["snr_db"], q["seed"])
    opts = RunOptions(profile=q["profile"], device=device, snr_db=q["snr_db"], progress=progress)
    res = analyse(
        data,
        cfg,
        methods=q["methods"],
        seed=q["seed"],
        snr_db=q["snr_db"],
        truth=truth,
        opts=opts,
    )
    wall = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        t1 = time.perf_counter()
        write_run(res, Path(tmp) / "run")
        report_s = time.perf_counter() - t1
    return {
        **q,
        "wall_s": wall,
        "report_s": report_s,
        "time_breakdown_s": res.manifest.get("time_breakdown_s"),
        "timings_s": res.manifest.get("timings_s"),
    }


def bench(device: str = "cpu", progress: bool = True, run: bool = False) -> dict:
    """All sections: derivatives (Taylor vs nested autograd), ensemble (one after another vs batched vs parallel
    processes), many networks trained as one, modal; with ``run`` also the quick start's breakdown
    (`bench_run`, minutes)."""
    import torch

    from .pinn.bench import bench_derivatives, bench_ensemble
    from .pinn.bench_networks import bench_many_networks

    threads = torch.get_num_threads()
    res = {"schema": "bayespinn.bench/1", "device": device, "threads": threads}
    log.info("bench: derivatives (Taylor mode vs nested autograd) ...")
    res["derivatives"] = bench_derivatives(device=device)
    log.info("bench: ensemble (one after another vs batched vs parallel processes) ...")
    res["ensemble"] = bench_ensemble(device=device)
    log.info("bench: many networks trained as one (1, 8, 64, 256) ...")
    res["many_networks"] = bench_many_networks(device=device)
    log.info("bench: modal likelihood ...")
    res["modal"] = bench_modal()
    if run:
        log.info("bench: the quick start's analysis (bayespinn run --snr 10), minutes ...")
        res["run"] = bench_run(device=device, progress=progress)
    return res
