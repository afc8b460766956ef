"""Pyro's NUTS on a potential function, with the sampler's own account of what went wrong.

`run_nuts` runs one chain and returns its draws together with per-draw sample statistics:
`diverging` (the trajectory hit a divergence), `tree_depth` (doublings of the trajectory), `step_size`
and `lp` (minus the potential). Pyro records divergences but not tree depths; the depth is recovered
from the number of gradient evaluations of the iteration (a trajectory of depth d takes up to 2^d - 1
leapfrog steps, one gradient each). Warnings raised while sampling are kept and logged, never silenced.

`NUTSSettings`, the MAP and Laplace factor of a potential (`map_estimate`, `laplace_factor`), the
whitened coordinates NUTS runs in (`Whitened`) and the chains' dispersed starts (`valid_start`) are shared
by both B-PINN variants.

`nuts_health` turns the statistics of all chains into the diagnostics a run reports, and `healthy`
says whether they allow calling the run converged (R-hat, bulk and tail ESS, no divergence, no
trajectory cut at the maximum tree depth).
"""

from __future__ import annotations

import logging
import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from .. import seeding
from .sampler import ESS_MIN, RHAT_MAX

log = logging.getLogger(__name__)


@dataclass
class ChainRun:
    """One NUTS chain: draws per site (draw, ...) and per-draw sample statistics (draw,)."""

    samples: dict[str, torch.Tensor]
    lp: np.ndarray
    diverging: np.ndarray
    tree_depth: np.ndarray
    step_size: np.ndarray
    max_tree_depth: int
    warnings: list[str] = field(default_factory=list)
    nonfinite: int = (
        0  # potential evaluations that were not finite (treated as outside the support)
    )


class _Counted:
    """A potential function that counts its calls (one per leapfrog step) and treats a point where the
    potential is not finite or cannot be computed (an unbounded or undefined density, e.g. near an improper
    posterior's pole, where a Cholesky factor fails in float64) as outside the support: +inf, which NUTS rejects and reports as a divergence, where a -inf or NaN would
    crash Pyro's tree building."""

    def __init__(self, fn: Callable):
        self.fn, self.calls, self.nonfinite = fn, 0, 0

    def __call__(self, params):
        self.calls += 1
        try:
            pe = self.fn(params)
        except torch.linalg.LinAlgError:  # e.g. a covariance no longer positive definite in float64
            pe = None
        if pe is not None and bool(torch.isfinite(pe)):
            return pe
        self.nonfinite += 1
        anchor = sum((v * 0).sum() for v in params.values())  # keeps the graph: a zero gradient
        return anchor + float("inf")


def run_nuts(
    potential_fn: Callable[[dict], torch.Tensor],
    initial_params: dict[str, torch.Tensor],
    *,
    warmup: int,
    samples: int,
    seed: np.random.SeedSequence,
    full_mass: bool = True,
    max_tree_depth: int = 10,
    progress: bool = False,
) -> ChainRun:
    """One NUTS chain on `potential_fn` (step size and mass matrix adapted in warm-up), a function of the seed."""
    from pyro.infer import MCMC, NUTS

    pot = _Counted(potential_fn)
    stats: dict[str, list] = {"lp": [], "diverging": [], "tree_depth": [], "step_size": []}
    state = {"calls": 0, "div": 0}

    def hook(kernel, params, stage, i):
        n = pot.calls - state["calls"]
        state["calls"] = pot.calls
        if stage != "Sample":
            return
        ndiv = len(kernel._divergences)
        stats["diverging"].append(ndiv > state["div"])
        state["div"] = ndiv
        stats["tree_depth"].append(max(1, math.ceil(math.log2(n + 1))) if n > 0 else 0)
        stats["step_size"].append(float(kernel.step_size))
        pe = kernel._potential_energy_last  # Pyro's cache of the current state's potential
        stats["lp"].append(-float(pe) if pe is not None else float("nan"))

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seeding.int_seed(seed))
        kernel = NUTS(
            potential_fn=pot,
            adapt_step_size=True,
            adapt_mass_matrix=True,
            full_mass=full_mass,
            max_tree_depth=max_tree_depth,
        )
        mcmc = MCMC(
            kernel,
            num_samples=samples,
            warmup_steps=warmup,
            initial_params=initial_params,
            disable_progbar=not progress,
            hook_fn=hook,
        )
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            mcmc.run()
    msgs = list(dict.fromkeys(f"{w.category.__name__}: {w.message}" for w in caught))
    for m in msgs:
        log.warning("[nuts] %s", m)
    return ChainRun(
        samples={k: v.detach() for k, v in mcmc.get_samples().items()},
        lp=np.asarray(stats["lp"], float),
        diverging=np.asarray(stats["diverging"], bool),
        tree_depth=np.asarray(stats["tree_depth"], int),
        step_size=np.asarray(stats["step_size"], float),
        max_tree_depth=max_tree_depth,
        warnings=msgs,
        nonfinite=pot.nonfinite,
    )


def sample_stats(chains: list[ChainRun]) -> dict[str, np.ndarray]:
    """The chains' statistics stacked (chain, draw), as ArviZ's `sample_stats` group names them."""
    return {
        k: np.stack([getattr(c, k) for c in chains])
        for k in ("lp", "diverging", "tree_depth", "step_size")
    }


def nuts_health(chains: list[ChainRun]) -> dict:
    """Divergences, trajectories cut at the maximum tree depth, and the sampler's warnings, over all chains."""
    div = [int(c.diverging.sum()) for c in chains]
    sat = [int((c.tree_depth >= c.max_tree_depth).sum()) for c in chains]
    n = sum(c.diverging.size for c in chains)
    return {
        "divergences": int(sum(div)),
        "divergences_per_chain": div,
        "max_tree_depth": chains[0].max_tree_depth if chains else None,
        "tree_depth_saturated": int(sum(sat)),
        "tree_depth_saturated_fraction": float(sum(sat) / n) if n else 0.0,
        "mean_tree_depth": float(np.mean([c.tree_depth.mean() for c in chains]))
        if n
        else float("nan"),
        "step_size": [float(c.step_size[-1]) if c.step_size.size else float("nan") for c in chains],
        "sampler_warnings": list(dict.fromkeys(m for c in chains for m in c.warnings)),
        "nonfinite_potential": int(sum(c.nonfinite for c in chains)),
    }


def problems(diag: dict) -> list[str]:
    """What keeps a sampler's run from counting as converged, in words (empty when nothing does): R-hat above
    1.01, bulk or tail ESS below 400 (Vehtari et al. 2021), any divergent transition, or any trajectory cut at
    the maximum tree depth (the sampler did not explore the posterior as NUTS promises)."""
    out = []
    rhat, bulk, tail = diag.get("rhat"), diag.get("ess_bulk"), diag.get("ess_tail")
    if rhat is None or not math.isfinite(rhat) or rhat > RHAT_MAX:
        out.append(
            f"R-hat {rhat:.3g} > {RHAT_MAX}"
            if rhat is not None and math.isfinite(rhat)
            else "R-hat n/a"
        )
    for name, v in (("bulk", bulk), ("tail", tail)):
        if v is None or not math.isfinite(v) or v < ESS_MIN:
            out.append(
                f"{name} ESS {v:.0f} < {ESS_MIN:.0f}"
                if v is not None and math.isfinite(v)
                else f"{name} ESS n/a"
            )
    if diag.get("divergences"):
        out.append(f"{diag['divergences']} divergent transitions")
    if diag.get("tree_depth_saturated"):
        out.append(
            f"{diag['tree_depth_saturated']} trajectories cut at the maximum tree depth "
            f"{diag.get('max_tree_depth')}"
        )
    return out


@dataclass(frozen=True)
class NUTSSettings:
    chains: int = 4
    warmup: int = 300
    samples: int = 500
    max_tree_depth: int = 10  # Pyro's and Stan's default: up to 1023 leapfrog steps per iteration

    @classmethod
    def for_profile(cls, profile: str) -> NUTSSettings:
        return {"smoke": cls(4, 60, 60), "fast": cls(), "paper": cls(4, 1000, 1000)}[profile]


def map_estimate(pot, z0: np.ndarray) -> np.ndarray:
    z = torch.tensor(z0, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.LBFGS(
        [z], lr=1.0, max_iter=200, line_search_fn="strong_wolfe", tolerance_grad=1e-10
    )

    def closure():
        opt.zero_grad()
        v = pot({"z": z})
        v.backward()
        return v

    opt.step(closure)
    return z.detach().numpy()


def laplace_factor(pot, z: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor of the Laplace covariance (inverse Hessian) at the MAP; a diagonal fallback of
    0.1 when the Hessian is not positive definite there."""
    zt = torch.tensor(z, dtype=torch.float64)
    H = torch.autograd.functional.hessian(lambda v: pot({"z": v}), zt).numpy()
    try:
        return np.linalg.cholesky(np.linalg.inv(0.5 * (H + H.T)))
    except np.linalg.LinAlgError:
        log.warning(
            "[bpinn] the posterior's Hessian at the MAP is not positive definite; NUTS starts unscaled"
        )
        return np.diag([0.1, 0.1])


class Whitened:
    """The potential in whitened coordinates u, z = z_map + L u (L the Laplace factor; constant Jacobian).

    In z the posterior of (log theta, log sigma) can be very narrow and correlated (sds of 1e-3 or less with
    clean or low-noise data), so NUTS with a unit mass matrix starts at a tiny step size and the maximum tree
    depth until its mass-matrix windows catch up (measured: 2.7 s per iteration at the clean level); in u it
    is about a unit Gaussian from the first step."""

    def __init__(self, pot, z_map: np.ndarray, L: np.ndarray, device: str | torch.device = "cpu"):
        self.pot = pot
        self.z_map = torch.tensor(z_map, dtype=torch.float64, device=device)
        self.L = torch.tensor(L, dtype=torch.float64, device=device)

    def z(self, u):
        return self.z_map + self.L @ u

    def z_draws(self, u: torch.Tensor) -> np.ndarray:
        """Draws of z (n, 2) from draws of u (n, 2)."""
        return (self.z_map[None, :] + u.detach().to(torch.float64) @ self.L.T).cpu().numpy()

    def __call__(self, params: dict) -> torch.Tensor:
        return self.pot({"z": self.z(params["u"])})


#: dispersion of the chains' starts, in Laplace sds around the MAP, tried in turn until the potential is finite
START_SCALES = (2.0, 1.0, 0.5, 0.25, 0.0)


def valid_start(pot, direction: torch.Tensor, key: str = "u", **fixed) -> torch.Tensor:
    """The first of `START_SCALES` * direction where the whitened potential is finite (a chain cannot start
    where the density is zero or undefined, e.g. far out on an improper posterior's flank)."""
    for k in START_SCALES:
        u = k * direction
        try:
            with torch.no_grad():
                ok = bool(torch.isfinite(pot({key: u, **fixed})))
        except torch.linalg.LinAlgError:
            ok = False
        if ok:
            return u
    raise RuntimeError(
        "the B-PINN posterior cannot be evaluated even at its MAP: the last-layer model is "
        "degenerate for these data"
    )
