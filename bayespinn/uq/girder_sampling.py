"""A girder-PINN member's sampler of its exact last-layer posterior (`uq.girder_pinn`'s deep ensemble):
adaptive multiple importance sampling, the smooth field reference's (`field_search.amis`), started at the
member's MAP and, for a smooth field, at every other posterior mode the reference's search finds."""

from __future__ import annotations

import numpy as np

from .girder_lastlayer import GirderLastLayer
from .girder_problem import GirderProblem

#: adaptive importance sampling of a member's last-layer posterior (`importance_sample`): the first
#: proposal's scale on the Laplace covariance (the posterior of a segment next to a support is skewed and up
#: to twice the Laplace width)
IS_INFLATE = 2.0
#: and the most rounds it may take (twice the smooth field reference's: one member's posterior on the smooth
#: loss, whose far flank is heavy-tailed, had an effective sample size of 308 after 10 rounds)
IS_MAX_ROUNDS = 20


def importance_sample(
    ll: GirderLastLayer,
    z_map: np.ndarray,
    cov: np.ndarray,
    rng: np.random.Generator,
    settings,
    others: tuple = (),
) -> tuple[np.ndarray, dict]:
    """Draws of one member's exact last-layer posterior by adaptive multiple importance sampling, the smooth
    field reference's sampler (`field_search.amis`): multivariate t proposals, the first at the Laplace
    covariance times `IS_INFLATE^2`, each next at the tempered weighted moments of every draw so far, every
    draw weighted against the mixture of all proposals; at least `field_search.AMIS_ROUNDS` rounds, then
    until the effective sample size reaches the convergence verdict's `ESS_MIN` (at most `IS_MAX_ROUNDS`).
    Returns `settings.is_draws` draws resampled from the weighted ones, the effective sample size and the
    number of draws evaluated. `others`: further (z, covariance) starts, one
    proposal each (the other modes of a smooth field's posterior)."""
    from .field_search import amis

    def target(Z: np.ndarray):
        return ll.log_post_many(Z), np.zeros(len(Z))

    starts = [
        {"theta": np.asarray(z, float), "H": np.linalg.inv(c * IS_INFLATE**2)}
        for z, c in ((z_map, cov), *others)
    ]
    Z, lw, _, n = amis(target, starts, rng, max_rounds=IS_MAX_ROUNDS)
    w = _normalised(lw)
    idx = rng.choice(Z.shape[0], size=settings.is_draws, p=w)
    return Z[idx], {"ess": float(1.0 / np.sum(w**2)), "max_weight": float(w.max()), "samples": n}


def _normalised(lw: np.ndarray) -> np.ndarray:
    """Importance weights summing to one from their logs."""
    w = np.exp(lw - lw.max())
    return w / w.sum()


def other_modes(problem: GirderProblem, z_map: np.ndarray, cov: np.ndarray) -> tuple:
    """Starts for a member's sampler beside its MAP: a smooth field's other posterior modes as the
    reference's search finds them (their theta and Laplace covariance, log sigma at the member's MAP and
    sd), those more than one Laplace sd from the member's MAP; none for a segmented girder."""
    modes = getattr(problem, "modes", None) or []
    k = problem.dim
    out = []
    for m in modes:
        d = np.asarray(m["theta"], float) - z_map[:k]
        C = np.linalg.inv(m["H"])
        if d @ np.linalg.solve(C, d) <= 1.0:
            continue  # the member's own mode
        c = cov.copy()
        c[:k, :k] = C
        c[:k, k:] = c[k:, :k] = 0.0
        out.append((np.r_[m["theta"], z_map[k:]], c))
    return tuple(out)
