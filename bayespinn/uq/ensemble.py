"""Deep ensembles of the paper's PINN whose spread is an honest interval for EI.

A plain ensemble spreads only by initialisation. Here each of the M members (own initialisation and
collocation stream) is trained in two phases through the one training loop, all members together as
batched tensors:

1. on the measured data, to learn the noise level: sigma_m from its residuals;
2. randomise-then-optimise: warm-started from phase 1, on its own perturbed copy of the data
   (y + sigma_hat eps_m) with its own perturbed prior anchor (log EI_0 + s eta_m), under the
   posterior-scaled objective. For a linear-Gaussian problem the fits are then exact posterior draws.

Five draws estimate a spread to about +-35 %, so each member also reports its own local (Laplace)
width of log EI, from the exact last-layer marginal likelihood of its trained features (`lastlayer`).
The ensemble's variance of log EI is the conjugate pooling of the two estimates of the same quantity:
(nu0 s_laplace^2 + (M - 1) S_between^2) / (nu0 + M - 1), nu0 = `LAPLACE_DOF`, so the between-member
spread (which also carries training noise) dominates as M grows.

The noise level comes from the same last-layer marginal likelihood, not from the trained network's raw
residuals: with its physics penalties of weight one, a network of 5 x 64 neurons absorbs part of the
noise (its residuals under-state sigma by 25-35 % at 10-20 dB), while the marginal, whose output
weights are held to the physics at the scale the network achieves, counts what the fit spent. Per
member, p(sigma | EI_m, y) on a grid of log sigma (log-uniform prior); its mode sets the perturbation
of randomise-then-optimise (phase 1 members) and the Laplace width (phase 2 members), and sigma's
posterior draws are taken from the members' grids in equal shares.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, replace

import numpy as np

from .. import seeding
from ..config import Config
from ..data.measurements import Measurements
from ..threads import torch_threads
from .bpinn import IDENTIFIED_FRACTION, LastLayerPredictor
from .lastlayer import LastLayer
from .posterior import Posterior
from .priors import EIPrior, NoisePrior

log = logging.getLogger(__name__)

#: the members' mean Laplace variance counts as this many degrees of freedom in the pooled variance
LAPLACE_DOF = 4
#: share of the profile's Adam steps spent in the randomise-then-optimise phase
RTO_FRACTION = 0.25
#: posterior draws stored
N_DRAWS = 4000
#: members scattering more than this many times their own Laplace sd are flagged as not converged
#: (with 5 members the sample sd is itself uncertain by ~35 %, so 3x is far outside chance)
MAX_SCATTER_RATIO = 3.0


#: the grid of log sigma: this many points over +-`SIGMA_GRID_HALF_WIDTH` around the fit's residual level
SIGMA_GRID_POINTS = 241
SIGMA_GRID_HALF_WIDTH = 1.2


@dataclass(frozen=True)
class SigmaGrid:
    """p(log sigma | EI, y) of a last-layer model on a grid (log-uniform prior on sigma)."""

    log_sigma: np.ndarray
    prob: np.ndarray

    @property
    def mode(self) -> float:
        return float(np.exp(self.log_sigma[int(np.argmax(self.prob))]))

    def draws(self, k: int, rng: np.random.Generator) -> np.ndarray:
        """k draws of sigma: a grid cell by its probability, uniform within it."""
        h = self.log_sigma[1] - self.log_sigma[0]
        i = rng.choice(self.prob.size, size=k, p=self.prob)
        return np.exp(self.log_sigma[i] + h * (rng.random(k) - 0.5))


def sigma_grid(ll: LastLayer, noise: NoisePrior) -> SigmaGrid:
    """The noise level's posterior for one member at its fitted EI (see the module docstring); with the
    SNR-conditioned noise prior its log-normal density is added (as in the B-PINN)."""
    import torch

    center = 0.5 * math.log(max(ll.fit_rss, 1e-300) / max(ll.n, 1))
    grid = center + np.linspace(-SIGMA_GRID_HALF_WIDTH, SIGMA_GRID_HALF_WIDTH, SIGMA_GRID_POINTS)
    lt = torch.tensor(math.log(ll.theta_fit), dtype=torch.float64)
    with torch.no_grad(), torch_threads(1):
        lp = np.array([float(ll.log_marginal(lt, torch.tensor(g, dtype=torch.float64))) for g in grid])
    if noise.kind == "snr":
        lp = lp - 0.5 * ((grid - math.log(noise.center)) / noise.log_sd) ** 2
    if int(np.argmax(lp)) in (0, grid.size - 1):
        log.warning("[ensemble] the noise level's posterior reaches the edge of its grid (%.3g .. %.3g)",
                    math.exp(grid[0]), math.exp(grid[-1]))
    p = np.exp(lp - lp.max())
    return SigmaGrid(grid, p / p.sum())


def _rto_data(data: Measurements, sigma: float, M: int, rng: np.random.Generator) -> tuple[Measurements, ...]:
    return tuple(data.with_values(data.value + sigma * rng.standard_normal(len(data))) for _ in range(M))


def ensemble_posterior(
    data: Measurements,
    cfg: Config,
    *,
    seed: int | np.random.SeedSequence,
    opts,
    noise: NoisePrior,
) -> Posterior:
    """Train M members (phase 1 then randomise-then-optimise) and pool them into a posterior."""
    from ..pinn import Problem, TrainSettings, fit

    t0 = time.perf_counter()
    M = int(opts.members)
    settings = TrainSettings.for_profile(opts.profile)
    ei_prior = EIPrior.from_spec(cfg.prior)
    n = len(data)
    if n == 0:
        from .modal_mcmc import prior_only

        log.warning("[ensemble] no measurements: EI is not identified, returning the prior")
        return prior_only(ei_prior, seed, t0, method="ensemble")
    quiet = not opts.progress

    def last_layers(res) -> list[LastLayer]:
        model = res.model("cpu")
        with torch_threads(1):
            return [LastLayer(model, m, base, data, np.random.default_rng(seeding.child(seed, "collocation", m)),
                              n_pde=settings.n_pde, n_bc=settings.n_bc, n_ic=settings.n_ic,
                              beta_rel=settings.beta_rel, images=settings.images) for m in range(M)]

    # phase 1: all members on the measured data
    log.info("[ensemble] phase 1: %d members on the measured data", M)
    base = Problem.from_config(cfg, data)
    r1 = fit(base, settings, seed=seeding.stream(seed, "init"), members=M, device=opts.device, quiet=quiet)
    grids1 = [sigma_grid(ll, noise) for ll in last_layers(r1)]
    sigma_hat = float(np.median([g.mode for g in grids1]))
    # phase 2: randomise-then-optimise
    rng = np.random.default_rng(seeding.stream(seed, "noise"))
    eta = rng.standard_normal(M)
    anchors = ei_prior.loc + ei_prior.log_sd * eta
    pdata = _rto_data(data, sigma_hat, M, rng)
    problem = Problem.from_config(cfg, pdata, noise_sd=sigma_hat, anchor=(anchors, ei_prior.log_sd))
    s2 = replace(settings, epochs=max(1, int(RTO_FRACTION * settings.epochs)), lr=settings.lr * 0.3)
    log.info("[ensemble] phase 2: randomise-then-optimise (sigma_hat = %.3g)", sigma_hat)
    r2 = fit(problem, s2, seed=seeding.stream(seed, "collocation"), members=M, device=opts.device, quiet=quiet,
             init_state=r1.state)
    member_EI = np.atleast_1d(np.asarray(r2.EI, float))
    log_ei_m = np.log(member_EI)
    # per member, on the measured data: the noise level's grid posterior and the local width of log EI
    lls = last_layers(r2)
    grids = [sigma_grid(ll, noise) for ll in lls]
    lap_sd = np.array([ll.laplace_sd_log_theta(math.log(ll.theta_fit), math.log(g.mode), ei_prior.log_sd)
                       for ll, g in zip(lls, grids, strict=True)])
    between = float(np.var(log_ei_m, ddof=1)) if M > 1 else 0.0
    lap_var = float(np.mean(lap_sd**2))
    pooled = (LAPLACE_DOF * lap_var + (M - 1) * between) / (LAPLACE_DOF + M - 1)
    mu = float(np.mean(log_ei_m))
    draw_rng = np.random.default_rng(seeding.child(seed, "ensemble", 0))
    log_ei = mu + math.sqrt(pooled) * draw_rng.standard_normal(N_DRAWS)
    sigma = np.concatenate([g.draws(-(-N_DRAWS // M), draw_rng) for g in grids])[:N_DRAWS]
    sigma = sigma[draw_rng.permutation(N_DRAWS)]
    ident = bool(math.sqrt(pooled) < IDENTIFIED_FRACTION * ei_prior.log_sd)
    info = {
        "members": M,
        "member_EI": member_EI.tolist(),
        "member_laplace_sd_log_EI": lap_sd.tolist(),
        "between_sd_log_EI": math.sqrt(between),
        "laplace_sd_log_EI": math.sqrt(lap_var),
        "pooling": f"conjugate: Laplace variance with {LAPLACE_DOF} dof + between-member variance with {M - 1} dof",
        "sigma_hat_rto": sigma_hat,
        "member_sigma_mode": [g.mode for g in grids],
        "identified": ident,
    }
    if M == 1:
        info["note"] = "a single member has no spread: its interval is its own Laplace width only"
    if not ident:
        info["note"] = "EI is not identified by these data"
    # self-check: members that scatter far more than each one's own (Laplace) uncertainty have not
    # converged to the same answer; the pooled interval then mostly measures optimisation scatter
    if M > 1 and lap_var > 0 and between > MAX_SCATTER_RATIO**2 * lap_var:
        msg = (f"the members disagree: their EI spread (sd {math.sqrt(between):.3f} in log EI) is "
               f"{math.sqrt(between / lap_var):.1f} x each member's own uncertainty ({math.sqrt(lap_var):.3f}); "
               "training has not converged to one answer, so this interval mostly measures optimisation scatter")
        log.warning("[ensemble] %s", msg)
        info["warnings"] = [msg]
    diag = {"fit_runtime_s": r1.runtime_s + r2.runtime_s, "beta_factor": r2.beta_factor}
    shift = math.log(base.EI_ref) - math.log(r2.beta_factor)
    predictor = _MixturePredictor(
        [LastLayerPredictor(ll, np.full(64, math.log(ll.theta_fit)), np.full(64, math.log(g.mode)), shift)
         for ll, g in zip(lls, grids, strict=True)]
    )
    return Posterior("ensemble", np.exp(log_ei)[None, :], sigma[None, :], diagnostics=diag, info=info,
                     runtime_s=time.perf_counter() - t0, predictor=predictor)


class _MixturePredictor:
    """Predictive draws split evenly over the members' own last-layer predictives."""

    def __init__(self, parts: list):
        self.parts = parts

    def __call__(self, x, t, quantity: str = "deflection", n_draws: int = 200, rng=None) -> np.ndarray:
        rng = rng or np.random.default_rng(0)
        k = max(1, n_draws // len(self.parts))
        return np.concatenate([p(x, t, quantity, k, rng) for p in self.parts])
