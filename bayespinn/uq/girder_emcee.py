"""The girder reference's sampler (`uq.girder_posterior`): `n_groups` independent emcee ensembles with
the differential-evolution move, grown in chunks until the post-burn-in chain is long against the
integrated autocorrelation time (`GirderMCMCSettings`, `run_emcee`); a function of the seed.
"""

from __future__ import annotations

import logging
import math
import warnings
from dataclasses import dataclass

import numpy as np

from .. import seeding
from ..config import _check_number
from ..errors import InputError


@dataclass(frozen=True)
class GirderMCMCSettings:
    """emcee run for the girder posterior: walkers from the dimension, run length from tau."""

    n_groups: int = 2
    min_walkers: int = 32
    walkers_per_dim: int = 4
    chunk: int = 200
    min_steps: int = 600
    max_steps: int = 40000
    tau_factor: float = 50.0
    burn_factor: float = 5.0
    tau_rtol: float = 0.1
    #: initial cloud: MAP + start_scale x Laplace-covariance draws
    start_scale: float = 1.0
    #: emcee moves: "de" (emcee's DEMove, differential evolution) or "stretch" (emcee's default)
    moves: str = "de"

    def __post_init__(self) -> None:
        for name in (
            "n_groups",
            "min_walkers",
            "walkers_per_dim",
            "chunk",
            "min_steps",
            "max_steps",
        ):
            v = getattr(self, name)
            if (
                isinstance(v, bool)
                or not isinstance(v, int)
                or v < (2 if name == "n_groups" else 1)
            ):
                raise InputError(f"mcmc.{name}", v, "an integer >= 1 (n_groups >= 2)")
        for name in ("tau_factor", "burn_factor", "tau_rtol", "start_scale"):
            _check_number(f"mcmc.{name}", getattr(self, name), positive=True)
        if self.moves not in ("stretch", "de"):
            raise InputError("mcmc.moves", self.moves, "'stretch' or 'de'")

    def walkers_per_group(self, dim: int) -> int:
        """max(min_walkers, walkers_per_dim x dim) over the groups, even, and >= 2 dim per group
        (emcee's red-blue moves need twice the dimension)."""
        total = max(self.min_walkers, self.walkers_per_dim * dim)
        per = max(-(-total // self.n_groups), 2 * dim)
        return per + per % 2


@dataclass
class GirderChains:
    """theta draws (group, draw, dim) with their log densities (group, draw), and run facts."""

    theta: np.ndarray
    lp: np.ndarray
    tau: float
    tau_per_parameter: np.ndarray
    steps: int
    burn: int
    thin: int
    walkers: int
    acceptance: float


def run_emcee(
    log_prob,
    center: np.ndarray,
    cov: np.ndarray,
    settings: GirderMCMCSettings | None = None,
    seed: int | np.random.SeedSequence = 0,
) -> GirderChains:
    """Sample a vectorised log density (theta (W, D) -> (W,)) with `n_groups` independent emcee
    ensembles started from N(center, start_scale^2 cov) (draws outside the support redrawn).
    A function of the seed."""
    import emcee

    s = settings or GirderMCMCSettings()
    center = np.asarray(center, float)
    D = center.size
    nw = s.walkers_per_group(D)
    C = np.linalg.cholesky(np.atleast_2d(cov) + 1e-300 * np.eye(D))
    samplers, states = [], []
    for g in range(s.n_groups):
        r = np.random.default_rng(seeding.child(seed, "emcee", g))
        p0 = center + s.start_scale * r.standard_normal((nw, D)) @ C.T
        for _ in range(200):
            bad = ~np.isfinite(log_prob(p0))
            if not bad.any():
                break
            p0[bad] = center + 0.5 * s.start_scale * r.standard_normal((int(bad.sum()), D)) @ C.T
        else:
            raise RuntimeError("could not start the walkers inside the posterior's support")
        moves = None if s.moves == "stretch" else emcee.moves.DEMove()
        sampler = emcee.EnsembleSampler(nw, D, log_prob, moves=moves, vectorize=True)
        rs = np.random.RandomState(seeding.int_seed(seeding.child(seed, "emcee", 1000 + g)) % 2**32)
        sampler.random_state = rs.get_state()
        samplers.append(sampler)
        states.append(p0)
    logging.getLogger("emcee").setLevel(logging.ERROR)
    steps, tau, tau_prev = 0, float("nan"), float("nan")
    tau_dim = np.full(D, np.nan)
    while True:
        for i, sm in enumerate(samplers):
            states[i] = sm.run_mcmc(states[i], s.chunk, progress=False)
        steps += s.chunk
        if steps < s.min_steps:
            continue
        per = np.array(
            [
                emcee.autocorr.integrated_time(sm.get_chain()[steps // 3 :], quiet=True)
                for sm in samplers
            ]
        )
        tau_dim = per.max(axis=0)
        tau = float(tau_dim.max())
        burn = int(math.ceil(s.burn_factor * tau))
        long_enough = steps - burn >= s.tau_factor * tau
        stable = math.isfinite(tau_prev) and abs(tau - tau_prev) <= s.tau_rtol * tau
        if (long_enough and stable) or steps >= s.max_steps:
            if not (long_enough and stable):
                warnings.warn(
                    f"girder MCMC stopped at max_steps={s.max_steps} with tau={tau:.1f} "
                    f"(needs {s.tau_factor:g} tau after burn-in, tau stable to {s.tau_rtol:g})",
                    RuntimeWarning,
                    stacklevel=3,
                )
            break
        tau_prev = tau
    burn = min(int(math.ceil(s.burn_factor * tau)), steps // 2)
    thin = max(1, int(tau / 4))

    def grouped(a: np.ndarray) -> np.ndarray:  # (step, walker, ...) -> (walker * step, ...)
        return np.swapaxes(a, 0, 1).reshape((-1,) + a.shape[2:])

    theta = np.stack([grouped(sm.get_chain(discard=burn, thin=thin)) for sm in samplers])
    lp = np.stack([grouped(sm.get_log_prob(discard=burn, thin=thin)) for sm in samplers])
    acc = float(np.mean([sm.acceptance_fraction.mean() for sm in samplers]))
    return GirderChains(theta, lp, tau, tau_dim, steps, burn, thin, nw * s.n_groups, acc)
