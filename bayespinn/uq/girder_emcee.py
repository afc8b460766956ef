"""The girder reference's use of the emcee driver (`uq.sampler.run_groups`): its settings
(`GirderMCMCSettings`: walkers from the dimension, differential-evolution moves, tau required stable) and
`run_emcee`, which starts the groups from the Laplace covariance; a function of the seed.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from .. import seeding
from ..config import _check_number
from ..errors import InputError
from .sampler import collect, run_groups


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
    ensembles (`uq.sampler.run_groups`) started from N(center, start_scale^2 cov) (draws outside the
    support redrawn), until the run after burn-in is tau_factor tau long and tau moved by at most
    tau_rtol since the last check. A function of the seed."""
    import emcee

    s = settings or GirderMCMCSettings()
    center = np.asarray(center, float)
    D = center.size
    nw = s.walkers_per_group(D)
    C = np.linalg.cholesky(np.atleast_2d(cov) + 1e-300 * np.eye(D))
    starts = []
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
        starts.append(p0)
    last = {"tau": float("nan")}

    def enough(steps: int, tau_dim: np.ndarray) -> tuple[bool, int]:
        tau, prev = float(tau_dim.max()), last["tau"]
        last["tau"] = tau
        long_enough = steps - int(math.ceil(s.burn_factor * tau)) >= s.tau_factor * tau
        stable = math.isfinite(prev) and abs(tau - prev) <= s.tau_rtol * tau
        last["ok"] = long_enough and stable
        return last["ok"], int(math.ceil((s.tau_factor + s.burn_factor) * tau))

    samplers, steps, tau_dim = run_groups(
        log_prob, starts, seed, chunk=s.chunk, min_steps=s.min_steps, max_steps=s.max_steps,
        enough=enough, moves=None if s.moves == "stretch" else emcee.moves.DEMove,
    )  # fmt: skip
    tau = float(tau_dim.max())
    if not last.get("ok"):
        warnings.warn(
            f"girder MCMC stopped at max_steps={s.max_steps} with tau={tau:.1f} "
            f"(needs {s.tau_factor:g} tau after burn-in, tau stable to {s.tau_rtol:g})",
            RuntimeWarning,
            stacklevel=2,
        )
    burn = min(int(math.ceil(s.burn_factor * tau)), steps // 2)
    thin = max(1, int(tau / 4))
    theta, lp, _, acc = collect(samplers, burn, thin)
    return GirderChains(theta, lp, tau, tau_dim, steps, burn, thin, nw * s.n_groups, acc)
