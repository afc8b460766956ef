"""PINNs on real girders: EI per segment, rotational springs at the bearings, an uncertain axle-load factor;
and a smooth EI field, whose phi is the field's four coordinates read per piece (`uq.field_pinn`).

The network's output, in the units of `pinn.problem.Scales` (u = U w, x = L xi, t = T tau), is

    u(x, t) = c_E E(x, t; phi) + U sum_j c_j N_j(xi, tau),

phi = (log EI per segment, log k per support when `supports = "springs"`, log load factor when inferred).

* **The enrichment E** is the girder's own moving-load response at phi for the stated axle loads (load factor
  1): the finite-element modal model of "Real girders I" (`physics.fe_modal.GirderModalModel`: modes of the
  FE eigenproblem of the girder with these segment EIs and springs, a static correction for the truncated
  ones). It is the generalisation of the uniform girder's enrichment (`pinn.enrich`: the forced moving-load
  response and the tied free vibrations of a pinned, uniform beam), and it assumes neither pins nor a uniform
  EI: it is recomputed at every phi tried. Its coefficient c_E is free. E solves the girder's equation
  (EI(x) E_xx)_xx + mu E_tt = f with the stated loads f, meets the support conditions and starts at rest,
  so its contribution to those residuals is exact: (c_E - lambda) f in the PDE rows (lambda the load
  factor), and nothing in the boundary and initial rows. Only its values at the data are computed (by the
  modal model; their derivatives in phi by central differences, `_EColumn`).
* **The network N** (tanh MLP of (xi, tau), the hidden layers trained, the output layer c solved by least
  squares at every step: variable projection, as `pinn.varpro`) carries what the enrichment does not. Its
  physics is the girder's, with stiffness along the span:

      (EI(x) N_xx)_xx = sum_s EI_s (chi_s N_xxxx + 2 chi_s' N_xxx + chi_s'' N_xx),

  chi_s the smoothed indicator of segment s (logistic steps at the segment edges, of width the Gaussian
  load's, `EDGE_WIDTH_REL` L, the resolution at which the PINN's PDE sees a point load; the chi_s sum to 1
  exactly), and the supports' conditions u = 0 and EI u_xx -/+ k u_x = 0 at the left / right end
  (pinned: EI u_xx = 0), written as (EI w_xixi -/+ kappa w_xi) / (EI + kappa) with kappa = k L / EI_ref so the
  row stays O(1) from a pin to a clamp. Every residual is linear in the output weights (c, c_E), so each
  term is a Gram matrix assembled from precomputed pieces at any phi (`Pieces`, `assemble`).

Training (`train_fit`): phi starts at the enrichment-only least-squares fit (the FE model alone: c = 0,
c_E = lambda); the hidden layers are trained by Adam on the sum of squares of the scaled residuals at the
solved output layer (data / sigma_0, physics rows / `TRAIN_PHYSICS_SD`); every `theta_every` steps phi is
re-solved by L-BFGS on the reduced objective (the output layer profiled out) plus minus the log prior.

The last layer (`GirderLastLayer`): with the hidden layers fixed, the output weights are integrated out
exactly, as in `uq.lastlayer` (Gaussian data rows y ~ N(D(phi) c, sigma^2), physics pseudo-observations
with sds from the fit's RMS residuals, `girder_lastlayer.GIRDER_PDE_SD_FACTOR` for the PDE rows, weight prior N(0, s_w^2) with s_w
`WEIGHT_PRIOR_FACTOR` times the largest fitted weight), giving log p(y | phi, sigma) exactly. The physics
rows and the weight prior enter as the output layer's *normalised* prior given phi (`log_marginal`): counted
as observations, their precision's determinant (the PDE rows scale as EI_s^2) and their own best residual
would inform phi through the network's approximation error rather than through the data.

The B-PINN (last-layer variant) runs NUTS on (phi, log sigma) in whitened coordinates (`uq.nuts`). The deep
ensemble trains M networks from their own starts, samples each member's exact last-layer posterior by
adaptive multiple importance sampling (`uq.girder_sampling`: multivariate t proposals, the first at twice
the Laplace sd, each next at the weighted moments of every draw so far, every draw weighted against the
mixture of all proposals; the effective sample size is reported and checked), and pools the members in
equal shares, so the spread between the networks adds to each one's width. Not randomise-then-optimise, as on the uniform girder (`uq.ensemble`): with five segments the
posterior of log EI is far from Gaussian (the segments next to the supports are skewed, the Laplace sd of
the middle ones 0.4x the reference's), and uncorrected randomise-then-optimise draws on the last layer gave
sds 0.56-0.71x the reference's (smoke profile, damaged Exeter girder at 30 dB, 20 draws per member).

AR(1) noise (`[model] noise = "ar1"`): the network is trained as for white noise (a point fit), and its last
layer whitens the data rows along each sensor's series at the coefficient rho (`uq.girder_lastlayer`), so
both samplers draw (phi, log sigma, atanh rho) from the exact last-layer posterior, as the reference does.

What this does not do: damping in the network's PDE rows (the enrichment carries the girder's modal damping;
the correction N is undamped).
"""

from __future__ import annotations

import functools
import logging
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from .. import seeding
from ..config import Config
from ..data.measurements import Measurements
from ..errors import InputError
from ..threads import one_blas_thread, torch_threads
from .ar1 import AR1Noise
from .ensemble_pool import MAX_SCATTER_RATIO
from .field_pinn import NAMES as FIELD_NAMES
from .field_pinn import FieldGirderProblem, make_problem
from .field_reference import FieldReference, field_result
from .girder_lastlayer import GirderLastLayer, split_z
from .girder_net import (
    GirderNetSettings,
    GirderProblem,
    train_fit,
)
from .girder_posterior import GirderPosterior
from .girder_reference import GirderPredictor, GirderReference, check_segments
from .girder_sampling import importance_sample, other_modes
from .posterior import mcmc_diagnostics
from .sampler import ESS_MIN

log = logging.getLogger(__name__)


def member_fit_seed(ensemble_seed, m: int) -> np.random.SeedSequence:
    """The seed of the deep ensemble's member m network (the last-layer B-PINN trains member 0's)."""
    return seeding.child(ensemble_seed, "init", m)


def check_girder(cfg: Config, data: Measurements, display: str) -> None:
    """Refuse what the girder PINN does not describe (exit 2, naming the field): what a crossing leaves to
    infer (a speed, an entry time, damping, fluctuating forces, several crossings: it takes the crossing as
    stated), too many segments for the data, and what a smooth EI field's reference does not describe."""
    from ..crossings.checks import refuse_crossings

    refuse_crossings(cfg, data, display)
    if cfg.model.EI_field == "smooth":
        from .girder_field import check_field

        return check_field(cfg, data)
    if cfg.model.noise not in ("iid", "ar1"):
        raise InputError("model.noise", cfg.model.noise, f"'iid' or 'ar1' for the {display}")
    check_segments(cfg, data)


def _noise(cfg: Config, data: Measurements) -> AR1Noise | None:
    """The AR(1) series of the data when the analysis model's noise is AR(1), else None (white noise)."""
    return AR1Noise.of(data) if cfg.model.noise == "ar1" else None


# --------------------------------------------------------------------------------------------------
# posteriors


def _posterior(
    problem: GirderProblem,
    ar1: bool,
    z: np.ndarray,
    method: str,
    diagnostics: dict,
    info: dict,
    runtime: float,
) -> GirderReference:
    """The pipeline's Posterior of draws z (chain, draw, dim): phi, log sigma (and atanh rho when `ar1`)."""
    if isinstance(problem, FieldGirderProblem):
        return _field_posterior(problem, z, method, diagnostics, info, runtime)
    lay = problem.layout
    phi, log_sigma, zeta = split_z(z, problem.dim, ar1)
    sigma = np.exp(log_sigma)
    gp = GirderPosterior(
        EI_segments=np.exp(phi[..., : lay.n_segments]),
        rotational_stiffness=np.exp(phi[..., lay.springs]) if lay.infer_springs else None,
        load_factor=np.exp(phi[..., lay.load]) if lay.infer_load else None,
        sigma=sigma,
        noise_ar1=None if zeta is None else np.tanh(zeta),
        edges=np.linspace(0.0, problem.L, lay.n_segments + 1),
        EI_nominal=problem.nominal,
        diagnostics=diagnostics,
        info=info,
        runtime_s=runtime,
        method=method,
    )
    return GirderReference(
        method,
        gp.EI,
        gp.sigma,
        diagnostics=diagnostics,
        info={"EI_nominal": gp.EI_nominal, **info},
        runtime_s=runtime,
        predictor=GirderPredictor(problem.cfg, gp),
        girder=gp,
    )


def _field_posterior(
    problem: FieldGirderProblem, z: np.ndarray, method: str, diagnostics: dict, info: dict, runtime
) -> FieldReference:
    """The pipeline's Posterior of a smooth field's draws z (chain, draw, 5): theta, log sigma."""
    phi, log_sigma, _ = split_z(z, problem.dim, False)
    fp = problem.field_posterior(
        phi.reshape(-1, problem.dim), np.exp(log_sigma).ravel(), diagnostics, runtime
    )
    return field_result(method, problem.cfg, fp, info)


def _inner(post):
    """The method-level posterior a pipeline Posterior carries: the girder's or the smooth field's."""
    return post.field if isinstance(post, FieldReference) else post.girder


def _draws(problem: GirderProblem, post, z: np.ndarray) -> dict[str, np.ndarray]:
    """Named draws (chain, draw) for the convergence diagnostics: a girder's parameters, or a smooth
    field's coordinates theta and log sigma."""
    if isinstance(problem, FieldGirderProblem):
        return {n: z[..., i] for i, n in enumerate((*FIELD_NAMES, "log_sigma"))}
    return post.girder.draws()


def _info(problem: GirderProblem, settings: GirderNetSettings, ll: GirderLastLayer | None) -> dict:
    model = {
        "EI_segments": problem.S,
        "supports": problem.cfg.model.supports,
        "load_factor": "inferred" if problem.infer_load else "fixed at 1",
        "noise": problem.cfg.model.noise,
    }
    if isinstance(problem, FieldGirderProblem):
        model = {"EI_field": "smooth", "pieces": problem.S, "noise": problem.cfg.model.noise}
    out: dict[str, Any] = {
        "model": model,
        "network": (
            f"{settings.depth} x {settings.width} tanh, enriched with the girder's FE modal response "
            f"({problem.n_modes} modes and a static correction) at the current parameters"
        ),
        "enrichment_modes": problem.n_modes,
        "steps": settings.steps,
    }
    if ll is not None:
        out["pseudo_sd"] = {"pde": ll.s_f, "bc": ll.s_b, "ic": ll.s_i, "weights": ll.s_w}
    return out


def _one_thread(fn):
    """Run fn with one torch and one BLAS thread: its small dense algebra is fastest so, and its numbers are
    then the same function of the seed whatever the machine's thread count (`bayespinn.threads`)."""

    @functools.wraps(fn)
    @one_blas_thread
    def wrapper(*args, **kwargs):
        with torch_threads(1):
            return fn(*args, **kwargs)

    return wrapper


@dataclass(frozen=True)
class _Member:
    """One deep-ensemble member on a girder, an executor task: its result is a function of its fit seed."""

    problem: GirderProblem
    settings: GirderNetSettings
    seed: object  # the member's fit seed (`member_fit_seed`)
    noise: AR1Noise | None


def _run_member(t: _Member) -> tuple[np.ndarray, dict]:
    """(draws of z (draw, dim), info) of one member: its network trained, its last-layer posterior sampled
    by adaptive importance sampling."""
    fit = train_fit(t.problem, t.settings, t.seed)  # quiet: the pool's bar shows the members
    ll = GirderLastLayer(t.problem, fit, t.settings, seeding.stream(t.seed, "collocation"), t.noise)
    zmap = ll.map(ll.start(fit.phi))
    cov = ll.covariance(zmap)
    Z, is_info = importance_sample(
        ll, zmap, cov, seeding.rng(t.seed, "noise"), t.settings, other_modes(t.problem, zmap, cov)
    )
    k = t.problem.dim
    return Z, {
        "phi_mean": Z[:, :k].mean(0).tolist(),
        "phi_sd": Z[:, :k].std(0, ddof=1).tolist(),
        "sigma": float(np.exp(np.median(ll.split(Z)[1]))),
        "network_share": ll.network_share,
        "train_s": fit.seconds,
        **is_info,
    }


@_one_thread
def girder_ensemble_posterior(
    data: Measurements,
    cfg: Config,
    *,
    seed,
    members: int = 5,
    profile: str = "fast",
    progress: bool = False,
    executor=None,
) -> GirderReference:
    """Deep ensemble on a real girder: M networks from their own starts, as tasks of `executor` (default: the
    local pool, one process per core); each member's exact last-layer posterior of (phi, log sigma[, atanh
    rho]) sampled by adaptive importance sampling; the members pooled in equal shares (module docstring)."""
    from ..executor import Executor, task_resources

    t0 = time.perf_counter()
    settings = GirderNetSettings.for_profile(profile)
    problem = make_problem(data, cfg)
    noise = _noise(cfg, data)
    tasks = [_Member(problem, settings, member_fit_seed(seed, m), noise) for m in range(members)]
    res = (executor or Executor()).map(
        _run_member,
        tasks,
        desc="ensemble members",
        progress=progress,
        resources=task_resources("cpu"),
    )
    draws, member_info = [z for z, _ in res], [i for _, i in res]
    for m, i in enumerate(member_info):
        log.info(
            "[ensemble] member %d/%d: phi %s (importance ESS %.0f)",
            m + 1,
            members,
            ", ".join(f"{e:.4g}" for e in i["phi_mean"]),
            i["ess"],
        )
    th = np.stack(draws)  # (member, draw, dim)
    # members' scatter of their means against their own widths (the uniform girder's `MAX_SCATTER_RATIO`)
    means, sds = th.mean(1), th.std(1, ddof=1)
    ratio = float(np.max(means.std(0, ddof=1) / np.mean(sds, 0))) if members > 1 else 0.0
    min_ess = min(i["ess"] for i in member_info)
    diagnostics = {
        "members": members,
        "scatter_ratio": ratio,
        "importance_ess_min": min_ess,
        "converged": bool(ratio <= MAX_SCATTER_RATIO and min_ess >= ESS_MIN),
        "scheme": "each member's last-layer posterior by adaptive importance sampling; members pooled",
    }
    shares = [i["network_share"] for i in member_info]
    info = _info(problem, settings, None) | {
        # the median, as the uniform girder's pooling reports it
        "network_share": float(np.median(shares)),
        "member_network_share": shares,
        "members": member_info,
    }
    return _posterior(
        problem,
        noise is not None,
        th.reshape(1, -1, th.shape[-1]),
        "ensemble",
        diagnostics,
        info,
        time.perf_counter() - t0,
    )


class GirderPotential:
    """-log posterior of a girder last layer at params["z"], +inf outside the prior's support: the potential
    of the B-PINN's NUTS chains (a class, so a chain can be a task of a process pool)."""

    def __init__(self, ll: GirderLastLayer):
        self.ll = ll

    def __call__(self, params: dict) -> torch.Tensor:
        z = params["z"]
        if not self.ll.inside(z.detach().numpy()):
            return torch.as_tensor(math.inf, dtype=torch.float64) + (z * 0).sum()
        return -self.ll.log_post(z)


@_one_thread
def girder_bpinn_posterior(
    data: Measurements,
    cfg: Config,
    *,
    seed,
    profile: str = "fast",
    fit_seed=None,
    progress: bool = False,
    executor=None,
) -> GirderReference:
    """Last-layer B-PINN on a real girder: NUTS on (phi, log sigma[, atanh rho]), output layer integrated out;
    the chains run as tasks of `executor` (the uniform girder's runner, `uq.bpinn.nuts`: each chain from a
    dispersed start on its own seed, single-threaded, so the draws do not depend on the executor)."""
    from .bpinn import nuts as run_chains
    from .nuts import NUTSSettings, nuts_health, problems, sample_stats

    t0 = time.perf_counter()
    settings = GirderNetSettings.for_profile(profile)
    problem = make_problem(data, cfg)
    fs = fit_seed if fit_seed is not None else member_fit_seed(seeding.stream(seed, "ensemble"), 0)
    fit = train_fit(problem, settings, fs, progress)
    ll = GirderLastLayer(
        problem, fit, settings, seeding.stream(fs, "collocation"), _noise(cfg, data)
    )
    zmap = ll.map(ll.start(fit.phi))
    Lc = np.linalg.cholesky(ll.covariance(zmap))
    ns = NUTSSettings.for_profile(profile)
    z, chains = run_chains(GirderPotential(ll), zmap, Lc, ns, seed, progress, executor)
    post = _posterior(problem, ll.ar1 is not None, z, "bpinn", {}, {}, 0.0)
    per = {name: mcmc_diagnostics(d) for name, d in _draws(problem, post, z).items()}
    health = nuts_health(chains)
    diag = {
        "rhat": max(v["rhat"] for v in per.values()),
        "ess_bulk": min(v["ess_bulk"] for v in per.values()),
        "ess_tail": min(v["ess_tail"] for v in per.values()),
        "per_parameter": per,
        **health,
        "variant": "last-layer",
    }
    why = problems(diag)
    diag["converged"] = not why
    diag["problems"] = why
    info = _info(problem, settings, ll) | {
        "variant": "last-layer",
        "fit_s": fit.seconds,
        "network_share": ll.network_share,  # of the fit the posterior is built on
    }
    inner = _inner(post)
    inner.diagnostics = diag
    if hasattr(inner, "info"):
        inner.info = info
    post.diagnostics = diag
    post.info = {"EI_nominal": problem.nominal, **info}
    post.sample_stats = sample_stats(chains)
    post.runtime_s = inner.runtime_s = time.perf_counter() - t0
    return post


__all__ = [
    "GirderNetSettings",
    "check_girder",
    "girder_bpinn_posterior",
    "girder_ensemble_posterior",
]
