"""The linearised crossing posterior's hyperparameters h = (log s, log l, log sigma and, for sprung
vehicles, the suspension's): their log posterior under the linearisation (exact evidence, `linearised`),
its maximum, the curvature's sds there, and their sampler, adaptive multiple importance sampling
(`importance.amis`) with emcee as the caller's fallback. Every function takes `lin`, a
`linearised.Linearisation` (not imported here: `linearised` imports this module)."""

from __future__ import annotations

import math

import numpy as np

from .curvature import curvature_sds

#: the importance sampler: draws of its first proposal's guide (about the maximum, with the curvature's
#: sds) and the rows its equal-weight draws are laid out in (a layout, not chains)
HYPER_GUIDE, HYPER_CHAINS = 2000, 4


def hyper_maximum(lin, start: np.ndarray) -> np.ndarray:
    """The hyperparameters' maximum of log prior + log evidence under the linearisation."""
    from scipy.optimize import minimize

    def f(z):
        v = float(log_hyper_posterior(lin, z[None])[0])
        return -v if np.isfinite(v) else 1e300

    res = minimize(
        f, start, method="Nelder-Mead", options={"xatol": 1e-4, "fatol": 1e-4, "maxiter": 600}
    )
    return res.x if res.fun < f(start) else np.asarray(start, float)


def log_hyper_posterior(lin, hyper: np.ndarray) -> np.ndarray:
    """log p(h) + log p_lin(y | h) (the priors of `likelihood.CrossingsLogPosterior` on h)."""
    hyper = np.atleast_2d(hyper)
    full = np.repeat(lin.theta[None], hyper.shape[0], 0)
    full[:, lin.hyper] = hyper
    lp = np.where(lin.inside(hyper), lin.post.log_prior(full), -np.inf)
    out = np.full(hyper.shape[0], -np.inf)
    ok = np.isfinite(lp)
    if ok.any():
        out[ok] = lp[ok] + lin.log_evidence(hyper[ok])
    return out


def hyper_importance(lin, h: np.ndarray, scale: np.ndarray, seed, progress):
    """The hyperparameters' linearised posterior by adaptive multiple importance sampling
    (`importance.amis`) from a multivariate t about their maximum h with the curvature's sds `scale`.
    The density is exact and cheap and has three to six dimensions, so a few rounds of a few hundred
    evaluations reach the importance sampler's ESS and Pareto k-hat criterion, where emcee's run-length
    rule asks for tens of thousands. Returns equal-weight draws as `Chains` (a layout of
    `HYPER_CHAINS` rows, not independent chains) and the sampler's diagnostics; (None, diagnostics)
    when the criterion is not met (the caller then runs emcee)."""
    from .. import seeding
    from ..uq.sampler import Chains
    from .importance import amis

    rng = np.random.default_rng(seeding.child(seed, "emcee", 9050))
    guide = h[None] + scale[None] * rng.standard_normal((HYPER_GUIDE, h.size))
    z, lp, info = amis(lambda u: log_hyper_posterior(lin, u), guide, rng, progress)
    info = {k: v for k, v in info.items() if k != "history"}
    if not info["passed"]:
        return None, info
    shape = (HYPER_CHAINS, z.shape[0] // HYPER_CHAINS)
    ch = Chains(
        draws=z.reshape(*shape, h.size), tau=None, steps=0, acceptance=None, lp=lp.reshape(shape)
    )
    return ch, info


def conditional_sd(lin, h: np.ndarray) -> np.ndarray:
    """theta's conditional sds given h, from 64 conditional draws (zero for the hyperparameters)."""
    rng = np.random.default_rng(0)
    d = lin.conditional(np.repeat(h[None], 64, 0), rng)
    sd = d.std(axis=0)
    sd[lin.hyper] = 0.0
    return sd


def hyper_scale(lin, h: np.ndarray) -> np.ndarray:
    """sds of h from the curvature of its log posterior at the maximum (`curvature.curvature_sds`)."""
    step = np.array([1e-2, 1e-2, 1e-3] + [1e-2] * (h.size - 3))
    sd = curvature_sds(lambda p: -log_hyper_posterior(lin, p), h, step)
    if sd is not None:
        return sd
    return np.array([0.3, 0.3, 1.0 / math.sqrt(2 * lin.n)] + [0.1] * (h.size - 3))
