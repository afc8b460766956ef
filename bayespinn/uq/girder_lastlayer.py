"""The girder PINN's last layer (`uq.girder_pinn`): log p(y | phi, sigma) of a trained network with its
output layer (c, c_E) integrated out exactly on fixed points, with pseudo-sds stated from the fit's own
residuals (`GirderLastLayer`), and its MAP, gradient, Hessian and covariance in phi for the deep ensemble's
importance sampling and the B-PINN's NUTS. The posteriors built on it are in `uq.girder_pinn`.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from .. import seeding
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
from .lastlayer import MIN_PSEUDO_SD, PDE_SD_FACTOR, WEIGHT_PRIOR_FACTOR


class GirderLastLayer:
    """log p(y | phi, sigma) with the output layer (c, c_E) integrated out exactly (`uq.girder_pinn`'s
    docstring), for a trained network on fixed points."""

    def __init__(self, problem: GirderProblem, fit: GirderFit, settings: GirderNetSettings, seed):
        self.problem = problem
        gen = torch.Generator().manual_seed(seeding.int_seed(seed))
        self.pts = Points.draw(settings, gen)
        with torch.no_grad():
            self.P = _detach(pieces(problem, fit.net, self.pts, problem.y))
        # pseudo-sds from the fit's own residuals at its phi (a function of the fit, stated not tuned)
        self.s_f, self.s_b, self.s_i, self.s_w, self.c_fit = self._scales(fit.phi)
        self.n = problem.y.size

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
        s_f = max(PDE_SD_FACTOR * rms(rf, k["pde"]), MIN_PSEUDO_SD)
        s_b = max(rms(cn @ Gb @ cn, 2 * k["bc"]), MIN_PSEUDO_SD)
        s_i = max(rms(cn @ P.ic @ cn, 2 * k["ic"]), MIN_PSEUDO_SD)
        s_w = WEIGHT_PRIOR_FACTOR * float(c.abs().max())
        return s_f, s_b, s_i, s_w, c.detach()

    def scales(self, sigma) -> Scales_:
        return Scales_(sigma, self.s_f, self.s_b, self.s_i, self.s_w)

    def log_marginal(self, phi: torch.Tensor, log_sigma: torch.Tensor) -> torch.Tensor:
        """log p(y | phi, sigma) up to a constant independent of both (differentiable).

        The physics rows and the weight prior act as the output layer's prior given phi, normalised:
        c ~ N(mu_p, A_p^-1). Counted as observations instead, the normaliser's log|A_p(phi)| / 2 (the PDE
        rows' precision grows as EI_s^2) and the physics' own minimum would inform phi through the network's
        approximation error rather than the data (`uq.lastlayer` docstring); so
        y ~ N(D mu_p, sigma^2 I + D A_p^-1 D'), computed through A = A_p + D'D / sigma^2."""
        pr = self.problem
        sigma = torch.exp(log_sigma)
        sc = self.scales(sigma)
        E = enrichment_column(pr, phi)
        Ap, gp, _ = physics(pr, self.P, phi, sc)
        Ad, gd, kd = data_terms(pr, self.P, E, sigma)
        mu, Lp = _solve(Ap, gp)
        b = gp + gd
        c, L = _solve(Ap + Ad, b)
        return (
            -0.5 * (kd + mu @ gp - b @ c)
            - torch.log(torch.diagonal(L)).sum()
            + torch.log(torch.diagonal(Lp)).sum()
            - self.n * log_sigma
        )

    def log_post(self, z: torch.Tensor) -> torch.Tensor:
        """log posterior of z = (phi, log sigma): marginal + prior (log-uniform sigma)."""
        phi = z[:-1]
        return self.log_marginal(phi, z[-1]) + self.problem.log_prior(phi)

    @torch.no_grad()
    def log_post_many(self, Z: np.ndarray) -> np.ndarray:
        """`log_post` at many points Z (W, dim + 1) at once (no gradients); -inf outside the prior's support."""
        pr, P = self.problem, self.P
        Z = np.atleast_2d(Z)
        out = np.full(Z.shape[0], -np.inf)
        ok = pr.post.inside(Z[:, :-1])
        if not ok.any():
            return out
        z = torch.as_tensor(Z[ok])
        phi, ls = z[:, :-1], z[:, -1]
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
        dE = E @ P.Phi_d  # (W, D)
        Ad = torch.zeros_like(Ap)
        Ad[:, :D, :D] = P.dd
        Ad[:, :D, D] = Ad[:, D, :D] = dE
        Ad[:, D, D] = (E * E).sum(1)
        Ad = Ad / sig2[:, None, None]
        gd = torch.cat([P.dy.expand(W, D), (E @ y)[:, None]], 1) / sig2[:, None]
        kd = P.yy / sig2

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
        lp = pr.post.log_prior(Z[ok, :-1])
        val = lm.numpy() + lp
        val[(i1 != 0).numpy() | (i2 != 0).numpy() | ~np.isfinite(val)] = -np.inf
        out[ok] = val
        return out

    def map(self, z0: np.ndarray) -> np.ndarray:
        z = torch.tensor(z0, dtype=torch.float64, requires_grad=True)
        opt = torch.optim.LBFGS([z], lr=1.0, max_iter=100, line_search_fn="strong_wolfe")

        def closure():
            opt.zero_grad()
            if not self.problem.inside(z.detach().numpy()[:-1]):
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

    def sigma_mode(self, phi: np.ndarray) -> float:
        """The log sigma maximising the marginal at phi (golden section on log sigma)."""
        lo, hi = math.log(self.problem.sigma0) - 3.0, math.log(self.problem.sigma0) + 3.0
        phit = torch.as_tensor(phi)
        f = lambda s: float(self.log_marginal(phit, torch.as_tensor(s, dtype=torch.float64)))  # noqa: E731
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
