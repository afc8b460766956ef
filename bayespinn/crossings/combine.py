"""Many crossings with fluctuating forces: each crossing analysed on its own, EI combined through a
crossing-level error.

One model of every crossing's nuisances at once carries about four parameters per crossing besides the
shared ones, and its exact posterior (importance-sampled where the linearisation fails) does not finish for
ten crossings on a laptop. EI is the girder property the crossings share; each crossing keeps its own speed,
entry time, suspension, damping ratio, force law and noise level (a lorry's road, tyres and the day's
temperature differ from crossing to crossing). The posterior then factorises,

    p(EI | y_1 .. y_J) ∝ p(EI) prod_i L_i(EI),     L_i(EI) = p_i(EI | y_i) / p(EI),

with p_i crossing i's own posterior, so the crossings are analysed independently (in parallel, and a new
crossing adds one analysis, not a new joint one).

A crossing-level error. Each crossing's analysis model is an approximation (its force spectrum, its timing):
on simulated crossings the single-crossing answers disagree by more than their own sds (docs/methods.md), and
a plain product would be over-confident by the square root of the number of crossings. So crossing i
informs EI_i = EI + delta_i, delta_i ~ N(0, tau^2) on log EI, with tau inferred under a half-Cauchy prior
(Gelman 2006, "Prior distributions for variance parameters in hierarchical models") whose scale is the
median of the crossings' own posterior sds of log EI: a crossing-level error of the order of one crossing's
uncertainty a priori. Crossings that agree leave tau near 0 and EI near the product; crossings that disagree
widen EI's interval. tau is reported (`crossing_error`, on log EI: a relative error).

Numerics: L_i is a Gaussian kernel density of crossing i's log EI draws weighted by 1 / p(EI), binned to
`N_BINS` components, convolved with N(0, tau^2) in closed form; (log EI, tau) on a grid; equal-weight draws
from the grid. Each crossing's own draws (its nuisances) are resampled by p(EI_i = draw | the other
crossings) / p(EI_i): its posterior within the combined analysis.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
from scipy.signal import fftconvolve
from scipy.special import logsumexp

from .. import seeding
from ..data.measurements import Measurements
from ..uq.priors import EIPrior

#: components of each crossing's binned kernel density; points of tau's grid; the grid's last tau in
#: units of the prior's scale (the half-Cauchy's mass beyond it: 2 / (pi TAU_MAX) = 1.3 %)
N_BINS, N_TAU, TAU_MAX = 120, 48, 50.0
#: log EI grid: step a sixth of the narrowest crossing's sd, at most MAX_GRID points
GRID_PER_SD, MAX_GRID = 6.0, 6000
#: equal-weight draws of the combined posterior, laid out as OUT_CHAINS rows (a layout, not chains)
N_OUT, OUT_CHAINS = 4000, 4


@dataclasses.dataclass
class Combination:
    """The combined posterior on its grid: log EI grid x, tau grid, log p(x, tau) per cell (mass), and
    each crossing's log L_i(x | tau)."""

    x: np.ndarray
    tau: np.ndarray
    log_mass: np.ndarray  # (n_tau, n_x), normalised
    log_lik: list  # per crossing (n_tau, n_x)
    prior: EIPrior
    tau_scale: float

    def draws(self, rng: np.random.Generator, n: int = N_OUT) -> tuple[np.ndarray, np.ndarray]:
        """n equal-weight draws of (log EI, tau): grid cells by their mass, log EI jittered in its cell."""
        p = np.exp(self.log_mass.ravel())
        cell = rng.choice(p.size, size=n, p=p / p.sum())
        j, k = np.unravel_index(cell, self.log_mass.shape)
        dx = self.x[1] - self.x[0]
        return self.x[k] + dx * (rng.random(n) - 0.5), self.tau[j]

    def predictive_weights(self, i: int, u: np.ndarray) -> np.ndarray:
        """Weights p(EI_i = u | the other crossings) / p(u) for crossing i's own draws u (log EI)."""
        lm = self.log_mass - self.log_lik[i]
        lm = np.where(np.isfinite(lm), lm, -np.inf)
        m = np.exp(lm - lm.max())  # (n_tau, n_x): the other crossings' posterior of (EI, tau)
        dx = self.x[1] - self.x[0]
        dens = np.zeros_like(self.x)
        for j, t in enumerate(self.tau):
            if t < dx / 4:
                dens += m[j] / dx
                continue
            half = min(int(math.ceil(6 * t / dx)), self.x.size)
            g = np.arange(-half, half + 1) * dx
            kern = np.exp(-0.5 * (g / t) ** 2) / (t * math.sqrt(2 * math.pi))
            dens += fftconvolve(m[j], kern, mode="same")
        pred = np.interp(u, self.x, np.clip(dens, 0.0, None), left=0.0, right=0.0)
        w = pred * np.exp(-self.prior.logpdf(u) + self.prior.logpdf(np.median(u)))
        return w


def _components(u: np.ndarray, prior: EIPrior) -> tuple[np.ndarray, np.ndarray, float]:
    """Crossing draws u (log EI) as a binned kernel density of L = p_i / p: centres, log weights and
    each component's variance (Silverman's bandwidth squared plus the bin's own spread)."""
    u = np.asarray(u, float).ravel()
    sd = float(np.std(u))
    h = 1.06 * sd * u.size ** (-0.2)
    edges = np.linspace(u.min() - 1e-12, u.max() + 1e-12, N_BINS + 1)
    w = np.exp(-(prior.logpdf(u) - prior.logpdf(np.median(u))))
    mass, _ = np.histogram(u, bins=edges, weights=w)
    keep = mass > 0
    centres = 0.5 * (edges[1:] + edges[:-1])[keep]
    bw = edges[1] - edges[0]
    return centres, np.log(mass[keep] / mass.sum()), h * h + bw * bw / 12.0


def combine(draws: list[np.ndarray], prior: EIPrior, crossing_error: bool = True) -> Combination:
    """The combined posterior of log EI and the crossing-level error tau (module docstring), from each
    crossing's posterior draws of log EI; without `crossing_error`, tau = 0: the plain product."""
    means = np.array([float(np.mean(u)) for u in draws])
    sds = np.array([float(np.std(u)) for u in draws])
    if not np.all(sds > 0):
        raise ValueError("a crossing's posterior of EI has no spread")
    J = len(draws)
    c = float(np.median(sds))
    if crossing_error:
        tau = np.concatenate([[0.0], c * np.geomspace(1e-2, TAU_MAX, N_TAU - 1)])
        # tau's prior mass per grid point: the half-Cauchy's density times the trapezoid weights
        dt = np.gradient(tau)
        log_ptau = np.log(2.0 / (math.pi * c * (1.0 + (tau / c) ** 2))) + np.log(dt)
    else:
        tau, log_ptau = np.zeros(1), np.zeros(1)
    centre = float(np.median(means))
    half = (
        float(np.max(np.abs(means - centre)))
        + 8.0 * float(sds.max())
        + 5.0 * math.sqrt((tau[-1] ** 2 + float(sds.max()) ** 2) / J)
    )
    step = max(float(sds.min()) / GRID_PER_SD, 2 * half / MAX_GRID)
    x = np.arange(centre - half, centre + half + step / 2, step)
    log_lik = []
    total = prior.logpdf(x)[None, :] + log_ptau[:, None] + math.log(step)
    for u in draws:
        mu, lw, v = _components(u, prior)
        V = v + tau[:, None, None] ** 2  # (n_tau, 1, 1)
        d = x[None, :, None] - mu[None, None, :]
        ll = logsumexp(lw - 0.5 * d * d / V - 0.5 * np.log(2 * math.pi * V), axis=2)
        log_lik.append(ll)
        total = total + ll
    total = total - logsumexp(total)
    return Combination(x, tau, total, log_lik, prior, c)


def _resample(w: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Systematic resampling: n indices with probabilities w (an equal-weight layout if w is all zero)."""
    w = np.asarray(w, float)
    if not np.isfinite(w).all() or w.sum() <= 0:
        w = np.ones_like(w)
    c = np.cumsum(w / w.sum())
    return np.minimum(np.searchsorted(c, (rng.random() + np.arange(n)) / n), w.size - 1)


class CombinedPredictor:
    """Each crossing's rows predicted by that crossing's own analysis (the `Posterior.predictor` contract);
    points that are not a crossing's own rows are predicted by the first crossing's."""

    def __init__(self, singles: list, data: Measurements, rows: list[np.ndarray]):
        from .predictor import CrossingRows

        self.singles = singles
        self.rows = CrossingRows(data, rows)
        self.n = min(int(s.EI.size) for s in singles)

    def __call__(self, x, t, quantity: str = "deflection", n_draws: int = 200, rng=None):
        rng = rng or np.random.default_rng(0)
        x, t = np.broadcast_arrays(np.asarray(x, float).ravel(), np.asarray(t, float).ravel())
        which = self.rows.of(x, t, "deflection" if quantity == "deflection" else "curvature")
        out = None
        for i in np.unique(which):
            sel = which == i
            seed = int(rng.integers(2**31))
            part = self.singles[int(i)].predictor(
                x[sel], t[sel], quantity, n_draws, np.random.default_rng(seed)
            )
            if out is None:
                out = np.empty((part.shape[0], x.size))
            out[:, sel] = part
        return out


def combined_reference(data: Measurements, cfg, *, seed, settings, progress: bool, single):
    """Each crossing of `data` by `single(sub_data, sub_cfg, seed)` (a one-crossing reference), in
    parallel, then EI combined (module docstring): a `result.CrossingsReference`."""
    import multiprocessing as mp

    from ..executor import Executor, cpu_count
    from .checks import split_crossings
    from .predictor import fit_check_on_rows
    from .result import CrossingsReference

    t_start = time.perf_counter()
    parts = split_crossings(cfg, data)
    tables = {c.name: c for c in cfg.crossings}
    tasks = []
    for j, (name, rows, _veh) in enumerate(parts):
        sub = data.select(np.isin(np.arange(len(data)), rows))
        sub_cfg = dataclasses.replace(cfg, crossings=(tables[name],))
        tasks.append((single, sub, sub_cfg, seeding.child(seed, "emcee", 9400 + j), settings))
    # one process per core; inside a pool's worker (a daemon may not start processes) one at a time
    workers = 1 if mp.current_process().daemon else min(cpu_count(), len(tasks))
    singles = Executor(workers=workers).map(_run_single, tasks, desc="crossings", progress=progress)
    prior = EIPrior.from_spec(cfg.prior)
    logs = [np.log(s.EI.ravel()) for s in singles]
    comb = combine(logs, prior)
    rng = np.random.default_rng(seeding.child(seed, "emcee", 9401))
    lei, tau = comb.draws(rng)
    shape = (OUT_CHAINS, N_OUT // OUT_CHAINS)
    nuisance: dict = {"crossings": {}, "crossing_error": tau.reshape(shape)}
    pooled: dict = {}
    sig2 = np.zeros(N_OUT)
    n_tot = 0
    fit_checks, problems = {}, []
    for i, ((name, rows, _), s) in enumerate(zip(parts, singles, strict=True)):
        idx = _resample(comb.predictive_weights(i, logs[i]), N_OUT, rng)
        own = {}
        for k, v in s.nuisance.items():
            if k == "crossings":
                for kk, vv in v.get(name, {}).items():
                    own[kk] = np.asarray(vv).ravel()[idx].reshape(shape)
            else:
                own[k] = np.asarray(v).ravel()[idx].reshape(shape)
                pooled.setdefault(k, []).append(own[k])
        own["EI"] = s.EI.ravel()[idx].reshape(shape)
        nuisance["crossings"][name] = own
        sig2 += len(rows) * s.sigma.ravel()[idx] ** 2
        n_tot += len(rows)
        fc = fit_check_on_rows(s, data, rows, cfg)
        if fc is not None:
            fit_checks[name] = fc
        for p in s.diagnostics.get("problems", []):
            problems.append(f"{name}: {p}")
    # the per-crossing nuisances pooled (draw d from crossing d mod J): a crossing's value at random
    J = len(parts)
    pick = np.arange(N_OUT) % J
    for k, arrs in pooled.items():
        stack = np.stack([a.ravel() for a in arrs])
        nuisance[k] = stack[pick, np.arange(N_OUT)].reshape(shape)
    diag = {
        "converged": not problems,
        "problems": problems,
        "rhat": None,
        "ess_bulk": min(float(s.diagnostics.get("ess_bulk") or 0.0) for s in singles),
        "ess_tail": min(float(s.diagnostics.get("ess_tail") or 0.0) for s in singles),
        "scheme": (
            "each crossing's reference on its own (its own damping, force law and noise), EI combined "
            "with a crossing-level error tau (half-Cauchy prior) on a grid of (log EI, tau)"
        ),
        "crossing_runtime_s": [float(s.runtime_s) for s in singles],
        "crossing_schemes": [s.diagnostics.get("scheme") for s in singles],
        "grid_points": [int(comb.tau.size), int(comb.x.size)],
        "crossing_error_prior_scale": comb.tau_scale,
    }
    out = CrossingsReference(
        singles[0].method, np.exp(lei).reshape(shape), np.sqrt(sig2 / n_tot).reshape(shape),
        diagnostics=diag, info={"crossing_fit_checks": fit_checks},
        predictor=CombinedPredictor(singles, data, [p[1] for p in parts]),
        nuisance=nuisance, crossing_names=tuple(p[0] for p in parts),
    )  # fmt: skip
    out.runtime_s = time.perf_counter() - t_start
    return out


def _run_single(task):
    single, sub, sub_cfg, seed, settings = task
    return single(sub, sub_cfg, seed=seed, settings=settings, progress=False, fit_checks=False)
