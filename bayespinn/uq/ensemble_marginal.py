"""Each deep-ensemble member's own posterior (`uq.ensemble`), from the exact last-layer marginal likelihood
of its trained features on the measured data: the grid posterior of its noise level (`sigma_grid`; with
AR(1) noise jointly with the coefficient, `ar1_grid`), its local width of log EI (`local_sd`), its marginal
of log EI on a grid that follows the peak (`member_marginal`), and the members' equal mixture
(`pool_log_ei`).

Apart from the members' training (`uq.ensemble`) and the pooled posterior (`uq.ensemble_pool`) because
the batched ensembles of many datasets (`uq.ensemble_batch`) and the studies use these pieces on their own.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from ..threads import torch_threads
from .lastlayer import (
    GRID_EDGE,
    LastLayer,
    log_prior_z,
)
from .lastlayer_grid import log_marginal_grid
from .priors import EIPrior, NoisePrior

#: the ensemble's logger: its warnings read as they did when this was part of `uq.ensemble`
log = logging.getLogger("bayespinn.uq.ensemble")

#: the grid of log sigma: this many points over +-`SIGMA_GRID_HALF_WIDTH` around the fit's residual level
SIGMA_GRID_POINTS = 241
SIGMA_GRID_HALF_WIDTH = 1.2


@dataclass(frozen=True)
class SigmaGrid:
    """p(log sigma | EI, y) of a last-layer model on a grid (log-uniform prior on sigma); with AR(1) noise
    p(log sigma, z | EI, y) on a grid of both (``z`` the axis of z = atanh rho, ``prob`` (sigma, z))."""

    log_sigma: np.ndarray
    prob: np.ndarray
    z: np.ndarray | None = None

    @property
    def mode(self) -> float:
        """sigma's mode (of its marginal where the grid has a z axis)."""
        p = self.prob if self.z is None else self.prob.sum(axis=1)
        return float(np.exp(self.log_sigma[int(np.argmax(p))]))

    def at_edge(self, tol: float) -> bool:
        """Does the density at an edge of the grid exceed `tol` of its peak (the grid cuts off mass)? The
        coefficient's axis is exempt where it is clipped at the support's bound."""
        from .ar1 import Z_MAX

        p = self.prob / self.prob.max()
        if self.z is None:
            return bool(max(p[0], p[-1]) > tol)
        edges = [p[0].max(), p[-1].max()]
        if self.z[0] > -Z_MAX:
            edges.append(p[:, 0].max())
        if self.z[-1] < Z_MAX:
            edges.append(p[:, -1].max())
        return bool(max(edges) > tol)

    @property
    def z_mode(self) -> float | None:
        """The mode of z = atanh rho's marginal, or None for white noise."""
        if self.z is None:
            return None
        return float(self.z[int(np.argmax(self.prob.sum(axis=0)))])

    def draws(self, k: int, rng: np.random.Generator) -> np.ndarray:
        """k draws of sigma: a grid cell by its probability, uniform within it."""
        h = self.log_sigma[1] - self.log_sigma[0]
        i = rng.choice(self.prob.size, size=k, p=self.prob)
        return np.exp(self.log_sigma[i] + h * (rng.random(k) - 0.5))

    def draws_ar1(self, k: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """k joint draws of (sigma, rho) from the two-dimensional grid (a cell by its probability, uniform
        within it)."""
        hs, hz = self.log_sigma[1] - self.log_sigma[0], self.z[1] - self.z[0]
        flat = rng.choice(self.prob.size, size=k, p=self.prob.ravel())
        i, j = np.unravel_index(flat, self.prob.shape)
        u = rng.random((2, k)) - 0.5
        return np.exp(self.log_sigma[i] + hs * u[0]), np.tanh(self.z[j] + hz * u[1])


def sigma_grid(ll: LastLayer, noise: NoisePrior) -> SigmaGrid:
    """The noise level's posterior for one member at its fitted EI (see the module docstring); with the
    SNR-conditioned noise prior its log-normal density is added (as in the B-PINN). With AR(1) noise the
    joint posterior of sigma and the coefficient (`ar1_grid`)."""

    if ll.ar1 is not None:
        return ar1_grid(ll, noise)

    center = 0.5 * math.log(max(ll.fit_rss, 1e-300) / max(ll.n, 1))
    grid = center + np.linspace(-SIGMA_GRID_HALF_WIDTH, SIGMA_GRID_HALF_WIDTH, SIGMA_GRID_POINTS)
    with torch_threads(1):
        lp = log_marginal_grid(ll, math.log(ll.theta_fit), grid)
    if noise.kind == "snr":
        lp = lp - 0.5 * ((grid - math.log(noise.center)) / noise.log_sd) ** 2
    if int(np.argmax(lp)) in (0, grid.size - 1):
        log.warning(
            "[ensemble] the noise level's posterior reaches the edge of its grid (%.3g .. %.3g)",
            math.exp(grid[0]),
            math.exp(grid[-1]),
        )
    p = np.exp(lp - lp.max())
    return SigmaGrid(grid, p / p.sum())


#: the AR(1) noise grid: points per axis, and its half-width in Laplace sds of each axis
AR1_GRID_POINTS = 41
AR1_GRID_HALF_WIDTH = 6.0


def ar1_grid(ll: LastLayer, noise: NoisePrior) -> SigmaGrid:
    """p(log sigma, z | EI_fit, y) of a last-layer model with AR(1) noise, z = atanh rho under rho's uniform
    prior, on a grid of AR1_GRID_POINTS^2 around its mode (+-AR1_GRID_HALF_WIDTH Laplace sds of each): the
    mode by L-BFGS from the fit residuals' level and lag-1 autocorrelation, the sds from the Hessian there."""
    import torch
    from scipy.optimize import minimize

    from .ar1 import Z_MAX

    T = lambda v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
    lt = T(math.log(ll.theta_fit))

    def logp(ls, z):
        out = ll.log_marginal(lt, ls, z) + log_prior_z(z)
        if noise.kind == "snr":
            out = out - 0.5 * ((ls - math.log(noise.center)) / noise.log_sd) ** 2
        return out

    def neg(v):
        x = torch.tensor(v, dtype=torch.float64, requires_grad=True)
        f = -logp(x[0], x[1])
        (g,) = torch.autograd.grad(f, x)
        return float(f.detach()), g.numpy()

    x0 = [0.5 * math.log(max(ll.fit_rss, 1e-300) / max(ll.n, 1)), ll.z_start()]
    with torch_threads(1):
        opt = minimize(neg, x0, jac=True, method="L-BFGS-B", bounds=[(None, None), (-Z_MAX, Z_MAX)])
        H = torch.autograd.functional.hessian(lambda x: -logp(x[0], x[1]), T(opt.x))
    H = H.numpy()
    try:
        cov = np.linalg.inv(H)
        sd = np.sqrt(np.diag(cov))
        ok = bool(np.all(np.isfinite(sd)) and np.all(np.linalg.eigvalsh(H) > 0))
    except np.linalg.LinAlgError:
        ok = False
    if not ok:  # no curvature at the optimum: a wide grid
        log.warning(
            "[ensemble] the AR(1) noise posterior has no curvature at its mode; using a wide grid"
        )
        sd = np.array([0.2, 0.2])
    h = AR1_GRID_HALF_WIDTH
    ls_ax = opt.x[0] + np.linspace(-h * sd[0], h * sd[0], AR1_GRID_POINTS)
    z_ax = np.clip(opt.x[1] + np.linspace(-h * sd[1], h * sd[1], AR1_GRID_POINTS), -Z_MAX, Z_MAX)
    with torch.no_grad(), torch_threads(1):
        # z outer: the last layer reuses its first-mode block across sigma (`LastLayer._vary_block`)
        lp = np.array([[float(logp(T(a), T(b))) for a in ls_ax] for b in z_ax]).T
    p = np.exp(lp - lp.max())
    if max(p[0].max(), p[-1].max(), p[:, 0].max(), p[:, -1].max()) > 1e-4:
        log.warning("[ensemble] the AR(1) noise posterior reaches the edge of its grid")
    return SigmaGrid(ls_ax, p / p.sum(), z_ax)


#: a member's marginal of log EI: grid points over +-MARGINAL_HALF_WIDTH local sds, re-centred on the peak
#: and widened (x MARGINAL_WIDEN) up to MARGINAL_TRIES times until both ends hold less than GRID_EDGE of it
MARGINAL_POINTS = 321
MARGINAL_HALF_WIDTH = 8.0
MARGINAL_WIDEN = 2.0
MARGINAL_TRIES = 5


@dataclass(frozen=True)
class MemberMarginal:
    """p(log EI | y, a member's features, sigma at its mode) on a grid: the member's posterior of EI."""

    log_ei: np.ndarray
    prob: np.ndarray

    @property
    def mean(self) -> float:
        return float((self.prob * self.log_ei).sum())

    @property
    def var(self) -> float:
        return float((self.prob * (self.log_ei - self.mean) ** 2).sum())

    def draws(self, k: int, rng: np.random.Generator) -> np.ndarray:
        """k draws of log EI: a grid cell by its probability, uniform within it."""
        h = self.log_ei[1] - self.log_ei[0]
        i = rng.choice(self.prob.size, size=k, p=self.prob)
        return self.log_ei[i] + h * (rng.random(k) - 0.5)


def member_marginal(
    ll: LastLayer, grid: SigmaGrid, ei_prior: EIPrior, log_shift: float, sd: float
) -> MemberMarginal | None:
    """Member's exact last-layer marginal of log EI on the measured data (sigma, and an AR(1)
    coefficient, held at their modes), times the EI prior; log EI = log theta + `log_shift`. The grid
    starts at the member's trained EI, `sd` (its local width) sets its step, and it follows the peak:
    the trained EI can sit several local widths from the marginal's mean (module docstring). None when
    there is no width (`sd` nan) or the density never falls off within the grid."""

    if not (math.isfinite(sd) and sd > 0):
        return None
    centre, half = math.log(ll.theta_fit), MARGINAL_HALF_WIDTH * sd
    ls = math.log(grid.mode)
    for _ in range(MARGINAL_TRIES):
        g = centre + np.linspace(-half, half, MARGINAL_POINTS)
        lp = log_marginal_grid(ll, g, ls, grid.z_mode)
        lp = lp - 0.5 * ((g + log_shift - ei_prior.loc) / ei_prior.log_sd) ** 2
        p = np.exp(lp - lp.max())
        if max(p[0], p[-1]) < GRID_EDGE:
            return MemberMarginal(g + log_shift, p / p.sum())
        centre, half = float(g[int(np.argmax(p))]), half * MARGINAL_WIDEN
    return None


def pool_log_ei(
    log_ei_fit: np.ndarray, marginals: list, prior_log_sd: float
) -> tuple[float, float, float, float, float]:
    """(mean, between-member variance, mean local variance, members with a marginal, ensemble variance) of
    log EI.

    The ensemble's posterior is the equal mixture of its members' marginals (module docstring): mean the
    mean of their means, variance the mean of their variances plus the variance of their means. Members
    without a marginal (None) are left out. With no member's marginal the trained EIs stand for the
    posterior: their mean, variance between (1 + 1 / M); with one member and none, the prior's variance.
    """
    log_ei_fit = np.asarray(log_ei_fit, float)
    M = log_ei_fit.size
    ok = [m for m in marginals if m is not None]
    if ok:
        means = np.array([m.mean for m in ok])
        between = float(np.var(means))
        lap_var = float(np.mean([m.var for m in ok]))
        return float(means.mean()), between, lap_var, float(len(ok)), lap_var + between
    between = float(np.var(log_ei_fit, ddof=1)) if M > 1 else 0.0
    pooled = between * (1.0 + 1.0 / M) if M > 1 else prior_log_sd**2
    return float(log_ei_fit.mean()), between, 0.0, 0.0, pooled


def local_sd(ll: LastLayer, grid: SigmaGrid, ei_prior: EIPrior) -> float:
    """A member's own width of log EI: the sd of its last-layer marginal at its noise level's mode (and, with
    AR(1) noise, its coefficient's)."""
    return ll.local_sd_log_theta(
        math.log(ll.theta_fit), math.log(grid.mode), ei_prior.log_sd, z=grid.z_mode
    )
