"""Reference posterior: emcee on the reduced modal surrogate.

Parameters (log EI, log sigma); Gaussian measurement noise; the closed-form modal model (exact static
part plus `n_modes` modal dynamic corrections, chosen so that the truncation error is far below the
noise) evaluated for all walkers at once. Independent groups of walkers start from a dispersed cloud
around the MAP; the run grows until it is at least `tau_factor` integrated autocorrelation times long,
and R-hat / ESS come from ArviZ with one chain per independent group (its walkers' trajectories in turn).
"""

from __future__ import annotations

import logging
import math
import time
import warnings
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from .. import seeding
from ..config import Config
from ..data.measurements import Measurements
from ..physics.modal import ModalModel
from .posterior import Posterior, mcmc_diagnostics
from .priors import EIPrior, NoisePrior

log = logging.getLogger(__name__)

#: modal truncation must stay below this fraction of the noise sd
TRUNCATION_FRACTION = 0.01
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

    @classmethod
    def for_profile(cls, profile: str) -> MCMCSettings:
        return cls(min_steps=400, tau_factor=30.0) if profile == "smoke" else cls()


class ModalLikelihood:
    """Gaussian log-likelihood of measurements under the modal surrogate, vectorised over walkers."""

    def __init__(self, cfg: Config, data: Measurements, n_modes: int = 10):
        a_u, a_xx = data.weights
        self.model = ModalModel(cfg.beam, cfg.vehicle, data.x, data.t, a_u, a_xx, n_modes=n_modes)
        self.y = np.asarray(data.value, float)
        self.n = self.y.size

    def rss(self, EI: np.ndarray) -> np.ndarray:
        """Residual sum of squares for each EI, shape (W,)."""
        r = self.y[None, :] - self.model.predict(np.atleast_1d(EI))
        return np.einsum("wp,wp->w", r, r)

    def loglik(self, log_EI: np.ndarray, log_sigma: np.ndarray) -> np.ndarray:
        rss = self.rss(np.exp(log_EI))
        return -0.5 * rss * np.exp(-2 * log_sigma) - self.n * log_sigma - 0.5 * self.n * math.log(2 * math.pi)


class LogPosterior:
    """log p(log EI, log sigma | data) up to a constant; call with theta shaped (W, 2)."""

    def __init__(self, lik: ModalLikelihood, ei_prior: EIPrior, noise_prior: NoisePrior):
        self.lik, self.ei_prior, self.noise_prior = lik, ei_prior, noise_prior

    def __call__(self, theta: np.ndarray) -> np.ndarray:
        theta = np.atleast_2d(theta)
        lp = self.ei_prior.logpdf(theta[:, 0]) + self.noise_prior.logpdf(theta[:, 1])
        out = np.full(theta.shape[0], -np.inf)
        ok = np.isfinite(lp) & (np.abs(theta[:, 0] - self.ei_prior.loc) < 12 * self.ei_prior.log_sd)
        if ok.any():
            out[ok] = lp[ok] + self.lik.loglik(theta[ok, 0], theta[ok, 1])
        return out

    def profile_sigma(self, log_EI: float) -> float:
        """log sigma maximising the posterior at fixed EI (1-D, bounded)."""
        rss = float(self.lik.rss(np.array([math.exp(log_EI)]))[0])
        lo, hi = math.log(self.noise_prior.low), math.log(self.noise_prior.high)
        f = lambda ls: -float(self(np.array([[log_EI, ls]]))[0])  # noqa: E731
        guess = 0.5 * math.log(max(rss / self.lik.n, self.noise_prior.low**2))
        res = minimize_scalar(f, bounds=(max(lo, guess - 3), min(hi, guess + 3)), method="bounded")
        return float(res.x)

    def map_estimate(self) -> tuple[float, float, float]:
        """(log EI, log sigma) at the maximum, and a Laplace sd of log EI (profile curvature)."""
        prior = self.ei_prior
        grid = prior.loc + prior.log_sd * np.linspace(-5, 5, 801)
        rss = np.concatenate([self.lik.rss(np.exp(g)) for g in np.array_split(grid, 8)])
        n = self.lik.n
        floor = self.noise_prior.low**2
        prof = -0.5 * n * np.log(np.maximum(rss / n, floor)) + prior.logpdf(grid)
        i = int(np.argmax(prof))
        lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]

        def negprof(le: float) -> float:
            r = float(self.lik.rss(np.array([math.exp(le)]))[0])
            return 0.5 * n * math.log(max(r / n, floor)) - float(prior.logpdf(le))

        res = minimize_scalar(negprof, bounds=(lo, hi), method="bounded", options={"xatol": 1e-12})
        le = float(res.x)
        h = 1e-4
        curv = (negprof(le + h) - 2 * negprof(le) + negprof(le - h)) / h**2
        sd = 1.0 / math.sqrt(curv) if curv > 0 else prior.log_sd
        return le, self.profile_sigma(le), min(sd, prior.log_sd)


def choose_modes(cfg: Config, data: Measurements, EI: float, sigma: float, start: int = 6, cap: int = 64):
    """Smallest mode count whose truncation error (against twice as many modes) is below
    TRUNCATION_FRACTION x sigma; returns (n_modes, max abs truncation error)."""
    a_u, a_xx = data.weights
    scale = float(np.sqrt(np.mean(np.asarray(data.value) ** 2)))
    tol = max(TRUNCATION_FRACTION * sigma, 1e-9 * scale)
    n = start
    while True:
        p1 = ModalModel(cfg.beam, cfg.vehicle, data.x, data.t, a_u, a_xx, n_modes=n).predict(EI)
        p2 = ModalModel(cfg.beam, cfg.vehicle, data.x, data.t, a_u, a_xx, n_modes=2 * n).predict(EI)
        err = float(np.max(np.abs(p1 - p2)))
        if err <= tol or n >= cap:
            return n, err
        n *= 2


def _group_chain(chain: np.ndarray) -> np.ndarray:
    """(step, walker, dim) -> (walker * step, dim): each walker's trajectory in turn."""
    return np.transpose(chain, (1, 0, 2)).reshape(-1, chain.shape[-1])


def modal_posterior(
    data: Measurements,
    cfg: Config,
    *,
    noise_prior: NoisePrior,
    seed: int | np.random.SeedSequence = 0,
    settings: MCMCSettings | None = None,
    progress: bool = False,
) -> Posterior:
    """Sample the reference posterior of (EI, sigma) given measurements.

    Returns a Posterior with draws shaped (walker, draw) over all groups, diagnostics (R-hat, bulk and
    tail ESS, autocorrelation time, steps, modes, truncation error, converged) and MAP information.
    """
    import emcee

    t0 = time.perf_counter()
    s = settings or MCMCSettings()
    ei_prior = EIPrior.from_spec(cfg.prior)
    lik = ModalLikelihood(cfg, data, n_modes=6)
    post = LogPosterior(lik, ei_prior, noise_prior)
    le, ls, sd = post.map_estimate()
    n_modes, trunc = choose_modes(cfg, data, math.exp(le), math.exp(ls))
    if n_modes != 6:
        lik = ModalLikelihood(cfg, data, n_modes=n_modes)
        post = LogPosterior(lik, ei_prior, noise_prior)
        le, ls, sd = post.map_estimate()
    sd_ls = 1.0 / math.sqrt(2 * lik.n)  # Laplace sd of log sigma
    samplers, states = [], []
    for g in range(s.n_groups):
        r = np.random.default_rng(seeding.child(seed, "emcee", g))
        p0 = np.column_stack(
            [le + 2.0 * sd * r.standard_normal(s.n_walkers), ls + 2.0 * sd_ls * r.standard_normal(s.n_walkers)]
        )
        sampler = emcee.EnsembleSampler(s.n_walkers, 2, post, vectorize=True)
        sampler.random_state = np.random.RandomState(seeding.int_seed(seeding.child(seed, "emcee", 100 + g)) % 2**32).get_state()
        samplers.append(sampler)
        states.append(p0)
    logging.getLogger("emcee").setLevel(logging.ERROR)  # its short-chain warning is our loop condition
    steps, tau = 0, float("nan")
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=s.min_steps, desc="modal MCMC", unit="step", leave=False)
    while True:
        for i, sampler in enumerate(samplers):
            states[i] = sampler.run_mcmc(states[i], s.chunk, progress=False)
        steps += s.chunk
        if bar is not None:
            bar.update(s.chunk)
        if steps < s.min_steps:
            continue
        taus = []
        for sampler in samplers:
            chain = sampler.get_chain()
            burn = steps // 3
            taus.append(emcee.autocorr.integrated_time(chain[burn:], quiet=True).max())
        tau = float(np.max(taus))
        need = int(math.ceil(s.tau_factor * tau + s.burn_factor * tau))
        if steps >= need or steps >= s.max_steps:
            break
        if bar is not None:
            bar.total = min(need, s.max_steps)
            bar.refresh()
    if bar is not None:
        bar.close()
    burn = int(math.ceil(max(s.burn_factor * tau, steps / 5)))
    thin = max(1, int(tau / 4))
    # one chain per independent group: its walkers' post-burn-in segments, one after another
    chains = np.stack([_group_chain(sm.get_chain(discard=burn, thin=thin)) for sm in samplers])  # (G, draw, 2)
    EI, sig = np.exp(chains[:, :, 0]), np.exp(chains[:, :, 1])
    diag = mcmc_diagnostics(EI)
    converged = bool(diag["rhat"] <= RHAT_MAX and diag["ess_bulk"] >= ESS_MIN and diag["ess_tail"] >= ESS_MIN)
    if not converged:
        warnings.warn(
            f"modal MCMC did not meet R-hat <= {RHAT_MAX} and ESS >= {ESS_MIN}: {diag}", RuntimeWarning, stacklevel=2
        )
    acc = float(np.mean([sm.acceptance_fraction.mean() for sm in samplers]))
    diag.update(
        converged=converged,
        tau=tau,
        steps=steps,
        walkers=s.n_walkers * s.n_groups,
        acceptance=acc,
        n_modes=n_modes,
        truncation_error=trunc,
        noise_prior=noise_prior.describe(),
    )
    info = {"map": {"EI": math.exp(le), "sigma": math.exp(ls)}}
    return Posterior("modal_mcmc", EI, sig, diagnostics=diag, info=info, runtime_s=time.perf_counter() - t0)
