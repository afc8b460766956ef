"""Deep ensembles of the paper's PINN whose spread is an honest interval for EI.

A plain ensemble spreads only by initialisation. Here each of the M members (own initialisation and
collocation stream) is trained in two phases through the one training loop:

1. on the measured data, to learn the noise level (its sigma grid, below);
2. randomise-then-optimise: warm-started from phase 1, on its own perturbed copy of the data
   (y + sigma_hat eps_m) with its own perturbed prior anchor (log EI_0 + s eta_m), under the
   posterior-scaled objective. For a linear-Gaussian problem the fits are then exact posterior draws.

Each member's EI comes from the exact last-layer marginal likelihood of its trained features on the
measured data (`lastlayer`), times the EI prior, on a grid of log EI (`member_marginal`; sigma at its
mode): the member's posterior of EI given its features, skewed where the data make it so (at 10 dB the
first mode's frequency does). The ensemble's posterior is the equal mixture of the members' marginals (its
draws come from them in equal shares): mean the mean of their means, variance their mean variance plus the
variance of their means, the spread between networks (`pool_log_ei`).

The trained EI itself is not the centre. Training minimises data misfit plus physics penalties of weight
one, while the marginal weighs the physics at the pseudo-sd the network achieves, so the two optima differ;
and randomise-then-optimise members are posterior draws only in the linear-Gaussian case. Measured on the
family of bridges at 30 dB, centring on the trained EIs (variance: local + between / M) put the
ensemble's mean 0.74 reference sd from the reference's, bridge to bridge (sd of z over 24 bridges, largest
2.46, where one bridge's five trained members sat at z = 0.0 to 7.1); the same members' marginal means sat
within 0.35 sd of the reference's on that bridge (their mixture: z +0.13, sd 1.19x). Members whose
marginals' means scatter more than their widths say are flagged (`MAX_SCATTER_RATIO`).

The noise level comes from the same last-layer marginal likelihood, not from the trained network's raw
residuals: with its physics penalties of weight one, a network of 5 x 64 neurons absorbs part of the
noise (its residuals under-state sigma by 25-35 % at 10-20 dB), while the marginal, whose output
weights are held to the physics at the scale the network achieves, counts what the fit spent. Per
member, p(sigma | EI_m, y) on a grid of log sigma (log-uniform prior); its mode sets the perturbation
of randomise-then-optimise (phase 1 members) and the local width (phase 2 members), and sigma's
posterior draws are taken from the members' grids in equal shares.

With AR(1) noise (`[model] noise = "ar1"`) each member's last-layer model whitens its data rows along the
sensors' series, and its noise posterior is a grid over log sigma and z = atanh rho jointly (`ar1_grid`:
AR1_GRID_POINTS^2 points over +-AR1_GRID_HALF_WIDTH Laplace sds around the mode, rho uniform on (-1, 1)).
Phase 1 trains on the white objective (rho is not known yet); phase 2 perturbs the data with AR(1) noise of
sigma_hat and rho_hat (the median of the members' modes) and trains on the whitened residuals
(`pinn.Problem.noise_ar1`), which for a linear-Gaussian model makes the members draws from the AR(1)
posterior; the local widths hold sigma and rho at each member's modes, and (sigma, rho) are drawn jointly
from the members' grids. Measured on one AR(1) strain dataset (0.8, 200 Hz, 20 dB, fast profile): EI 0.84
reference sds from the reference's mean with an sd 1.07x its, rho 0.7828 +- 0.0120 against 0.7818 +- 0.0120.

Where members train: on a CPU each member of each phase is one task (`train_member`) of the executor
(`bayespinn.executor`: the local process pool, one torch thread per process, or Ray), so members train in
parallel and a member's result depends on its seed only, not on the executor or the number of workers
(measured on 2 cores: 5 members take 3 rounds of ~0.1 s per step against 0.35 s per step for one batched
network on both threads). On CUDA all members train together as one batched network (weights (M, in,
out), `torch.bmm`). The two paths give statistically equivalent but not bit-identical members: float32
training is chaotic enough that batched and single matrix products (equal to ~1e-7) drift apart. A study
on CUDA goes further and trains the ensembles of many datasets as one network (`ensemble_batch`); the
pieces it shares with this function (`rto_inputs`, `pooled_posterior`, `local_sd`) are defined here once.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, replace

import numpy as np

from .. import seeding
from ..config import Config
from ..data.measurements import Measurements
from ..threads import torch_threads
from .ensemble_marginal import (
    AR1_GRID_HALF_WIDTH,
    AR1_GRID_POINTS,
    MARGINAL_HALF_WIDTH,
    MARGINAL_POINTS,
    MARGINAL_TRIES,
    MARGINAL_WIDEN,
    SIGMA_GRID_HALF_WIDTH,
    SIGMA_GRID_POINTS,
    MemberMarginal,
    SigmaGrid,
    ar1_grid,
    local_sd,
    member_marginal,
    pool_log_ei,
    sigma_grid,
)
from .ensemble_pool import MAX_SCATTER_RATIO, N_DRAWS, _Phase, pooled_posterior
from .lastlayer import LastLayer
from .posterior import Posterior
from .priors import EIPrior, NoisePrior, prior_only
from .shared_fit import key as fit_key
from .shared_fit import member_fit, member_seed, remember

#: its public names, with those of its parts in their own modules (`ensemble_marginal`: each member's
#: noise grid and marginal of EI; `ensemble_pool`: the pooled posterior), importable from here
__all__ = [
    "AR1_GRID_HALF_WIDTH",
    "AR1_GRID_POINTS",
    "MARGINAL_HALF_WIDTH",
    "MARGINAL_POINTS",
    "MARGINAL_TRIES",
    "MARGINAL_WIDEN",
    "MAX_SCATTER_RATIO",
    "N_DRAWS",
    "RTO_FRACTION",
    "SIGMA_GRID_HALF_WIDTH",
    "SIGMA_GRID_POINTS",
    "MemberMarginal",
    "MemberTask",
    "SigmaGrid",
    "ar1_grid",
    "ensemble_posterior",
    "local_sd",
    "member_marginal",
    "phase2_settings",
    "pool_log_ei",
    "pooled_posterior",
    "rto_inputs",
    "rto_rho",
    "sigma_grid",
    "train_member",
]

log = logging.getLogger(__name__)

#: share of the profile's Adam steps spent in the randomise-then-optimise phase
RTO_FRACTION = 0.25


def _rto_data(
    data: Measurements, sigma: float, M: int, rng: np.random.Generator, rho: float | None = None
) -> tuple[Measurements, ...]:
    """M perturbed copies of the data: y + sigma e, e white, or AR(1) with coefficient rho along the series."""
    if rho is None:
        return tuple(
            data.with_values(data.value + sigma * rng.standard_normal(len(data))) for _ in range(M)
        )
    from ..data.synthetic import ar1_noise  # the series and recursion `simulate` uses

    return tuple(
        data.with_values(data.value + sigma * ar1_noise(rng.standard_normal(len(data)), data, rho))
        for _ in range(M)
    )


@dataclass(frozen=True)
class MemberTask:
    """Everything one member's training needs; a function of it alone (its seed streams are (seed, m)),
    so a member's result does not depend on the executor, its workers or the other members."""

    m: int
    phase: int  # 1: the measured data; 2: randomise-then-optimise
    cfg: Config
    data: Measurements  # the measured data (its last-layer model and sigma grid)
    train_data: Measurements  # what it trains on (phase 2: its perturbed copy)
    settings: object  # TrainSettings
    seed: object  # the ensemble's SeedSequence
    noise: NoisePrior
    noise_sd: float | None = None  # phase 2: sigma_hat
    # phase 2 with AR(1) noise: rho_hat (the objective whitens with it)
    noise_ar1: float | None = None
    anchor: tuple[float, float] | None = None  # phase 2: (its log EI anchor, sd)
    init_state: dict | None = None  # phase 2: its phase-1 state
    progress: bool = False


def _last_layer(
    model, m: int, base, data: Measurements, seed, settings, index: int | None = None, ar1=False
) -> LastLayer:
    """Member m's last-layer model (its pseudo-observation points from (seed, m)); `index` is its place in
    `model` when that differs from m (several ensembles in one network); ``ar1``: AR(1) noise."""
    from .ar1 import AR1Noise

    rng = np.random.default_rng(seeding.child(seed, "collocation", m))
    return LastLayer(
        model,
        0 if model.members == 1 else (m if index is None else index),
        base,
        data,
        rng,
        n_pde=settings.n_pde,
        n_bc=settings.n_bc,
        n_ic=settings.n_ic,
        beta_rel=settings.beta_rel,
        images=settings.images,
        noise=AR1Noise.of(data) if ar1 else None,
    )


def train_member(task: MemberTask) -> dict:
    """Train member m of one phase alone (one torch thread) and build its last-layer model on the measured
    data: the unit of work the executor spreads over processes (or Ray workers)."""
    from ..pinn import Problem, fit

    t = task
    s = t.settings
    with torch_threads(1):
        problem = Problem.from_config(
            t.cfg,
            t.train_data,
            noise_sd=t.noise_sd,
            anchor=None if t.anchor is None else ([t.anchor[0]], t.anchor[1]),
            noise_ar1=t.noise_ar1,
        )
        every = max(1, (s.epochs + s.lbfgs_iters) // 5)

        def report(step, info):
            if t.progress and step % every == 0:
                log.debug(  # per training step: shown with --verbose
                    "[ensemble] phase %d, member %d: step %d, EI %.5g N m^2",
                    t.phase,
                    t.m,
                    step,
                    float(info["EI_raw"][0]),
                )

        if t.phase == 1:  # the fit the B-PINN shares (`shared_fit`)
            r = member_fit(problem, s, member_seed(t.seed), t.m, callback=report)
        else:
            r = fit(
                problem,
                s,
                seed=seeding.stream(t.seed, "collocation"),
                members=1,
                first_member=t.m,
                device="cpu",
                quiet=True,
                init_state=t.init_state,
                callback=report,
            )
        base = Problem.from_config(t.cfg, t.data)
        ll = _last_layer(
            r.model("cpu"), t.m, base, t.data, t.seed, s, ar1=t.cfg.model.noise == "ar1"
        )
        out = {
            "EI": float(r.EI[0]),
            "beta_factor": float(r.beta_factor),
            "grid": sigma_grid(ll, t.noise),
            "runtime_s": float(r.runtime_s),
        }
        if t.phase == 1:
            out["state"] = r.state
            if t.m == 0:
                out["fit"] = r
        else:  # the member's own posterior of EI, here in its task rather than one by one after
            ei_prior = EIPrior.from_spec(t.cfg.prior)
            sd = local_sd(ll, out["grid"], ei_prior)
            shift = math.log(base.EI_ref) - math.log(out["beta_factor"])
            out["last_layer"] = ll
            out["local_sd"] = sd
            out["marginal"] = member_marginal(ll, out["grid"], ei_prior, shift, float(sd))
    return out


def _phase_tasks(tasks: list[MemberTask], executor, desc: str, progress: bool) -> _Phase:
    from ..executor import Executor, task_resources

    ex = executor or Executor()
    res = ex.map(train_member, tasks, desc=desc, progress=progress, resources=task_resources("cpu"))
    return _Phase(
        EI=np.array([r["EI"] for r in res]),
        beta_factor=np.array([r["beta_factor"] for r in res]),
        grids=[r["grid"] for r in res],
        last_layers=[r["last_layer"] for r in res] if "last_layer" in res[0] else None,
        states=[r["state"] for r in res] if "state" in res[0] else None,
        state=None,
        runtime_s=float(sum(r["runtime_s"] for r in res)),
        fit0=res[0].get("fit"),
        lap_sd=np.array([r["local_sd"] for r in res]) if "local_sd" in res[0] else None,
        marginals=[r["marginal"] for r in res] if "marginal" in res[0] else None,
    )


def _phase_batched(
    problem,
    settings,
    seed,
    stream: str,
    M: int,
    device,
    quiet: bool,
    init_state,
    base,
    data,
    noise: NoisePrior,
    keep_last_layers: bool,
    ar1: bool = False,
) -> _Phase:
    from ..pinn import fit

    r = fit(
        problem,
        settings,
        seed=seeding.stream(seed, stream),
        members=M,
        device=device,
        quiet=quiet,
        init_state=init_state,
    )
    model = r.model("cpu")
    with torch_threads(1):
        lls = [_last_layer(model, m, base, data, seed, settings, ar1=ar1) for m in range(M)]
    return _Phase(
        EI=np.atleast_1d(np.asarray(r.EI, float)),
        beta_factor=np.full(M, r.beta_factor),
        grids=[sigma_grid(ll, noise) for ll in lls],
        last_layers=lls if keep_last_layers else None,
        states=None,
        state=r.state,
        runtime_s=r.runtime_s,
    )


def _batched(device) -> bool:
    """Members train as one batched network on a GPU, and as separate single-thread tasks on CPUs."""
    import torch

    d = str(device)
    return d.startswith("cuda") or (d == "auto" and torch.cuda.is_available())


def ensemble_posterior(
    data: Measurements,
    cfg: Config,
    *,
    seed: int | np.random.SeedSequence,
    members: int = 5,
    profile: str = "fast",
    device: str = "cpu",
    noise: NoisePrior,
    executor=None,
    progress: bool = False,
) -> Posterior:
    """Train `members` networks (phase 1 then randomise-then-optimise) and pool them into a posterior.

    On a CPU each member of each phase is one task of `executor` (default: the local process pool,
    one torch thread per process; Ray with `--executor ray`), so the result does not depend on the
    executor or its number of workers; on CUDA the members train together as one batched network.
    """
    from ..pinn import Problem, TrainSettings

    t0 = time.perf_counter()
    M = int(members)
    settings = TrainSettings.for_profile(profile)
    ei_prior = EIPrior.from_spec(cfg.prior)
    n = len(data)
    if n == 0:
        log.warning("[ensemble] no measurements: EI is not identified, returning the prior")
        return prior_only(ei_prior, seed, t0, method="ensemble")
    if not isinstance(seed, np.random.SeedSequence):
        seed = np.random.SeedSequence(int(seed))
    quiet = not progress
    batched = _batched(device)
    base = Problem.from_config(cfg, data)
    s2 = phase2_settings(settings)

    # phase 1: all members on the measured data
    log.info(
        "[ensemble] phase 1: %d members on the measured data (%s)",
        M,
        "batched on the GPU" if batched else "one task per member",
    )
    if batched:
        p1 = _phase_batched(
            base, settings, seed, "init", M, device, quiet, None, base, data, noise, False
        )
    else:
        p1 = _phase_tasks(
            [
                MemberTask(m, 1, cfg, data, data, settings, seed, noise, progress=not quiet)
                for m in range(M)
            ],
            executor,
            "ensemble phase 1",
            not quiet,
        )
    if p1.fit0 is not None:  # the B-PINN on the same data starts from it (`shared_fit`)
        remember(fit_key(base, settings, member_seed(seed), 0), p1.fit0)
    ar1 = cfg.model.noise == "ar1"
    sigma_hat, anchors, pdata = rto_inputs(data, p1.grids, seed, ei_prior, M)
    rho_hat = rto_rho(p1.grids)
    log.info(
        "[ensemble] phase 2: randomise-then-optimise (sigma_hat = %.3g%s)",
        sigma_hat,
        "" if rho_hat is None else f", AR(1) rho_hat = {rho_hat:.3f}",
    )
    if batched:
        problem = Problem.from_config(
            cfg,
            pdata,
            noise_sd=sigma_hat,
            anchor=(anchors, ei_prior.log_sd),
            noise_ar1=rho_hat,
        )
        p2 = _phase_batched(
            problem,
            s2,
            seed,
            "collocation",
            M,
            device,
            quiet,
            p1.state,
            base,
            data,
            noise,
            True,
            ar1,
        )
    else:
        p2 = _phase_tasks(
            [
                MemberTask(
                    m,
                    2,
                    cfg,
                    data,
                    pdata[m],
                    s2,
                    seed,
                    noise,
                    noise_sd=sigma_hat,
                    noise_ar1=rho_hat,
                    anchor=(float(anchors[m]), ei_prior.log_sd),
                    init_state=p1.states[m],
                    progress=not quiet,
                )
                for m in range(M)
            ],
            executor,
            "ensemble phase 2",
            not quiet,
        )
    training = "batched (one network of M members)" if batched else "one task per member"
    return pooled_posterior(p1, p2, sigma_hat, base, ei_prior, seed, M, training, t0)


def phase2_settings(settings):
    """Randomise-then-optimise trains RTO_FRACTION of the profile's steps at 0.3 x its learning rate."""
    return replace(
        settings, epochs=max(1, int(RTO_FRACTION * settings.epochs)), lr=settings.lr * 0.3
    )


def rto_inputs(data: Measurements, grids: list, seed, ei_prior: EIPrior, M: int):
    """Phase 2's inputs from phase 1's sigma grids: (sigma_hat, the M anchors of log EI, the M perturbed
    copies of the data), all from the ensemble's seed."""
    sigma_hat = float(np.median([g.mode for g in grids]))
    rng = np.random.default_rng(seeding.stream(seed, "noise"))
    eta = rng.standard_normal(M)
    anchors = ei_prior.loc + ei_prior.log_sd * eta
    return sigma_hat, anchors, _rto_data(data, sigma_hat, M, rng, rto_rho(grids))


def rto_rho(grids: list) -> float | None:
    """Phase 2's AR(1) coefficient: tanh of the median of the members' modes of z = atanh rho (None: white
    noise)."""
    if grids[0].z is None:
        return None
    return float(np.tanh(np.median([g.z_mode for g in grids])))
