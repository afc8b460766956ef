"""What a last-layer model's exact marginal (`uq.lastlayer.LastLayer`) says once it is built: the output
weights' Gaussian posterior given (theta, sigma), the local width of log theta (from the curvature, and on
a grid where the marginal is skewed), and posterior predictive draws, with the predictor a `Posterior`
carries and the test of whether the data identify EI.

`LastLayerPosterior` holds these methods of `LastLayer` (which derives from it) in a module of their own:
they only read the marginal's linear system (`_system`, `log_marginal`), which `uq.lastlayer` builds.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from .lastlayer_algebra import _cholesky, feature_jet
from .priors import EIPrior

#: `local_sd_log_theta`'s grid: points, starting half-width in Laplace sds, doublings allowed, and the
#: density (relative to the peak) its ends must fall below (1e-4: the tails beyond hold < 1e-4 of the mass
#: of a Gaussian, so the sd is off by less than 0.1 %). The points resolve a rough marginal: the test
#: fixture's smoke fit (no curvature at the fit, its log density jumping by nats between neighbouring
#: values) gave 0.1740 with 321 points against 0.1713 from 8001, and 0.1713 with 641
GRID_POINTS = 641
GRID_HALF_WIDTH = 6.0
GRID_DOUBLINGS = 4
GRID_EDGE = 1e-4


class LastLayerPosterior:
    """The methods of `uq.lastlayer.LastLayer` that read its exact marginal: the weights' posterior, the
    widths of log theta and the predictive (this module's docstring)."""

    def weights_posterior(
        self, log_theta: float, log_sigma: float, z: float | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Mean (k,) and covariance (k, k) of the output weights beta = gamma / theta given theta, sigma (and
        the AR(1) coefficient's z, default `self.z`)."""
        with torch.no_grad():
            A, b, *_ = self._system(
                torch.tensor(log_theta, dtype=torch.float64),
                torch.tensor(log_sigma, dtype=torch.float64),
                z,
            )
            Lc = _cholesky(A)
            mean = torch.cholesky_solve(b.unsqueeze(-1), Lc).squeeze(-1)
            cov = torch.cholesky_inverse(Lc)
        it = math.exp(-log_theta)
        return mean * it, cov * it**2

    def laplace_sd_log_theta(
        self, log_theta: float, log_sigma: float, prior_sd: float, z: float | None = None
    ) -> float:
        """sd of log theta from the curvature of the log marginal (sigma held) plus the prior's; nan when the
        log marginal is not concave in log theta there (no local width to report)."""
        lt = torch.tensor(log_theta, dtype=torch.float64, requires_grad=True)
        ls = torch.tensor(log_sigma, dtype=torch.float64)
        (g,) = torch.autograd.grad(self.log_marginal(lt, ls, z), lt, create_graph=True)
        (h,) = torch.autograd.grad(g, lt)
        if not -float(h) > 0:
            return float("nan")
        return 1.0 / math.sqrt(-float(h) + 1.0 / prior_sd**2)

    def local_sd_log_theta(
        self,
        log_theta: float,
        log_sigma: float,
        prior_sd: float,
        points: int = GRID_POINTS,
        z: float | None = None,
    ) -> float:
        """sd of log theta under the log marginal (sigma held) times the prior's curvature, on a grid
        around log_theta: the Laplace width where the marginal is Gaussian, and the true width where it is
        not (at 10 dB the first mode's frequency makes it skewed and heavy-tailed: measured on the quick
        start's members, Laplace 1.8 % against 2.5 % from NUTS). The grid starts at +-GRID_HALF_WIDTH Laplace
        sds (or the prior sd where there is no curvature) and doubles until its ends hold less than
        GRID_EDGE of the peak density; nan when the density never falls (no local width). sigma (and the
        AR(1) coefficient's z, default `self.z`) are held."""
        lap = self.laplace_sd_log_theta(log_theta, log_sigma, prior_sd, z)
        half = GRID_HALF_WIDTH * lap if math.isfinite(lap) else prior_sd
        ls = torch.tensor(log_sigma, dtype=torch.float64)
        from .lastlayer_grid import log_marginal_grid  # the grid as one batch

        for _ in range(GRID_DOUBLINGS + 1):
            g = log_theta + np.linspace(-half, half, points)
            lp = log_marginal_grid(self, g, float(ls), z)
            lp = lp - 0.5 * ((g - log_theta) / prior_sd) ** 2
            p = np.exp(lp - lp.max())
            if max(p[0], p[-1]) < GRID_EDGE:
                p /= p.sum()
                m = float((p * g).sum())
                return math.sqrt(float((p * (g - m) ** 2).sum()))
            half *= 2.0
        return float("nan")

    def weights_factor(
        self, log_theta: float, log_sigma: float, z: float | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Mean (k,) and lower Cholesky factor (k, k) of the output weights' posterior given theta, sigma
        (and z): what one predictive weight draw needs."""
        mean, cov = self.weights_posterior(log_theta, log_sigma, z)
        return mean, torch.linalg.cholesky(cov + 1e-30 * torch.eye(self.k, dtype=torch.float64))

    def predictive(
        self,
        x,
        t,
        kx: int,
        draws_log_theta,
        draws_log_sigma,
        rng: np.random.Generator,
        draws_z=None,
        factors: dict | None = None,
    ) -> np.ndarray:
        """Draws (S, P) of u [m] (kx=0) or u_xx [1/m] (kx=2) at x [m], t [s], one weight draw per (theta, sigma)
        (and AR(1) coefficient's z, `draws_z`; default `self.z`). `factors`: a dict that keeps each
        (theta, sigma, z)'s `weights_factor` for the next call with the same draws (building the weights'
        posterior is the cost of a draw; the report asks for the same draws at many points)."""
        sc = self.sc
        T = lambda a: torch.as_tensor(np.array(a, float).ravel(), dtype=torch.float64)  # noqa: E731
        xi, tau = T(x) / sc.L, T(t) / sc.T
        j = feature_jet(self.model, self.member, xi, tau, kx, 0)
        Phi_f = j.dx(kx)[:, : self.kf]
        scale = sc.U / sc.L**kx
        out = np.empty((len(draws_log_theta), Phi_f.shape[0]))
        zs = [None] * len(draws_log_theta) if draws_z is None else draws_z
        factors = {} if factors is None else factors
        jv = None
        if self.fv is not None:
            # the first mode's columns at every draw's theta, as one batch (S, P, nv)
            lts = torch.as_tensor(np.asarray(draws_log_theta, float).ravel(), dtype=torch.float64)
            with torch.no_grad():
                jv = self.fv.jet(
                    xi.expand(lts.numel(), -1), tau.expand(lts.numel(), -1), kx, 0, lts
                )
            jv = jv.dx(kx)
        for i, (lt, ls, zz) in enumerate(zip(draws_log_theta, draws_log_sigma, zs, strict=True)):
            key = (float(lt), float(ls), None if zz is None else float(zz))
            if key not in factors:
                factors[key] = self.weights_factor(*key)
            mean, Lc = factors[key]
            Phi = Phi_f if jv is None else torch.cat([Phi_f, jv[i]], dim=1)
            z = torch.as_tensor(rng.standard_normal(self.k), dtype=torch.float64)
            out[i] = (Phi @ (mean + Lc @ z)).numpy() * scale
        return out


#: EI counts as identified when the posterior sd of log EI is below this fraction of the prior's
IDENTIFIED_FRACTION = 0.5


def identified(log_ei_draws: np.ndarray, prior: EIPrior) -> bool:
    """Do the data move EI away from its prior? (posterior sd of log EI < half the prior sd)"""
    return bool(np.std(log_ei_draws) < IDENTIFIED_FRACTION * prior.log_sd)


class LastLayerPredictor:
    """Posterior predictive of a last-layer model: deflection, curvature or moment for (EI, sigma) draws."""

    def __init__(
        self,
        ll: LastLayerPosterior,
        log_theta: np.ndarray,
        log_sigma: np.ndarray,
        shift: float,
        z: np.ndarray | None = None,
    ):
        self.ll, self.lt, self.ls, self.shift, self.z = ll, log_theta, log_sigma, shift, z
        #: the order the posterior draws are used in (drawn from the first call's rng), and the weights'
        #: posterior of each draw used so far: every call takes the first n_draws of one random order, so a
        #: report's many calls (instants, quantities, sensors) build each draw's weights posterior once
        self._order: np.ndarray | None = None
        self._factors: dict = {}

    def __call__(
        self, x, t, quantity: str = "deflection", n_draws: int = 200, rng=None
    ) -> np.ndarray:
        rng = rng or np.random.default_rng(0)
        if self._order is None:
            self._order = rng.permutation(self.lt.size)
        idx = self._order[: min(n_draws, self.lt.size)]
        z = None if self.z is None else self.z[idx]
        args = (self.lt[idx], self.ls[idx], rng, z, self._factors)
        if quantity == "deflection":
            return self.ll.predictive(x, t, 0, *args)
        if quantity in ("curvature", "moment"):
            k = self.ll.predictive(x, t, 2, *args)
            return -np.exp(self.lt[idx] + self.shift)[:, None] * k if quantity == "moment" else k
        raise ValueError(f"quantity must be deflection, moment or curvature, got {quantity!r}")
