"""The girder PINN's last layer (`uq.girder_pinn`): log p(y | phi, sigma) of a trained network with its
output layer (c, c_E) integrated out exactly on fixed points, with pseudo-sds stated from the fit's own
residuals (`GirderLastLayer`), and its MAP, gradient, Hessian and covariance in phi for the deep ensemble's
importance sampling and the B-PINN's NUTS. The posteriors built on it are in `uq.girder_pinn`.

AR(1) noise (`noise`, `uq.ar1`): the data rows are whitened along each sensor's series at the coefficient
rho = tanh(zeta), zeta the last coordinate after log sigma, exactly as `uq.lastlayer` does for the uniform
girder: x_k -> (x_k - rho x_(k-1)) / sqrt(1 - rho^2) for every non-first sample, the whitening's Jacobian
(n - m) log cosh zeta for m series, and rho's uniform prior. The network's features' Gram products split
into four fixed pieces (first, current and previous rows, `_pieces`) combined at each rho; the enrichment
column, which changes with phi, is whitened where it is used.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch

from .. import seeding
from .ar1 import Z_MAX, AR1Noise, lag1
from .girder_net import (
    RIDGE,
    TRAIN_PHYSICS_SD,
    GirderFit,
    GirderNetSettings,
    GirderProblem,
    Points,
    Scales_,
    _detach,
    _solve,
    data_terms,
    enrichment_column,
    physics,
    pieces,
)
from .lastlayer import MIN_PSEUDO_SD, WEIGHT_PRIOR_FACTOR
from .lastlayer_algebra import _log_cosh, _pieces, combine_pieces, log_prior_z, whiten_rows

#: the PDE rows' sd is the fit's RMS PDE residual times this. The uniform girder's last layer uses 1
#: (`lastlayer.PDE_SD_FACTOR`, chosen on family seed 1); this network's physics rows are built differently
#: (segments, springs, a load factor; trained at a physics sd of 1e-2) and its factor has not been chosen
#: that way: it stays at the value both paths had before
GIRDER_PDE_SD_FACTOR = 10.0


def split_z(z, k: int, ar1: bool):
    """(phi, log sigma, zeta or None) of parameter vectors z (..., dim): phi's k entries, then log sigma, then
    with AR(1) noise zeta = atanh rho."""
    return z[..., :k], z[..., k], (z[..., k + 1] if ar1 else None)


class GirderLastLayer:
    """log p(y | phi, sigma[, rho]) with the output layer (c, c_E) integrated out exactly (`uq.girder_pinn`'s
    docstring), for a trained network on fixed points.

    The parameter vector z of `log_post`, `map` and the samplers is (phi, log sigma), and with AR(1) noise
    (`noise`) (phi, log sigma, zeta), rho = tanh(zeta) (module docstring); `dim` is its length."""

    def __init__(
        self,
        problem: GirderProblem,
        fit: GirderFit,
        settings: GirderNetSettings,
        seed,
        noise: AR1Noise | None = None,
    ):
        self.problem = problem
        gen = torch.Generator().manual_seed(seeding.int_seed(seed))
        self.pts = Points.draw(settings, gen)
        with torch.no_grad():
            self.P = _detach(pieces(problem, fit.net, self.pts, problem.y))
        # pseudo-sds from the fit's own residuals at its phi (a function of the fit, stated not tuned)
        self.s_f, self.s_b, self.s_i, self.s_w, self.c_fit = self._scales(fit.phi)
        self.network_share = self._network_share(fit.phi)
        self.n = problem.y.size
        self.phi_fit = np.asarray(fit.phi, float)
        self.ar1 = noise
        self.dim = problem.dim + 1 + (noise is not None)
        if noise is not None:
            if noise.n != self.n:
                raise ValueError(f"the AR(1) series cover {noise.n} points, the data {self.n}")
            ix = lambda a: torch.as_tensor(a, dtype=torch.long)  # noqa: E731
            self._f, self._c, self._p = ix(noise.first), ix(noise.cur), ix(noise.prev)
            D, y = self.P.Phi_d, torch.as_tensor(problem.y, dtype=torch.float64)
            rows = lambda X: (X[self._f], X[self._c], X[self._p])  # noqa: E731
            self._ar_dd = _pieces(*rows(D), *rows(D))
            self._ar_dy = _pieces(*rows(D), *rows(y))
            self._ar_yy = _pieces(*rows(y), *rows(y))

    def _scales(self, phi: np.ndarray):
        pr, P = self.problem, self.P
        phit = torch.as_tensor(phi)
        sc = Scales_(pr.sigma0, TRAIN_PHYSICS_SD, TRAIN_PHYSICS_SD, TRAIN_PHYSICS_SD, None)
        E = enrichment_column(pr, phit)
        Ap, gp, _ = physics(pr, P, phit, sc)
        Ad, gd, _ = data_terms(pr, P, E, sc.sigma)
        c, _ = _solve(Ap + Ad, gp + gd)
        theta, left, right, lam = pr.coefficients(phit)
        cn, ce = c[:-1], c[-1]
        a = torch.cat([theta, torch.ones(1, dtype=torch.float64)])
        Gnn = torch.einsum("i,j,ijDE->DE", a, a, P.KK)
        Gne = torch.einsum("i,iD->D", a, P.Kf)
        rf = cn @ Gnn @ cn + 2 * (ce - lam) * (Gne @ cn) + (ce - lam) ** 2 * P.ff
        Gb = P.vv + torch.einsum("a,b,abDE->DE", left, left, P.mm[0])
        Gb = Gb + torch.einsum("a,b,abDE->DE", right, right, P.mm[1])
        k = P.counts
        rms = lambda ss, m: math.sqrt(max(float(ss), 0.0) / m)  # noqa: E731
        s_f = max(GIRDER_PDE_SD_FACTOR * rms(rf, k["pde"]), MIN_PSEUDO_SD)
        s_b = max(rms(cn @ Gb @ cn, 2 * k["bc"]), MIN_PSEUDO_SD)
        s_i = max(rms(cn @ P.ic @ cn, 2 * k["ic"]), MIN_PSEUDO_SD)
        s_w = WEIGHT_PRIOR_FACTOR * float(c.abs().max())
        return s_f, s_b, s_i, s_w, c.detach()

    @torch.no_grad()
    def _network_share(self, phi: np.ndarray) -> float:
        """The share of the fitted response's energy at the data points that the network's own columns carry
        beyond the enrichment (the reference's modal model at phi): |D c_n|^2 / |D c_n + c_E E|^2 at the fit's
        output layer (c_n, c_E) (`uq.lastlayer`'s `network_share` for the uniform girder)."""
        E = enrichment_column(self.problem, torch.as_tensor(phi))
        cn, ce = self.c_fit[:-1], self.c_fit[-1]
        w_net = self.P.Phi_d @ cn
        w_fit = w_net + ce * E
        return float(w_net.pow(2).sum() / w_fit.pow(2).sum().clamp_min(1e-300))

    def scales(self, sigma) -> Scales_:
        return Scales_(sigma, self.s_f, self.s_b, self.s_i, self.s_w)

    # ---- AR(1) noise -----------------------------------------------------------------------------------
    def zeta_start(self) -> float:
        """A start for zeta = atanh rho: the fit residuals' lag-1 autocorrelation along the noise series
        (held inside |rho| <= 0.95)."""
        phit = torch.as_tensor(self.phi_fit)
        with torch.no_grad():
            E = enrichment_column(self.problem, phit)
            c = self.c_fit
            r = (torch.as_tensor(self.problem.y) - self.P.Phi_d @ c[:-1] - c[-1] * E).numpy()
        return math.atanh(min(max(lag1(self.ar1.series, r), -0.95), 0.95))

    def _whiten(self, X: torch.Tensor, zeta: torch.Tensor) -> torch.Tensor:
        """Rows of X (n, ...) whitened along the noise series (differentiable in zeta)."""
        return whiten_rows(X, self._c, self._p, zeta)

    def _white_pieces(self, zeta: torch.Tensor):
        """`Pieces` with the data's Gram products whitened at rho = tanh(zeta) (the physics rows unchanged)."""
        dd, dy, yy = (combine_pieces(p, zeta) for p in (self._ar_dd, self._ar_dy, self._ar_yy))
        return dataclasses.replace(
            self.P, dd=dd, dy=dy, yy=yy, Phi_d=self._whiten(self.P.Phi_d, zeta)
        )

    def _data(self, phi: torch.Tensor, sigma, zeta):
        """The data rows' normal equations (A_d, g_d, k_d) at phi (`data_terms`), whitened with AR(1) noise."""
        E = enrichment_column(self.problem, phi)
        if zeta is None:
            return data_terms(self.problem, self.P, E, sigma)
        y = self._whiten(torch.as_tensor(self.problem.y, dtype=torch.float64), zeta)
        P = self._white_pieces(zeta)
        return data_terms(self.problem, P, self._whiten(E, zeta), sigma, y, P.dy, P.yy)

    def split(self, z):
        """(phi, log sigma, zeta or None) of a parameter vector z (`dim`,) or a batch (W, `dim`)."""
        return split_z(z, self.problem.dim, self.ar1 is not None)

    def inside(self, z: np.ndarray) -> bool:
        """Is z inside the prior's support (phi's, and |rho| <= `ar1.RHO_MAX`)?"""
        phi, _, zeta = self.split(np.asarray(z, float))
        return self.problem.inside(phi) and (zeta is None or abs(float(zeta)) <= Z_MAX)

    def start(self, phi: np.ndarray) -> np.ndarray:
        """A starting z at phi: sigma at its mode there (and zeta at the fit residuals' lag-1 value)."""
        if self.ar1 is None:
            return np.r_[phi, self.sigma_mode(phi)]
        zeta = self.zeta_start()
        return np.r_[phi, self.sigma_mode(phi, zeta), zeta]

    def log_marginal(self, phi: torch.Tensor, log_sigma: torch.Tensor, zeta=None) -> torch.Tensor:
        """log p(y | phi, sigma[, rho = tanh zeta]) up to a constant independent of them (differentiable).

        The physics rows and the weight prior act as the output layer's prior given phi, normalised:
        c ~ N(mu_p, A_p^-1). Counted as observations instead, the normaliser's log|A_p(phi)| / 2 (the PDE
        rows' precision grows as EI_s^2) and the physics' own minimum would inform phi through the network's
        approximation error rather than the data (`uq.lastlayer` docstring); so
        y ~ N(D mu_p, sigma^2 I + D A_p^-1 D'), computed through A = A_p + D'D / sigma^2. With AR(1) noise
        the data rows are whitened at rho and the whitening's Jacobian is added (module docstring)."""
        pr = self.problem
        if zeta is not None and not torch.is_tensor(zeta):
            zeta = torch.tensor(float(zeta), dtype=torch.float64)
        sigma = torch.exp(log_sigma)
        sc = self.scales(sigma)
        Ap, gp, _ = physics(pr, self.P, phi, sc)
        Ad, gd, kd = self._data(phi, sigma, zeta)
        mu, Lp = _solve(Ap, gp)
        b = gp + gd
        c, L = _solve(Ap + Ad, b)
        out = (
            -0.5 * (kd + mu @ gp - b @ c)
            - torch.log(torch.diagonal(L)).sum()
            + torch.log(torch.diagonal(Lp)).sum()
            - self.n * log_sigma
        )
        if zeta is not None:  # the whitening's Jacobian, -((n - m)/2) log(1 - rho^2)
            out = out + (self.ar1.n - self.ar1.m) * _log_cosh(zeta)
        return out

    def log_post(self, z: torch.Tensor) -> torch.Tensor:
        """log posterior of z = (phi, log sigma[, zeta]): marginal + prior (log-uniform sigma, uniform rho)."""
        phi, ls, zeta = self.split(z)
        out = self.log_marginal(phi, ls, zeta) + self.problem.log_prior(phi)
        if zeta is not None:
            out = out + log_prior_z(zeta)
        return out

    @torch.no_grad()
    def log_post_many(self, Z: np.ndarray) -> np.ndarray:
        """`log_post` at many points Z (W, `dim`) at once (no gradients); -inf outside the prior's support."""
        pr, P = self.problem, self.P
        Z = np.atleast_2d(Z)
        out = np.full(Z.shape[0], -np.inf)
        phi_np, _, zeta_np = self.split(Z)
        ok = pr.post.inside(phi_np)
        if zeta_np is not None:
            ok &= np.abs(zeta_np) <= Z_MAX
        if not ok.any():
            return out
        z = torch.as_tensor(Z[ok])
        phi, ls, zeta = self.split(z)
        W = phi.shape[0]
        sig2 = torch.exp(2 * ls)
        E = torch.as_tensor(pr.enrichment(Z[ok, : pr.n_phys]))  # (W, n)
        theta, left, right, lam = pr.coefficients(phi)
        D = P.dd.shape[0]
        a = torch.cat([theta, torch.ones(W, 1, dtype=torch.float64)], 1)
        Gnn = torch.einsum("wi,wj,ijDE->wDE", a, a, P.KK)
        Gne = torch.einsum("wi,iD->wD", a, P.Kf)
        Ap = torch.zeros(W, D + 1, D + 1, dtype=torch.float64)
        Ap[:, :D, :D] = Gnn
        Ap[:, :D, D] = Ap[:, D, :D] = Gne
        Ap[:, D, D] = P.ff
        Ap = Ap / self.s_f**2
        gp = lam[:, None] * torch.cat([Gne, P.ff.expand(W, 1)], 1) / self.s_f**2
        Gb = P.vv + torch.einsum("wa,wb,abDE->wDE", left, left, P.mm[0])
        Gb = Gb + torch.einsum("wa,wb,abDE->wDE", right, right, P.mm[1])
        Ap[:, :D, :D] += Gb / self.s_b**2 + P.ic / self.s_i**2
        Ap = Ap + torch.eye(D + 1, dtype=torch.float64) / self.s_w**2
        y = torch.as_tensor(pr.y)
        if zeta is None:
            dd, dy, yy = P.dd, P.dy.expand(W, D), P.yy
            dE, EE, Ey = E @ P.Phi_d, (E * E).sum(1), E @ y  # (W, D), (W,), (W,)
        else:  # whitened at each point's own rho (module docstring)
            rho, c2 = torch.tanh(zeta), torch.cosh(zeta) ** 2
            r, k = rho[:, None], c2[:, None]
            dd = combine_pieces(self._ar_dd, zeta[:, None, None])  # (W, D, D)
            dy = combine_pieces(self._ar_dy, zeta[:, None])  # (W, D)
            yy = combine_pieces(self._ar_yy, zeta)  # (W,)
            f_, c_, p_ = self._f, self._c, self._p
            Phi = P.Phi_d
            # the enrichment's and the data's non-first rows, x_k - rho x_(k-1) (times cosh^2 below)
            We, Wy = E[:, c_] - r * E[:, p_], y[c_] - r * y[p_]  # (W, n - m)
            dE = E[:, f_] @ Phi[f_] + k * (We @ Phi[c_] - r * (We @ Phi[p_]))
            EE = (E[:, f_] ** 2).sum(1) + c2 * (We * We).sum(1)
            Ey = E[:, f_] @ y[f_] + c2 * (We * Wy).sum(1)
        Ad = torch.zeros_like(Ap)
        Ad[:, :D, :D] = dd
        Ad[:, :D, D] = Ad[:, D, :D] = dE
        Ad[:, D, D] = EE
        Ad = Ad / sig2[:, None, None]
        gd = torch.cat([dy, Ey[:, None]], 1) / sig2[:, None]
        kd = yy / sig2

        def chol_solve(A, g):
            d = A.diagonal(dim1=1, dim2=2).clamp_min(1e-300)
            L, info = torch.linalg.cholesky_ex(A + torch.diag_embed(RIDGE * d))
            return torch.cholesky_solve(g[..., None], L)[..., 0], L, info

        mu, Lp, i1 = chol_solve(Ap, gp)
        b = gp + gd
        c, L, i2 = chol_solve(Ap + Ad, b)
        lm = (
            -0.5 * (kd + (mu * gp).sum(1) - (b * c).sum(1))
            - torch.log(L.diagonal(dim1=1, dim2=2)).sum(1)
            + torch.log(Lp.diagonal(dim1=1, dim2=2)).sum(1)
            - self.n * ls
        )
        if zeta is not None:  # the whitening's Jacobian and rho's uniform prior
            lm = lm + (self.ar1.n - self.ar1.m) * _log_cosh(zeta) + log_prior_z(zeta)
        lp = pr.post.log_prior(phi_np[ok])
        val = lm.numpy() + lp
        val[(i1 != 0).numpy() | (i2 != 0).numpy() | ~np.isfinite(val)] = -np.inf
        out[ok] = val
        return out

    def map(self, z0: np.ndarray) -> np.ndarray:
        z = torch.tensor(z0, dtype=torch.float64, requires_grad=True)
        opt = torch.optim.LBFGS([z], lr=1.0, max_iter=100, line_search_fn="strong_wolfe")

        def closure():
            opt.zero_grad()
            if not self.inside(z.detach().numpy()):
                return torch.as_tensor(math.inf, dtype=torch.float64)
            v = -self.log_post(z)
            v.backward()
            return v

        opt.step(closure)
        return z.detach().numpy().copy()

    def grad(self, z: np.ndarray) -> np.ndarray:
        zt = torch.tensor(z, dtype=torch.float64, requires_grad=True)
        v = self.log_post(zt)
        (gz,) = torch.autograd.grad(v, zt)
        return gz.numpy()

    def hessian(self, z: np.ndarray, h: float = 1e-4) -> np.ndarray:
        """Hessian of the log posterior by central differences of its gradient."""
        k = z.size
        H = np.empty((k, k))
        for i in range(k):
            e = np.zeros(k)
            e[i] = h
            H[i] = (self.grad(z + e) - self.grad(z - e)) / (2 * h)
        return 0.5 * (H + H.T)

    def covariance(self, z: np.ndarray) -> np.ndarray:
        """Laplace covariance at z (the negative Hessian's inverse, its eigenvalues floored at the prior's
        precision so a flat direction falls back to the prior)."""
        H = -self.hessian(z)
        lam, V = np.linalg.eigh(H)
        floor = 1.0 / float(np.max(np.r_[self.problem.post.sd, 1.0])) ** 2
        lam = np.maximum(lam, floor)
        return (V / lam) @ V.T

    def sigma_mode(self, phi: np.ndarray, zeta: float | None = None) -> float:
        """The log sigma maximising the marginal at phi (and zeta, with AR(1) noise; golden section)."""
        lo, hi = math.log(self.problem.sigma0) - 3.0, math.log(self.problem.sigma0) + 3.0
        phit = torch.as_tensor(phi)
        T = lambda v: torch.as_tensor(v, dtype=torch.float64)  # noqa: E731
        zt = None if zeta is None else T(zeta)
        f = lambda s: float(self.log_marginal(phit, T(s), zt))  # noqa: E731
        r = (math.sqrt(5) - 1) / 2
        a, b = lo, hi
        c, d = b - r * (b - a), a + r * (b - a)
        fc, fd = f(c), f(d)
        for _ in range(40):
            if fc > fd:
                b, d, fd = d, c, fc
                c = b - r * (b - a)
                fc = f(c)
            else:
                a, c, fc = c, d, fd
                d = a + r * (b - a)
                fd = f(d)
        return 0.5 * (a + b)
