"""Last-layer Bayesian PINN: the trained network's hidden features fixed, its linear output weights
integrated out analytically.

With the hidden layers of a trained PINN frozen, the non-dimensional deflection is linear in the
output weights beta: w = Phi beta, Phi the output layer's basis (`PINN.basis_jet`: the last hidden
features and a constant, plus the static enrichment and the free vibrations (or the modulated
features) where the profile has them; their frequency stays at the fitted EI). Every term of the PINN is then linear in beta
given theta = EI / EI_ref:

* data (SI): y ~ N(D beta, sigma^2 I), D = U (a_u Phi + a_xx / L^2 Phi_xixi);
* PDE pseudo-observations: 0 ~ N(theta S Phi_xixixixi beta + I_c Phi_tautau beta - f/q, s_f^2);
* boundary and initial pseudo-observations: 0 ~ N(B beta, s_b^2), 0 ~ N(C beta, s_i^2);
* prior beta ~ N(0, s_w^2 I).

So p(y | theta, sigma) = integral over beta is Gaussian and exact: with A = D'D/sigma^2 + R'R/s_f^2 +
B'B/s_b^2 + C'C/s_i^2 + I/s_w^2 and b = D'y/sigma^2 + R'f/s_f^2,

    log p = -1/2 (y'y/sigma^2 + f'f/s_f^2) + 1/2 b'A^-1 b - 1/2 log|A| - P log sigma - (H+1) log s_w + c.

The pseudo-observation scales s_f, s_b, s_i are stated, not tuned: the RMS residual of each term at the
deterministic fit (what the network can actually achieve), floored at `MIN_PSEUDO_SD`. All Gram matrices
are precomputed, so one evaluation costs one (H+1) x (H+1) Cholesky factorisation (float64, torch,
differentiable for NUTS).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..data.measurements import Measurements
from ..pinn.losses import moving_load
from ..pinn.network import PINN
from ..pinn.problem import Problem
from ..pinn.taylor import Jet

#: floor of the pseudo-observation sds (non-dimensional), so a perfect fit cannot make them singular
MIN_PSEUDO_SD = 1e-6
#: prior sd of the output weights, as a multiple of the largest fitted weight
WEIGHT_PRIOR_FACTOR = 10.0


def feature_jet(model: PINN, member: int, xi: torch.Tensor, tau: torch.Tensor, kx: int, kt: int) -> Jet:
    """Jet of the output layer's basis functions (N, D) of one member at points (N,), float64.

    The basis is `PINN.basis_jet`: the last hidden layer's activations, the constant (the output bias),
    and with the fast profile's options the static enrichment and the free vibrations.
    """
    net = model if (model.members == 1 and member == 0 and model.log_ei.dtype == torch.float64) else (
        model.member(member).double())
    with torch.no_grad():
        j = net.basis_jet(xi.double().unsqueeze(0), tau.double().unsqueeze(0), kx, kt)
    return Jet(j.value[0], tuple(c[0] if c is not None else None for c in j.x),
               tuple(c[0] if c is not None else None for c in j.t))


class LastLayer:
    """Exact marginal likelihood of (theta, sigma) for one trained member; see the module docstring.

    Parameters
    ----------
    model : trained PINN; member : which of its members
    problem : the Problem it was trained on (scales, load); data : the measurements to explain (SI)
    n_pde, n_bc, n_ic : pseudo-observation points (uniform grid-free random, from `rng`)
    beta_rel, images : the Gaussian load as the PINN was trained on it (`TrainSettings.beta_rel`, `.images`)
    """

    def __init__(
        self,
        model: PINN,
        member: int,
        problem: Problem,
        data: Measurements,
        rng: np.random.Generator,
        n_pde: int = 2500,
        n_bc: int = 400,
        n_ic: int = 400,
        beta_rel: float | None = None,
        images: bool = False,
    ):
        model = model.member(member).double()  # one member, float64, for every basis evaluation
        member = 0
        self.model, self.member, self.problem = model, member, problem
        sc = problem.scales
        self.sc = sc
        kw = {} if beta_rel is None else {"beta_rel": beta_rel}
        pt = problem.tensors(1, dtype=torch.float64, **kw)
        self.pt = pt
        T = lambda a: torch.as_tensor(np.asarray(a, float), dtype=torch.float64)  # noqa: E731
        # data design (SI)
        a_u, a_xx = data.weights
        xi_d, tau_d = T(data.x / sc.L), T(data.t / sc.T)
        j = feature_jet(model, member, xi_d, tau_d, 2, 0)
        D = sc.U * (T(a_u)[:, None] * j.value + (T(a_xx) / sc.L**2)[:, None] * j.dx(2))
        y = T(data.value)
        # PDE pseudo-observations (non-dimensional residual, as in training but unscaled by beta)
        xi_f, tau_f = T(rng.uniform(0, 1, n_pde)), T(rng.uniform(0, 1, n_pde))
        jf = feature_jet(model, member, xi_f, tau_f, 4, 2)
        P4 = pt.stiffness * jf.dx(4)
        P2 = pt.inertia * jf.dt(2)
        f = moving_load(xi_f.unsqueeze(0), tau_f.unsqueeze(0), pt, images)[0]
        # boundary (u = u_xx = 0 at both ends) and initial (u = u_t = 0) pseudo-observations
        tb = T(rng.uniform(0, 1, n_bc))
        rows_b = []
        for end in (0.0, 1.0):
            jb = feature_jet(model, member, torch.full_like(tb, end), tb, 2, 0)
            rows_b += [jb.value, jb.dx(2)]
        Bm = torch.cat(rows_b)
        xi_i = T(rng.uniform(0, 1, n_ic))
        ji = feature_jet(model, member, xi_i, torch.zeros_like(xi_i), 0, 1)
        Cm = torch.cat([ji.value, ji.dt(1)])
        # the fitted output weights, and the residual scales they achieve
        beta_fit = model.head[0].detach().double()
        self.theta_fit = float(torch.exp(model.log_ei[member].detach().double()))
        r_f = self.theta_fit * P4 @ beta_fit + P2 @ beta_fit - f
        self.s_f = max(float(r_f.pow(2).mean().sqrt()), MIN_PSEUDO_SD)
        self.s_b = max(float((Bm @ beta_fit).pow(2).mean().sqrt()), MIN_PSEUDO_SD)
        self.s_i = max(float((Cm @ beta_fit).pow(2).mean().sqrt()), MIN_PSEUDO_SD)
        self.s_w = WEIGHT_PRIOR_FACTOR * float(beta_fit.abs().max())
        self.beta_fit = beta_fit
        # Gram matrices
        self.n = y.numel()
        self.G_dd, self.g_dy, self.yy = D.T @ D, D.T @ y, float(y @ y)
        self.G44 = P4.T @ P4 / self.s_f**2
        self.G42 = (P4.T @ P2 + P2.T @ P4) / self.s_f**2
        self.G22 = P2.T @ P2 / self.s_f**2
        self.g4f, self.g2f = P4.T @ f / self.s_f**2, P2.T @ f / self.s_f**2
        self.ff = float(f @ f) / self.s_f**2
        self.G_c = Bm.T @ Bm / self.s_b**2 + Cm.T @ Cm / self.s_i**2
        self.k = D.shape[1]
        self.eye = torch.eye(self.k, dtype=torch.float64) / self.s_w**2
        self.fit_rss = float(((D @ beta_fit - y) ** 2).sum())

    def _system(self, log_theta: torch.Tensor, log_sigma: torch.Tensor):
        th = torch.exp(log_theta)
        inv_s2 = torch.exp(-2 * log_sigma)
        A = self.G_dd * inv_s2 + th**2 * self.G44 + th * self.G42 + self.G22 + self.G_c + self.eye
        b = self.g_dy * inv_s2 + th * self.g4f + self.g2f
        return A, b, inv_s2

    def log_marginal(self, log_theta: torch.Tensor, log_sigma: torch.Tensor) -> torch.Tensor:
        """log p(y, pseudo-observations | theta, sigma) up to a constant (differentiable scalar)."""
        A, b, inv_s2 = self._system(log_theta, log_sigma)
        Lc = torch.linalg.cholesky(A)
        z = torch.cholesky_solve(b.unsqueeze(-1), Lc).squeeze(-1)
        logdet = 2 * torch.log(torch.diagonal(Lc)).sum()
        return -0.5 * (self.yy * inv_s2 + self.ff) + 0.5 * (b @ z) - 0.5 * logdet - self.n * log_sigma

    def weights_posterior(self, log_theta: float, log_sigma: float) -> tuple[torch.Tensor, torch.Tensor]:
        """Mean (k,) and covariance (k, k) of the output weights given theta and sigma."""
        with torch.no_grad():
            A, b, _ = self._system(torch.tensor(log_theta, dtype=torch.float64), torch.tensor(log_sigma, dtype=torch.float64))
            Lc = torch.linalg.cholesky(A)
            mean = torch.cholesky_solve(b.unsqueeze(-1), Lc).squeeze(-1)
            cov = torch.cholesky_inverse(Lc)
        return mean, cov

    def effective_params(self, log_theta: float, log_sigma: float) -> float:
        """Degrees of freedom the output weights spend on the data: trace(D A^-1 D') / sigma^2 [-]."""
        _, cov = self.weights_posterior(log_theta, log_sigma)
        return float(torch.trace(self.G_dd @ cov)) * math.exp(-2.0 * log_sigma)

    def laplace_sd_log_theta(self, log_theta: float, log_sigma: float, prior_sd: float) -> float:
        """sd of log theta from the curvature of the log marginal (sigma held) plus the prior's."""
        lt = torch.tensor(log_theta, dtype=torch.float64, requires_grad=True)
        ls = torch.tensor(log_sigma, dtype=torch.float64)
        (g,) = torch.autograd.grad(self.log_marginal(lt, ls), lt, create_graph=True)
        (h,) = torch.autograd.grad(g, lt)
        prec = -float(h) + 1.0 / prior_sd**2
        return 1.0 / math.sqrt(prec) if prec > 0 else prior_sd

    def predictive(self, x, t, kx: int, draws_log_theta, draws_log_sigma, rng: np.random.Generator) -> np.ndarray:
        """Draws (S, P) of u [m] (kx=0) or u_xx [1/m] (kx=2) at x [m], t [s], one weight draw per (theta, sigma)."""
        sc = self.sc
        T = lambda a: torch.as_tensor(np.array(a, float).ravel(), dtype=torch.float64)  # noqa: E731
        j = feature_jet(self.model, self.member, T(x) / sc.L, T(t) / sc.T, kx, 0)
        Phi = j.dx(kx)
        scale = sc.U / sc.L**kx
        out = np.empty((len(draws_log_theta), Phi.shape[0]))
        for i, (lt, ls) in enumerate(zip(draws_log_theta, draws_log_sigma, strict=True)):
            mean, cov = self.weights_posterior(float(lt), float(ls))
            Lc = torch.linalg.cholesky(cov + 1e-30 * torch.eye(self.k, dtype=torch.float64))
            z = torch.as_tensor(rng.standard_normal(self.k), dtype=torch.float64)
            out[i] = (Phi @ (mean + Lc @ z)).numpy() * scale
        return out
