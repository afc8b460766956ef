"""Reference posterior: emcee on the reduced modal surrogate.

Parameters (log EI, log sigma); Gaussian measurement noise; the closed-form modal model (exact static
part plus `n_modes` modal dynamic corrections, chosen so that the truncation error is far below the
noise) evaluated for all walkers at once; once the MAP is known, through a Chebyshev interpolant in log EI
around it whose log-likelihood is checked to stay within `INTERP_NATS` of the exact one (strain gauges
at 200 Hz: 8 s per run instead of 72 s, the posterior the same to every printed digit). Independent groups of walkers start from a dispersed cloud
around the MAP; the run grows until it is at least `tau_factor` integrated autocorrelation times long,
and R-hat / ESS come from ArviZ with one chain per independent group (its walkers' trajectories in turn).
"""

from __future__ import annotations

import logging
import math
import time
import warnings

import numpy as np
from scipy.optimize import minimize_scalar

from .. import seeding
from ..config import Config
from ..data.measurements import Measurements
from ..physics.loads import quantity_weights
from ..physics.modal import ModalModel
from .posterior import Posterior, mcmc_diagnostics
from .priors import EIPrior, NoisePrior, prior_only
from .sampler import ESS_MIN, RHAT_MAX, MCMCSettings, sample

log = logging.getLogger(__name__)

#: modal truncation must stay below this fraction of the noise sd
TRUNCATION_FRACTION = 0.01
#: the interpolated likelihood stays within this many nats of the exact one (`ModalLikelihood.interpolate`)
INTERP_NATS = 1e-3
#: the most Chebyshev nodes tried; the window is the MAP +- INTERP_WINDOW Laplace sds of log EI
INTERP_MAX_NODES, INTERP_WINDOW = 256, 12.0


def _chebyshev_rows(u: np.ndarray, K: int) -> np.ndarray:
    """T_0..T_(K-1) at u in [-1, 1], rows (cos(k arccos u): one vectorised call, not a K-step recurrence)."""
    return np.cos(np.arccos(np.clip(u, -1.0, 1.0))[:, None] * np.arange(K)[None, :])


class ModalLikelihood:
    """Gaussian log-likelihood of measurements under the modal surrogate, vectorised over walkers.

    After `interpolate`, predictions for log EI inside a window around the MAP come from a Chebyshev
    interpolant in log EI (a (W, K) @ (K, P) product instead of the modal sums; K chosen so that the
    collapsed log-likelihood -(n/2) log RSS differs from the exact one by at most `INTERP_NATS` between
    the nodes, where a Chebyshev interpolant's error peaks); outside the window, and without it, they are
    exact."""

    def __init__(self, cfg: Config, data: Measurements, n_modes: int = 10):
        a_u, a_xx = data.weights
        self.model = ModalModel(cfg.beam, cfg.vehicle, data.x, data.t, a_u, a_xx, n_modes=n_modes)
        self.y = np.asarray(data.value, float)
        self.n = self.y.size
        self.cheb: tuple[float, float, np.ndarray] | None = None
        self.interpolation: dict = {"used": False}

    def _predict(self, log_EI: np.ndarray) -> np.ndarray:
        log_EI = np.atleast_1d(np.asarray(log_EI, float))
        if self.cheb is None:
            return self.model.predict(np.exp(log_EI))
        c, hw, coef = self.cheb
        u = (log_EI - c) / hw
        inside = np.abs(u) <= 1.0
        out = np.empty((log_EI.size, self.n))
        if inside.any():
            out[inside] = _chebyshev_rows(u[inside], coef.shape[0]) @ coef
        if not inside.all():
            out[~inside] = self.model.predict(np.exp(log_EI[~inside]))
        return out

    def rss_log(self, log_EI: np.ndarray) -> np.ndarray:
        """Residual sum of squares for each log EI, shape (W,)."""
        r = self.y[None, :] - self._predict(log_EI)
        return np.einsum("wp,wp->w", r, r)

    def rss(self, EI: np.ndarray) -> np.ndarray:
        """Residual sum of squares for each EI, shape (W,)."""
        EI = np.atleast_1d(np.asarray(EI, float))
        if self.cheb is not None:
            return self.rss_log(np.log(EI))
        r = self.y[None, :] - self.model.predict(EI)
        return np.einsum("wp,wp->w", r, r)

    def interpolate(self, center: float, half_width: float) -> dict:
        """Replace the modal sums by a Chebyshev interpolant in log EI on center +- half_width, with the
        fewest nodes (16, 32, ..., INTERP_MAX_NODES) whose collapsed log-likelihood is within INTERP_NATS
        of the exact one at the midpoints between nodes; none when even the most nodes miss that."""
        K = 16
        while K <= INTERP_MAX_NODES:
            nodes = np.cos(np.pi * (np.arange(K) + 0.5) / K)  # Chebyshev points of the first kind
            Y = self.model.predict(np.exp(center + half_width * nodes))
            coef = np.linalg.solve(_chebyshev_rows(nodes, K), Y)
            mid = np.cos(np.pi * np.arange(1, K) / K)  # between consecutive nodes
            exact = self.y[None, :] - self.model.predict(np.exp(center + half_width * mid))
            approx = self.y[None, :] - _chebyshev_rows(mid, K) @ coef
            rss_e = np.einsum("wp,wp->w", exact, exact)
            rss_a = np.einsum("wp,wp->w", approx, approx)
            err = float(np.max(0.5 * self.n * np.abs(np.log(rss_a / rss_e))))
            if err <= INTERP_NATS:
                self.cheb = (float(center), float(half_width), coef)
                self.interpolation = {
                    "used": True,
                    "nodes": K,
                    "log_EI_window": [center - half_width, center + half_width],
                    "max_loglik_error_nats": err,
                }
                return self.interpolation
            K *= 2
        self.interpolation = {"used": False, "reason": f"no interpolant within {INTERP_NATS} nats"}
        return self.interpolation

    def loglik(self, log_EI: np.ndarray, log_sigma: np.ndarray) -> np.ndarray:
        rss = self.rss_log(log_EI)
        return (
            -0.5 * rss * np.exp(-2 * log_sigma)
            - self.n * log_sigma
            - 0.5 * self.n * math.log(2 * math.pi)
        )


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


class MarginalLogPosterior:
    """log p(log EI | data) with sigma integrated out under the log-uniform (Jeffreys) prior:
    log prior(EI) - (n/2) log RSS(EI). Call with theta shaped (W, 1)."""

    def __init__(self, lik: ModalLikelihood, ei_prior: EIPrior):
        self.lik, self.ei_prior = lik, ei_prior

    def __call__(self, theta: np.ndarray) -> np.ndarray:
        le = np.atleast_2d(theta)[:, 0]
        out = np.full(le.shape, -np.inf)
        ok = np.abs(le - self.ei_prior.loc) < 12 * self.ei_prior.log_sd
        if ok.any():
            out[ok] = self.ei_prior.logpdf(le[ok]) - 0.5 * self.lik.n * np.log(
                self.lik.rss_log(le[ok])
            )
        return out


def choose_modes(
    cfg: Config, data: Measurements, EI: float, sigma: float, start: int = 6, cap: int = 64
):
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


def modal_posterior(
    data: Measurements,
    cfg: Config,
    *,
    noise_prior: NoisePrior,
    seed: int | np.random.SeedSequence = 0,
    settings: MCMCSettings | None = None,
    progress: bool = False,
    method: str,
) -> Posterior:
    """Sample the reference posterior of (EI, sigma) given measurements, labelled `method` (the
    reference's summary key, `methods.REFERENCE_KEY`).

    Returns a Posterior with draws shaped (walker, draw) over all groups, diagnostics (R-hat, bulk and
    tail ESS, autocorrelation time, steps, modes, truncation error, converged) and MAP information.
    """
    t0 = time.perf_counter()
    s = settings or MCMCSettings()
    ei_prior = EIPrior.from_spec(cfg.prior)
    if len(data) == 0:
        return prior_only(ei_prior, seed, t0, method)
    lik = ModalLikelihood(cfg, data, n_modes=6)
    post = LogPosterior(lik, ei_prior, noise_prior)
    le, ls, sd = post.map_estimate()
    n_modes, trunc = choose_modes(cfg, data, math.exp(le), math.exp(ls))
    if n_modes != 6:
        lik = ModalLikelihood(cfg, data, n_modes=n_modes)
        post = LogPosterior(lik, ei_prior, noise_prior)
        le, ls, sd = post.map_estimate()
    interp = lik.interpolate(le, INTERP_WINDOW * sd)
    if noise_prior.kind == "vague":
        # collapsed sampler: sigma integrated out exactly (log-uniform prior -> RSS^(-n/2)), emcee on
        # log EI alone, then sigma^2 | EI ~ InvGamma(n/2, RSS/2) drawn exactly for every EI draw
        marg = MarginalLogPosterior(lik, ei_prior)
        ch = sample(marg, [le], [sd], s, seed, progress, desc="modal MCMC")
        EI = np.exp(ch.draws[:, :, 0])
        # RSS from the stored log density: lp = log prior - (n/2) log RSS
        rss = np.exp((ei_prior.logpdf(ch.draws[:, :, 0]) - ch.lp) * (2.0 / lik.n)).ravel()
        g = np.random.default_rng(seeding.stream(seed, "noise")).gamma(
            lik.n / 2.0, 1.0, size=rss.size
        )
        sig = np.sqrt(rss / (2.0 * g)).reshape(EI.shape)
        sig = np.clip(sig, noise_prior.low, noise_prior.high)
        scheme = "emcee on log EI with sigma marginalised; exact inverse-gamma sigma draws"
    else:
        sd_ls = 1.0 / math.sqrt(2 * lik.n)  # Laplace sd of log sigma
        ch = sample(post, [le, ls], [sd, sd_ls], s, seed, progress, desc="modal MCMC")
        EI, sig = np.exp(ch.draws[:, :, 0]), np.exp(ch.draws[:, :, 1])
        scheme = "emcee on (log EI, log sigma)"
    diag = mcmc_diagnostics(EI)
    converged = bool(
        diag["rhat"] <= RHAT_MAX and diag["ess_bulk"] >= ESS_MIN and diag["ess_tail"] >= ESS_MIN
    )
    if not converged:
        warnings.warn(
            f"modal MCMC did not meet R-hat <= {RHAT_MAX} and ESS >= {ESS_MIN}: {diag}",
            RuntimeWarning,
            stacklevel=2,
        )
    diag.update(
        converged=converged,
        tau=ch.tau,
        steps=ch.steps,
        walkers=s.n_walkers * s.n_groups,
        acceptance=ch.acceptance,
        n_modes=n_modes,
        truncation_error=trunc,
        interpolation=interp,
        noise_prior=noise_prior.describe(),
        scheme=scheme,
    )
    info = {
        "map": {"EI": math.exp(le), "sigma": math.exp(ls)},
        "identified": bool(np.std(np.log(EI)) < 0.5 * ei_prior.log_sd),
    }
    if not info["identified"]:
        info["note"] = "EI is not identified by these data"
    return Posterior(
        method,
        EI,
        sig,
        diagnostics=diag,
        info=info,
        runtime_s=time.perf_counter() - t0,
        predictor=ModalPredictor(cfg, EI.ravel(), n_modes),
        sample_stats={"lp": ch.lp, "acceptance": ch.walker_acceptance},
    )


class ModalPredictor:
    """Posterior predictive of the modal model: responses for EI draws (noise-free)."""

    def __init__(self, cfg: Config, EI_draws: np.ndarray, n_modes: int):
        self.cfg, self.EI, self.n_modes = cfg, np.asarray(EI_draws), n_modes

    def __call__(
        self, x, t, quantity: str = "deflection", n_draws: int = 200, rng=None
    ) -> np.ndarray:
        rng = rng or np.random.default_rng(0)
        ei = rng.choice(self.EI, size=min(n_draws, self.EI.size), replace=False)
        x, t = np.broadcast_arrays(np.asarray(x, float).ravel(), np.asarray(t, float).ravel())
        w = quantity_weights(quantity)
        m = ModalModel(self.cfg.beam, self.cfg.vehicle, x, t, *w, n_modes=max(self.n_modes, 24))
        out = m.predict(ei)
        return -ei[:, None] * out if quantity == "moment" else out
