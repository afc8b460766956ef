"""The one emcee driver: independent walker groups, run length from the autocorrelation time.

`run_groups` runs one vectorised `EnsembleSampler` per start cloud, seeded from the run's seed, in
chunks until a stopping rule on the integrated autocorrelation time says the run is long enough, and
`collect` takes every group's post-burn-in draws (each group one chain: its walkers' trajectories one
after another). Two front ends use it: `sample(log_prob, center, scale, settings, seed)` for the modal and
crossing references (a dispersed cloud about `center`, `tau_factor` autocorrelation times after burn-in)
and `uq.girder_emcee.run_emcee` for the girder reference (a Laplace-covariance cloud, differential
evolution moves, tau also required to be stable between checks).
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
    walker whose density and proposal are both zero. Where the center itself sits on the support's edge,
    a walker beyond it never gets in by halving; those left outside move onto the segments from the
    center to walkers inside (in turn, at distinct fractions of them: inside for a convex support, and no
    two walkers alike, which emcee refuses)."""
    p0 = p0.copy()
    for _ in range(tries):
        bad = ~np.isfinite(np.asarray(log_prob(p0), float))
        if not bad.any():
            return p0
        p0[bad] = center[None, :] + 0.5 * (p0[bad] - center[None, :])
    bad = ~np.isfinite(np.asarray(log_prob(p0), float))
    good = np.flatnonzero(~bad)
    if good.size:
        k = np.arange(int(bad.sum()))
        frac = (k + 1.0) / (k.size + 1.0)
        p0[bad] = center[None, :] + frac[:, None] * (p0[good[k % good.size]] - center[None, :])
    return p0


def run_groups(
    log_prob: Callable[[np.ndarray], np.ndarray],
    starts: list[np.ndarray],
    seed: int | np.random.SeedSequence,
    *,
    chunk: int,
    min_steps: int,
    max_steps: int,
    enough: Callable[[int, np.ndarray], tuple[bool, int]],
    moves=None,
    progress: bool = False,
    desc: str = "MCMC",
) -> tuple[list, int, np.ndarray]:
    """emcee groups from the start clouds (walkers, D) grown by `chunk` steps until `enough(steps,
    tau_per_parameter)` returns (True, _) (checked from `min_steps` on; its second value is the steps it
    expects in all, for the progress bar) or `max_steps`. Group g's walkers draw from seeding stream
    ("emcee", 1000 + g). Returns the samplers, the steps run and tau per parameter (the largest over
    the groups; NaN before the first check)."""
    import emcee

    samplers = []
    for g, p0 in enumerate(starts):
        sampler = emcee.EnsembleSampler(
            p0.shape[0], p0.shape[1], log_prob, moves=moves() if moves else None, vectorize=True
        )
        rs = np.random.RandomState(seeding.int_seed(seeding.child(seed, "emcee", 1000 + g)) % 2**32)
        sampler.random_state = rs.get_state()
        samplers.append(sampler)
    states = list(starts)
    logging.getLogger("emcee").setLevel(
        logging.ERROR
    )  # its short-chain warning is our loop condition
    steps = 0
    tau_dim = np.full(starts[0].shape[1], np.nan)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=min_steps, desc=desc, unit="step", leave=False)
    while True:
        for i, sampler in enumerate(samplers):
            states[i] = sampler.run_mcmc(states[i], chunk, progress=False)
        steps += chunk
        if bar is not None:
            bar.update(chunk)
        if steps < min_steps:
            continue
        per = np.array(
            [
                emcee.autocorr.integrated_time(sm.get_chain()[steps // 3 :], quiet=True)
                for sm in samplers
            ]
        )
        # a chain that has not moved has no autocorrelation time (emcee gives NaN): it counts as
        # correlated over the whole run, so the run goes on to max_steps and its diagnostics say so
        tau_dim = np.where(np.isfinite(per), per, float(steps)).max(axis=0)
        done, need = enough(steps, tau_dim)
        if done or steps >= max_steps:
            break
        if bar is not None:
            bar.total = min(need, max_steps)
            bar.refresh()
    if bar is not None:
        bar.close()
    return samplers, steps, tau_dim


def collect(
    samplers: list, burn: int, thin: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Every group's draws after `burn` steps, thinned: draws (group, draw, D), their log densities and
    the acceptance fraction of the walker that made each (group, draw), and the mean acceptance."""
    draws = np.stack([_group_chain(sm.get_chain(discard=burn, thin=thin)) for sm in samplers])
    lp = np.stack(
        [_group_chain(sm.get_log_prob(discard=burn, thin=thin)[..., None])[:, 0] for sm in samplers]
    )
    per_walker = []
    for sm in samplers:
        kept = sm.get_chain(discard=burn, thin=thin).shape[0]
        per_walker.append(np.repeat(sm.acceptance_fraction, kept))  # walker by walker, as in draws
    acc = float(np.mean([sm.acceptance_fraction.mean() for sm in samplers]))
    return draws, lp, np.stack(per_walker), acc


def sample(
    log_prob: Callable[[np.ndarray], np.ndarray],
    center: np.ndarray,
    scale: np.ndarray,
    settings: MCMCSettings | None = None,
    seed: int | np.random.SeedSequence = 0,
    progress: bool = False,
    desc: str = "MCMC",
) -> Chains:
    """Sample a vectorised log-density (theta (W, D) -> (W,)) from a cloud center + dispersion x scale x
    N(0, 1) (walkers outside the support pulled in), until the run is (tau_factor + burn_factor) tau
    long; a function of the seed."""
    s = settings or MCMCSettings()
    center = np.asarray(center, float)
    scale = np.asarray(scale, float)
    dim = center.size
    starts = []
    for g in range(s.n_groups):
        r = np.random.default_rng(seeding.child(seed, "emcee", g))
        p0 = center[None, :] + s.dispersion * scale[None, :] * r.standard_normal((s.n_walkers, dim))
        starts.append(_inside(log_prob, center, p0))

    def enough(steps: int, tau_dim: np.ndarray) -> tuple[bool, int]:
        need = int(math.ceil((s.tau_factor + s.burn_factor) * float(tau_dim.max())))
        return steps >= need, need

    samplers, steps, tau_dim = run_groups(
        log_prob, starts, seed, chunk=s.chunk, min_steps=s.min_steps, max_steps=s.max_steps,
        enough=enough, progress=progress, desc=desc,
    )  # fmt: skip
    tau = float(tau_dim.max())
    # at most half the run: a run stopped at max_steps short of its burn-in still keeps draws to judge
    burn = min(int(math.ceil(max(s.burn_factor * tau, steps / 5))), steps // 2)
    thin = max(1, int(tau / 4))
    draws, lp, per_walker, acc = collect(samplers, burn, thin)
    return Chains(draws, tau, steps, acc, lp, per_walker)
