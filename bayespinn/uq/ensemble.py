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
family of bridges at 30 dB (issue 21), centring on the trained EIs (variance: local + between / M) put the
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
from .lastlayer import (
    GRID_EDGE,
    IDENTIFIED_FRACTION,
    LastLayer,
    LastLayerPredictor,
    log_prior_z,
)
from .lastlayer_grid import log_marginal_grid
from .pinn_ar1 import AR1Posterior
from .posterior import Posterior
from .priors import EIPrior, NoisePrior, prior_only
from .shared_fit import key as fit_key
from .shared_fit import member_fit, member_seed, remember

log = logging.getLogger(__name__)

#: share of the profile's Adam steps spent in the randomise-then-optimise phase
RTO_FRACTION = 0.25
#: posterior draws stored
N_DRAWS = 4000
#: members scattering more than this many times their own local sd are flagged as not converged
#: (with 5 members the sample sd is itself uncertain by ~35 %, so 3x is far outside chance)
MAX_SCATTER_RATIO = 3.0


#: the grid of log sigma: this many points over +-`SIGMA_GRID_HALF_WIDTH` around the fit's residual level
SIGMA_GRID_POINTS = 241
SIGMA_GRID_HALF_WIDTH = 1.2


@dataclass(frozen=True)
class SigmaGrid:
    """p(log sigma | EI, y) of a last-layer model on a grid (log-uniform prior on sigma); with AR(1) noise
    p(log sigma, z | EI, y) on a grid of both (``z`` the axis of z = atanh rho, ``prob`` (sigma, z))."""

    log_sigma: np.ndarray
    prob: np.ndarray
    z: np.ndarray | None = None

    @property
    def mode(self) -> float:
        """sigma's mode (of its marginal where the grid has a z axis)."""
        p = self.prob if self.z is None else self.prob.sum(axis=1)
        return float(np.exp(self.log_sigma[int(np.argmax(p))]))

    @property
    def z_mode(self) -> float | None:
        """The mode of z = atanh rho's marginal, or None for white noise."""
        if self.z is None:
            return None
        return float(self.z[int(np.argmax(self.prob.sum(axis=0)))])

    def draws(self, k: int, rng: np.random.Generator) -> np.ndarray:
        """k draws of sigma: a grid cell by its probability, uniform within it."""
        h = self.log_sigma[1] - self.log_sigma[0]
        i = rng.choice(self.prob.size, size=k, p=self.prob)
        return np.exp(self.log_sigma[i] + h * (rng.random(k) - 0.5))

    def draws_ar1(self, k: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """k joint draws of (sigma, rho) from the two-dimensional grid (a cell by its probability, uniform
        within it)."""
        hs, hz = self.log_sigma[1] - self.log_sigma[0], self.z[1] - self.z[0]
        flat = rng.choice(self.prob.size, size=k, p=self.prob.ravel())
        i, j = np.unravel_index(flat, self.prob.shape)
        u = rng.random((2, k)) - 0.5
        return np.exp(self.log_sigma[i] + hs * u[0]), np.tanh(self.z[j] + hz * u[1])


def sigma_grid(ll: LastLayer, noise: NoisePrior) -> SigmaGrid:
    """The noise level's posterior for one member at its fitted EI (see the module docstring); with the
    SNR-conditioned noise prior its log-normal density is added (as in the B-PINN). With AR(1) noise the
    joint posterior of sigma and the coefficient (`ar1_grid`)."""

    if ll.ar1 is not None:
        return ar1_grid(ll, noise)

    center = 0.5 * math.log(max(ll.fit_rss, 1e-300) / max(ll.n, 1))
    grid = center + np.linspace(-SIGMA_GRID_HALF_WIDTH, SIGMA_GRID_HALF_WIDTH, SIGMA_GRID_POINTS)
    with torch_threads(1):
        lp = log_marginal_grid(ll, math.log(ll.theta_fit), grid)
    if noise.kind == "snr":
        lp = lp - 0.5 * ((grid - math.log(noise.center)) / noise.log_sd) ** 2
    if int(np.argmax(lp)) in (0, grid.size - 1):
        log.warning(
            "[ensemble] the noise level's posterior reaches the edge of its grid (%.3g .. %.3g)",
            math.exp(grid[0]),
            math.exp(grid[-1]),
        )
    p = np.exp(lp - lp.max())
    return SigmaGrid(grid, p / p.sum())


#: the AR(1) noise grid: points per axis, and its half-width in Laplace sds of each axis
AR1_GRID_POINTS = 41
AR1_GRID_HALF_WIDTH = 6.0


def ar1_grid(ll: LastLayer, noise: NoisePrior) -> SigmaGrid:
    """p(log sigma, z | EI_fit, y) of a last-layer model with AR(1) noise, z = atanh rho under rho's uniform
    prior, on a grid of AR1_GRID_POINTS^2 around its mode (+-AR1_GRID_HALF_WIDTH Laplace sds of each): the
    mode by L-BFGS from the fit residuals' level and lag-1 autocorrelation, the sds from the Hessian there."""
    import torch
    from scipy.optimize import minimize

    from .ar1 import Z_MAX

    T = lambda v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
    lt = T(math.log(ll.theta_fit))

    def logp(ls, z):
        out = ll.log_marginal(lt, ls, z) + log_prior_z(z)
        if noise.kind == "snr":
            out = out - 0.5 * ((ls - math.log(noise.center)) / noise.log_sd) ** 2
        return out

    def neg(v):
        x = torch.tensor(v, dtype=torch.float64, requires_grad=True)
        f = -logp(x[0], x[1])
        (g,) = torch.autograd.grad(f, x)
        return float(f.detach()), g.numpy()

    x0 = [0.5 * math.log(max(ll.fit_rss, 1e-300) / max(ll.n, 1)), ll.z_start()]
    with torch_threads(1):
        opt = minimize(neg, x0, jac=True, method="L-BFGS-B", bounds=[(None, None), (-Z_MAX, Z_MAX)])
        H = torch.autograd.functional.hessian(lambda x: -logp(x[0], x[1]), T(opt.x))
    H = H.numpy()
    try:
        cov = np.linalg.inv(H)
        sd = np.sqrt(np.diag(cov))
        ok = bool(np.all(np.isfinite(sd)) and np.all(np.linalg.eigvalsh(H) > 0))
    except np.linalg.LinAlgError:
        ok = False
    if not ok:  # no curvature at the optimum: a wide grid
        log.warning(
            "[ensemble] the AR(1) noise posterior has no curvature at its mode; using a wide grid"
        )
        sd = np.array([0.2, 0.2])
    h = AR1_GRID_HALF_WIDTH
    ls_ax = opt.x[0] + np.linspace(-h * sd[0], h * sd[0], AR1_GRID_POINTS)
    z_ax = np.clip(opt.x[1] + np.linspace(-h * sd[1], h * sd[1], AR1_GRID_POINTS), -Z_MAX, Z_MAX)
    with torch.no_grad(), torch_threads(1):
        # z outer: the last layer reuses its first-mode block across sigma (`LastLayer._vary_block`)
        lp = np.array([[float(logp(T(a), T(b))) for a in ls_ax] for b in z_ax]).T
    p = np.exp(lp - lp.max())
    if max(p[0].max(), p[-1].max(), p[:, 0].max(), p[:, -1].max()) > 1e-4:
        log.warning("[ensemble] the AR(1) noise posterior reaches the edge of its grid")
    return SigmaGrid(ls_ax, p / p.sum(), z_ax)


#: a member's marginal of log EI: grid points over +-MARGINAL_HALF_WIDTH local sds, re-centred on the peak
#: and widened (x MARGINAL_WIDEN) up to MARGINAL_TRIES times until both ends hold less than GRID_EDGE of it
MARGINAL_POINTS = 321
MARGINAL_HALF_WIDTH = 8.0
MARGINAL_WIDEN = 2.0
MARGINAL_TRIES = 5


@dataclass(frozen=True)
class MemberMarginal:
    """p(log EI | y, a member's features, sigma at its mode) on a grid: the member's posterior of EI."""

    log_ei: np.ndarray
    prob: np.ndarray

    @property
    def mean(self) -> float:
        return float((self.prob * self.log_ei).sum())

    @property
    def var(self) -> float:
        return float((self.prob * (self.log_ei - self.mean) ** 2).sum())

    def draws(self, k: int, rng: np.random.Generator) -> np.ndarray:
        """k draws of log EI: a grid cell by its probability, uniform within it."""
        h = self.log_ei[1] - self.log_ei[0]
        i = rng.choice(self.prob.size, size=k, p=self.prob)
        return self.log_ei[i] + h * (rng.random(k) - 0.5)


def member_marginal(
    ll: LastLayer, grid: SigmaGrid, ei_prior: EIPrior, log_shift: float, sd: float
) -> MemberMarginal | None:
    """Member's exact last-layer marginal of log EI on the measured data (sigma, and an AR(1)
    coefficient, held at their modes), times the EI prior; log EI = log theta + `log_shift`. The grid
    starts at the member's trained EI, `sd` (its local width) sets its step, and it follows the peak:
    the trained EI can sit several local widths from the marginal's mean (module docstring). None when
    there is no width (`sd` nan) or the density never falls off within the grid."""

    if not (math.isfinite(sd) and sd > 0):
        return None
    centre, half = math.log(ll.theta_fit), MARGINAL_HALF_WIDTH * sd
    ls = math.log(grid.mode)
    for _ in range(MARGINAL_TRIES):
        g = centre + np.linspace(-half, half, MARGINAL_POINTS)
        lp = log_marginal_grid(ll, g, ls, grid.z_mode)
        lp = lp - 0.5 * ((g + log_shift - ei_prior.loc) / ei_prior.log_sd) ** 2
        p = np.exp(lp - lp.max())
        if max(p[0], p[-1]) < GRID_EDGE:
            return MemberMarginal(g + log_shift, p / p.sum())
        centre, half = float(g[int(np.argmax(p))]), half * MARGINAL_WIDEN
    return None


def pool_log_ei(
    log_ei_fit: np.ndarray, marginals: list, prior_log_sd: float
) -> tuple[float, float, float, float, float]:
    """(mean, between-member variance, mean local variance, members with a marginal, ensemble variance) of
    log EI.

    The ensemble's posterior is the equal mixture of its members' marginals (module docstring): mean the
    mean of their means, variance the mean of their variances plus the variance of their means. Members
    without a marginal (None) are left out. With no member's marginal the trained EIs stand for the
    posterior: their mean, variance between (1 + 1 / M); with one member and none, the prior's variance.
    """
    log_ei_fit = np.asarray(log_ei_fit, float)
    M = log_ei_fit.size
    ok = [m for m in marginals if m is not None]
    if ok:
        means = np.array([m.mean for m in ok])
        between = float(np.var(means))
        lap_var = float(np.mean([m.var for m in ok]))
        return float(means.mean()), between, lap_var, float(len(ok)), lap_var + between
    between = float(np.var(log_ei_fit, ddof=1)) if M > 1 else 0.0
    pooled = between * (1.0 + 1.0 / M) if M > 1 else prior_log_sd**2
    return float(log_ei_fit.mean()), between, 0.0, 0.0, pooled


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
class _Phase:
    """One training phase of M members, as either path (batched or one task per member) returns it."""

    EI: np.ndarray  # (M,) [N m^2], beta-corrected
    beta_factor: np.ndarray  # (M,)
    grids: list  # SigmaGrid per member, on the measured data
    last_layers: list | None  # LastLayer per member (phase 2)
    states: list | None  # per-member state dicts (phase 1, the warm start of phase 2; task path)
    state: dict | None  # the batched state (batched path)
    runtime_s: float  # training time, summed over members when they ran as separate tasks
    fit0: object = None  # phase 1, task path: member 0's FitResult (the B-PINN's warm start)
    lap_sd: np.ndarray | None = None  # phase 2, task path: each member's local width (in its task)
    marginals: list | None = (
        None  # phase 2, task path: each member's marginal of log EI (in its task)
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


def local_sd(ll: LastLayer, grid: SigmaGrid, ei_prior: EIPrior) -> float:
    """A member's own width of log EI: the sd of its last-layer marginal at its noise level's mode (and, with
    AR(1) noise, its coefficient's)."""
    return ll.local_sd_log_theta(
        math.log(ll.theta_fit), math.log(grid.mode), ei_prior.log_sd, z=grid.z_mode
    )


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


def pooled_posterior(
    p1: _Phase,
    p2: _Phase,
    sigma_hat: float,
    base,
    ei_prior: EIPrior,
    seed,
    M: int,
    training: str,
    t0: float,
    runtime_s: float | None = None,
    lap_sd: np.ndarray | None = None,
) -> Posterior:
    """The ensemble's posterior from its two phases: members' local widths (`lap_sd`, computed here from
    phase 2's last layers unless given) pooled with their spread."""
    member_EI = p2.EI
    log_ei_m = np.log(member_EI)
    # per member, on the measured data: the noise level's grid posterior, the local width of log EI and
    # the member's marginal of log EI (its posterior given its features), centred where the data put it
    lls, grids = p2.last_layers, p2.grids
    shifts = [math.log(base.EI_ref) - math.log(f) for f in p2.beta_factor]
    if lap_sd is None:
        lap_sd = p2.lap_sd
    with torch_threads(1):
        if lap_sd is None:
            lap_sd = np.array([local_sd(ll, g, ei_prior) for ll, g in zip(lls, grids, strict=True)])
        marginals = p2.marginals
        if marginals is None:
            marginals = [
                member_marginal(ll, g, ei_prior, sh, float(sd))
                for ll, g, sh, sd in zip(lls, grids, shifts, lap_sd, strict=True)
            ]
    mu, between, lap_var, n_marg, pooled = pool_log_ei(log_ei_m, marginals, ei_prior.log_sd)
    warn = []
    bad = [i for i, m in enumerate(marginals) if m is None]
    if bad:
        warn.append(
            f"member(s) {bad}: the last-layer marginal likelihood has no peak in EI near the member's own "
            "fit, so they give no posterior of their own; the interval rests on the other members"
            + ("" if n_marg else " (none has one: on the spread between the trained members)")
        )
    draw_rng = np.random.default_rng(seeding.child(seed, "ensemble", 0))
    ok = [m for m in marginals if m is not None]
    if ok:  # the equal mixture of the members' marginals
        log_ei = np.concatenate([m.draws(-(-N_DRAWS // len(ok)), draw_rng) for m in ok])[:N_DRAWS]
        log_ei = log_ei[draw_rng.permutation(N_DRAWS)]
    else:
        log_ei = mu + math.sqrt(pooled) * draw_rng.standard_normal(N_DRAWS)
    rho = None
    if grids[0].z is None:
        sigma = np.concatenate([g.draws(-(-N_DRAWS // M), draw_rng) for g in grids])[:N_DRAWS]
        sigma = sigma[draw_rng.permutation(N_DRAWS)]
    else:  # AR(1): sigma and rho jointly, from each member's grid
        sr = [g.draws_ar1(-(-N_DRAWS // M), draw_rng) for g in grids]
        perm = draw_rng.permutation(N_DRAWS)
        sigma = np.concatenate([a for a, _ in sr])[:N_DRAWS][perm]
        rho = np.concatenate([b for _, b in sr])[:N_DRAWS][perm]
    ident = bool(math.sqrt(pooled) < IDENTIFIED_FRACTION * ei_prior.log_sd)
    info = {
        "members": M,
        "member_EI": member_EI.tolist(),
        "member_posterior_EI": [None if m is None else math.exp(m.mean) for m in marginals],
        "member_local_sd_log_EI": [None if m is None else math.sqrt(m.var) for m in marginals],
        "fit_between_sd_log_EI": float(np.std(log_ei_m, ddof=1)) if M > 1 else 0.0,
        "between_sd_log_EI": math.sqrt(between),
        "local_sd_log_EI": math.sqrt(lap_var),
        "pooling": (
            f"equal mixture of {n_marg:g} members' last-layer marginals of EI"
            if n_marg
            else f"the {M} trained EIs: their spread x (1 + 1/{M})"
        ),
        "sigma_hat_rto": sigma_hat,
        "member_sigma_mode": [g.mode for g in grids],
        **(
            {"member_noise_ar1_mode": [math.tanh(g.z_mode) for g in grids]}
            if rho is not None
            else {}
        ),
        "member_first_mode_follows_EI": [ll.first_mode_varies for ll in lls],
        "identified": ident,
    }
    if M == 1:
        info["note"] = "a single member has no spread: its interval is its own local width only"
    if not ident:
        info["note"] = "EI is not identified by these data"
    # self-check: members whose posteriors' means scatter far more than each one's own width read EI
    # differently from their features; the mixture is then mostly the spread between networks
    if n_marg > 1 and lap_var > 0 and between > MAX_SCATTER_RATIO**2 * lap_var:
        msg = (
            f"the members disagree: their posteriors' means spread by sd {math.sqrt(between):.3f} in log EI, "
            f"{math.sqrt(between / lap_var):.1f} x each member's own width ({math.sqrt(lap_var):.3f}); "
            "the networks have not converged to one answer, so this interval mostly measures their scatter"
        )
        warn.append(msg)
    for msg in warn:
        log.warning("[ensemble] %s", msg)
    if warn:
        info["warnings"] = warn
    diag = {
        "fit_runtime_s": p1.runtime_s + p2.runtime_s,
        "beta_factor": float(np.median(p2.beta_factor)),
        "training": training,
    }
    predictor = _MixturePredictor(
        [
            LastLayerPredictor(
                ll,
                np.full(64, math.log(ll.theta_fit)) if m is None else m.draws(64, draw_rng) - sh,
                np.full(64, math.log(g.mode)),
                sh,
                None if g.z is None else np.full(64, g.z_mode),
            )
            for ll, g, sh, m in zip(lls, grids, shifts, marginals, strict=True)
        ]
    )
    kw = dict(
        diagnostics=diag,
        info=info,
        runtime_s=time.perf_counter() - t0 if runtime_s is None else runtime_s,
        predictor=predictor,
    )
    if rho is not None:
        return AR1Posterior(
            "ensemble", np.exp(log_ei)[None, :], sigma[None, :], ar1=rho[None, :], **kw
        )
    return Posterior("ensemble", np.exp(log_ei)[None, :], sigma[None, :], **kw)


class _MixturePredictor:
    """Predictive draws split evenly over the members' own last-layer predictives."""

    def __init__(self, parts: list):
        self.parts = parts

    def __call__(
        self, x, t, quantity: str = "deflection", n_draws: int = 200, rng=None
    ) -> np.ndarray:
        rng = rng or np.random.default_rng(0)
        k = max(1, n_draws // len(self.parts))
        return np.concatenate([p(x, t, quantity, k, rng) for p in self.parts])
