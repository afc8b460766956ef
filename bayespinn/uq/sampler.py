"""Generic emcee driver: independent walker groups, run length from the autocorrelation time.

`sample(log_prob, center, scale, settings, seed)` runs `n_groups` independent `EnsembleSampler`s
(vectorised log-probability) from a dispersed cloud around `center`, in chunks, until the run is at
least `tau_factor` integrated autocorrelation times long (plus burn-in). Diagnostics treat each group
as one chain: its walkers' post-burn-in trajectories one after another.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .. import seeding

#: convergence thresholds written into summary.json
RHAT_MAX, ESS_MIN = 1.01, 400.0


@dataclass(frozen=True)
class MCMCSettings:
    """emcee run: walkers per group, groups, run length rules."""

    n_walkers: int = 16
    n_groups: int = 4
    chunk: int = 250
    min_steps: int = 750
    max_steps: int = 40000
    tau_factor: float = 50.0
    burn_factor: float = 5.0
    dispersion: float = 2.0  # initial cloud: center + dispersion * scale * N(0, 1)

    @classmethod
    def for_profile(cls, profile: str) -> MCMCSettings:
        return cls(min_steps=500, tau_factor=30.0) if profile == "smoke" else cls()

    @classmethod
    def for_coverage(cls) -> MCMCSettings:
        """Two groups of 32 walkers: the same run-length rule (50 tau) at half the calls, for studies
        that repeat the inference hundreds of times."""
        return cls(n_walkers=32, n_groups=2)


@dataclass
class Chains:
    """Draws (group, draw, dim), per-draw sample statistics (group, draw) and run facts.

    lp: the log density at each draw; acceptance: the acceptance fraction of the walker that made the draw
    (emcee accepts or rejects per walker, so this is the walker's rate over its whole run)."""

    draws: np.ndarray
    tau: float
    steps: int
    acceptance: float
    lp: np.ndarray | None = None
    walker_acceptance: np.ndarray | None = None


def _group_chain(chain: np.ndarray) -> np.ndarray:
    """(step, walker, dim) -> (walker * step, dim): each walker's trajectory in turn."""
    return np.transpose(chain, (1, 0, 2)).reshape(-1, chain.shape[-1])


def _inside(log_prob, center: np.ndarray, p0: np.ndarray, tries: int = 20) -> np.ndarray:
    """Walkers of the initial cloud outside the density's support (at a bound, such as a truncated prior,
    where the maximum may sit) pulled halfway to the center until they are inside: emcee cannot move a
    walker whose density and proposal are both zero."""
    p0 = p0.copy()
    for _ in range(tries):
        bad = ~np.isfinite(np.asarray(log_prob(p0), float))
        if not bad.any():
            break
        p0[bad] = center[None, :] + 0.5 * (p0[bad] - center[None, :])
    return p0


def sample(
    log_prob: Callable[[np.ndarray], np.ndarray],
    center: np.ndarray,
    scale: np.ndarray,
    settings: MCMCSettings | None = None,
    seed: int | np.random.SeedSequence = 0,
    progress: bool = False,
    desc: str = "MCMC",
) -> Chains:
    """Sample a vectorised log-density (theta (W, D) -> (W,)) with emcee; a function of the seed."""
    import emcee

    s = settings or MCMCSettings()
    center = np.asarray(center, float)
    scale = np.asarray(scale, float)
    dim = center.size
    samplers, states = [], []
    for g in range(s.n_groups):
        r = np.random.default_rng(seeding.child(seed, "emcee", g))
        p0 = center[None, :] + s.dispersion * scale[None, :] * r.standard_normal((s.n_walkers, dim))
        p0 = _inside(log_prob, center, p0)
        sampler = emcee.EnsembleSampler(s.n_walkers, dim, log_prob, vectorize=True)
        rs = np.random.RandomState(seeding.int_seed(seeding.child(seed, "emcee", 1000 + g)) % 2**32)
        sampler.random_state = rs.get_state()
        samplers.append(sampler)
        states.append(p0)
    logging.getLogger("emcee").setLevel(
        logging.ERROR
    )  # its short-chain warning is our loop condition
    steps, tau = 0, float("nan")
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=s.min_steps, desc=desc, unit="step", leave=False)
    while True:
        for i, sampler in enumerate(samplers):
            states[i] = sampler.run_mcmc(states[i], s.chunk, progress=False)
        steps += s.chunk
        if bar is not None:
            bar.update(s.chunk)
        if steps < s.min_steps:
            continue
        taus = [
            emcee.autocorr.integrated_time(sm.get_chain()[steps // 3 :], quiet=True).max()
            for sm in samplers
        ]
        tau = float(np.max(taus))
        need = int(math.ceil((s.tau_factor + s.burn_factor) * tau))
        if steps >= need or steps >= s.max_steps:
            break
        if bar is not None:
            bar.total = min(need, s.max_steps)
            bar.refresh()
    if bar is not None:
        bar.close()
    burn = int(math.ceil(max(s.burn_factor * tau, steps / 5)))
    thin = max(1, int(tau / 4))
    draws = np.stack([_group_chain(sm.get_chain(discard=burn, thin=thin)) for sm in samplers])
    acc = float(np.mean([sm.acceptance_fraction.mean() for sm in samplers]))
    lp = np.stack(
        [_group_chain(sm.get_log_prob(discard=burn, thin=thin)[..., None])[:, 0] for sm in samplers]
    )
    per_walker = []
    for sm in samplers:
        kept = sm.get_chain(discard=burn, thin=thin).shape[0]
        per_walker.append(np.repeat(sm.acceptance_fraction, kept))  # walker by walker, as in draws
    return Chains(draws, tau, steps, acc, lp, np.stack(per_walker))
