"""What both B-PINN variants share: the deterministic warm-start fit, the last-layer model's potential in
(log theta, log sigma) with its MAP and Laplace factor, and the assembling of the posterior (R-hat, ESS,
the sampler's problems, identifiability, the last-layer self-check).

`bpinn` (last-layer: NUTS on log EI and log sigma) and `bpinn_full` (NUTS on every hidden weight too)
each import this module and neither imports the other; `bayespinn.methods.bpinn` picks the variant
(`resolve_variant`).
"""

from __future__ import annotations

import logging
import math
import time
import warnings

import numpy as np
import torch

from .. import seeding
from ..config import Config
from ..data.measurements import Measurements
from .conditioned import ConditionedLastLayer
from .lastlayer import LastLayer, identified, log_prior_z
from .nuts import laplace_factor, map_estimate, problems
from .pinn_ar1 import AR1Posterior
from .posterior import Posterior, mcmc_diagnostics
from .priors import EIPrior, NoisePrior, prior_only

log = logging.getLogger(__name__)

#: `--bpinn-variant` choices; 'auto' is `resolve_variant`'s rule
VARIANTS = ("auto", "last-layer", "full")


def resolve_variant(name: str, profile: str) -> str:
    """'last-layer' or 'full': 'auto' is the last-layer sampler for every profile and device; the full-weight
    one (`bpinn_full`) runs only when asked for (`--bpinn-variant full`).

    Why it is no default, measured: on an H100 (fast profile, 20 dB) one gradient of the full potential took
    0.086 s (0.17 s on the 2-core CPU; the small 5 x 64 network's fourth-order jets are launch-bound, not
    arithmetic-bound) and NUTS warm-up cut its step size to 2.4e-4, the third iteration taking 16 s, so the
    fast profile's 3 200 iterations would take hours on a GPU as well (~20 h at the tree-depth limit); it has
    never converged on the quick start, and the paper profile (16 832 hidden weights, 4 x 2000 iterations) is
    hours to days per run with no converged record. `profile` is kept for the callers' signature."""
    if name not in VARIANTS:
        raise ValueError(f"B-PINN variant must be one of {', '.join(VARIANTS)}, got {name!r}")
    del profile
    return "last-layer" if name == "auto" else name


class LastLayerPotential:
    """-log posterior of z = (log theta, log sigma[, atanh rho]); theta = EI / EI_ref before the beta
    correction, rho the AR(1) noise coefficient where the last-layer model has AR(1) noise (uniform prior on
    (-1, 1), `ar1.AR1Noise.log_prior`)."""

    def __init__(self, ll: LastLayer, ei_prior: EIPrior, noise: NoisePrior, log_shift: float):
        self.ll, self.ei_prior, self.noise, self.shift = ll, ei_prior, noise, log_shift

    def log_ei(self, log_theta):
        return log_theta + self.shift

    def log_prior(self, lt, ls):
        """log p(EI) + log p(sigma) in (log theta, log sigma), up to a constant."""
        lp = -0.5 * ((self.log_ei(lt) - self.ei_prior.loc) / self.ei_prior.log_sd) ** 2
        if self.noise.kind == "snr":
            lp = lp - 0.5 * ((ls - math.log(self.noise.center)) / self.noise.log_sd) ** 2
        # vague: log-uniform sigma, constant density; its bounds lie far outside any posterior mass
        return lp

    def __call__(self, params: dict) -> torch.Tensor:
        z = params["z"]
        lt, ls = z[0], z[1]
        if self.ll.ar1 is None:
            return -(self.ll.log_marginal(lt, ls) + self.log_prior(lt, ls))
        za = z[2]
        prior_rho = log_prior_z(za)
        return -(self.ll.log_marginal(lt, ls, za) + self.log_prior(lt, ls) + prior_rho)


def warm_start_fit(
    data: Measurements, cfg: Config, seed, profile: str, device: str, progress: bool, fit_seed=None
):
    """The deterministic PINN fit both variants start from: (fit result, problem, training settings,
    where it came from). On a CPU it is the deep ensemble's member 0 of its first phase (`shared_fit`):
    taken from the ensemble when it ran on these data in this process, else computed the same way.
    ``fit_seed`` is that fit's seed (`shared_fit.member_seed`); None: the B-PINN's own stream "init"."""
    from ..pinn import Problem, TrainSettings, fit
    from . import shared_fit

    settings = TrainSettings.for_profile(profile)
    problem = Problem.from_config(cfg, data)
    if fit_seed is None:
        fit_seed = seeding.stream(seed, "init")
    if str(device).startswith("cuda") or (str(device) == "auto" and torch.cuda.is_available()):
        log.info("[bpinn] deterministic warm-start fit on the GPU (%s profile)", profile)
        res = fit(problem, settings, seed=fit_seed, members=1, device=device, quiet=not progress)
        return res, problem, settings, "own fit (GPU)"
    k = shared_fit.key(problem, settings, fit_seed, 0)
    res = shared_fit.recall(k)
    if res is not None:
        log.info("[bpinn] warm start: the deep ensemble's member 0 fit on the same data (shared)")
        return res, problem, settings, "shared with the deep ensemble (its member 0)"
    log.info("[bpinn] deterministic warm-start fit (%s profile, one thread)", profile)
    res = shared_fit.member_fit(problem, settings, fit_seed, 0, quiet=not progress)
    shared_fit.remember(k, res)
    return res, problem, settings, "own fit (the deep ensemble's member 0, computed here)"


def fit_ei(res) -> float:
    """The fit's EI [N m^2] (a one-member fit holds it as an array of one)."""
    return float(np.ravel(res.EI)[0])


def no_data(cfg: Config, seed, t0: float) -> Posterior:
    """No measurements: the prior (`priors.prior_only`)."""
    log.warning("[bpinn] no measurements: EI is not identified, returning the prior")
    return prior_only(EIPrior.from_spec(cfg.prior), seed, t0, method="bpinn")


def log_shift(res, problem) -> float:
    """log EI - log theta: EI = EI_ref theta / beta_factor."""
    return math.log(problem.EI_ref) - math.log(res.beta_factor)


def last_layer_map(
    res,
    problem,
    data,
    seed,
    noise,
    settings,
    ei_prior,
    shift,
    vary_first_mode=None,
    ar1=None,
    conditioned=True,
):
    """The fit's last-layer model, its potential in (log theta, log sigma[, atanh rho]), the MAP there and the
    Laplace factor: (model, LastLayer, potential, z_map, L). With ``ar1`` (`ar1.AR1Noise` of the data) the
    noise is AR(1), its coefficient starting at the fit residuals' lag-1 autocorrelation. ``conditioned``:
    the model in a well-conditioned basis of its weights (`conditioned.ConditionedLastLayer`, the same model
    without the rounding noise that can make the potential too jagged for NUTS); False: the plain
    `LastLayer`, whose rows other hidden weights can replace (`LastLayer.with_rows`, the full variant)."""
    model = res.model("cpu")
    rng = np.random.default_rng(seeding.stream(seed, "collocation"))
    ll = (ConditionedLastLayer if conditioned else LastLayer)(
        model,
        0,
        problem,
        data,
        rng,
        n_pde=settings.n_pde,
        n_bc=settings.n_bc,
        n_ic=settings.n_ic,
        beta_rel=settings.beta_rel,
        images=settings.images,
        vary_first_mode=vary_first_mode,
        noise=ar1,
    )
    pot = LastLayerPotential(ll, ei_prior, noise, shift)
    sigma0 = max(math.sqrt(ll.fit_rss / max(ll.n, 1)), noise.low * 10)
    z0 = [math.log(ll.theta_fit), math.log(sigma0)]
    if ar1 is not None:
        z0.append(ll.z_start())
    z_map = map_estimate(pot, np.array(z0))
    return model, ll, pot, z_map, laplace_factor(pot, z_map)


#: a last-layer posterior further than this many of its own sds from the fit it linearises is flagged
MAX_MOVE_SD = 3.0


def assemble(
    draws: np.ndarray,
    diag: dict,
    pred,
    stats: dict,
    *,
    res,
    shift: float,
    ei_prior: EIPrior,
    variant: str,
    name: str,
    t0: float,
    warm_start: str = "own fit",
) -> Posterior:
    """The B-PINN posterior from z draws (chain, draw, 2) of (log theta, log sigma): R-hat/ESS, the sampler's
    problems, identifiability and, for the last-layer variant, how far the posterior moved from the fit it
    linearises (the problems and a move beyond `MAX_MOVE_SD` decide `converged`)."""
    log_ei = draws[:, :, 0] + shift
    EI, sigma = np.exp(log_ei), np.exp(draws[:, :, 1])
    rho = np.tanh(draws[:, :, 2]) if draws.shape[-1] > 2 else None
    diag = {**mcmc_diagnostics(EI), **diag}
    trouble = problems(diag)
    if rho is not None:  # the noise coefficient's chains must have mixed too
        diag["noise_ar1"] = mcmc_diagnostics(rho)
        trouble += [f"AR(1) coefficient: {p}" for p in problems(diag["noise_ar1"])]
    if trouble:
        msg = "B-PINN NUTS did not converge: " + "; ".join(trouble)
        warnings.warn(msg, RuntimeWarning, stacklevel=2)
    moved_msg = None
    if variant == "last-layer":
        # self-check: the last-layer posterior linearises around the fit; it must stay near it, or its
        # interval rests on features trained for another EI (the verdict then says not converged)
        moved = abs(float(log_ei.mean()) - math.log(fit_ei(res))) / max(float(log_ei.std()), 1e-12)
        diag["moved_from_fit_sd"] = moved
        if moved > MAX_MOVE_SD:
            moved_msg = (
                f"the last-layer posterior (EI mean {float(EI.mean()):.4g} N m^2) lies {moved:.1f} posterior sd "
                f"from the PINN fit it is built on ({fit_ei(res):.4g} N m^2): the network has not learnt the "
                "physics well enough for this approximation, so this interval is not trustworthy"
            )
            warnings.warn("B-PINN: " + moved_msg, RuntimeWarning, stacklevel=2)
            trouble.append(
                f"posterior {moved:.1f} sd from the fit it linearises (limit {MAX_MOVE_SD:g})"
            )
    converged = not trouble
    if trouble:
        diag["problems"] = trouble
    ident = identified(log_ei.ravel(), ei_prior)
    shared = warm_start.startswith("shared")
    diag.update(
        converged=converged,
        fit_EI=fit_ei(res),
        # the training this method spent itself (none when it shared the ensemble's fit)
        fit_runtime_s=0.0 if shared else res.runtime_s,
        warm_start=warm_start,
        warm_start_fit_s=res.runtime_s,
        beta_factor=res.beta_factor,
    )
    info = {"variant": name, "identified": ident}
    if not ident:
        info["note"] = "EI is not identified by these data"
    if moved_msg:
        info["warnings"] = [moved_msg]
    kw = dict(
        diagnostics=diag,
        info=info,
        runtime_s=time.perf_counter() - t0,
        predictor=pred,
        sample_stats=stats,
    )
    if rho is not None:
        return AR1Posterior("bpinn", EI, sigma, ar1=rho, **kw)
    return Posterior("bpinn", EI, sigma, **kw)
