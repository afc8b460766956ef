"""The last-layer model in a well-conditioned basis of its output weights.

`lastlayer.LastLayer` forms the precision A(theta, sigma) of the output weights from Gram matrices of its
design rows (data, PDE, boundary, initial) plus the weights' prior I / s_w^2. A PINN's hidden features are
nearly collinear and its PDE rows carry fourth derivatives, so the Grams' entries reach 1e14 while the
prior adds 1e-4 (measured on the Exeter girder at 30 dB): rounding in the Grams (1e-16 of their entries,
about 1e-2) swamps the prior along the weakly determined directions, the condition number of A reaches
1e18, and log det A and b'A^-1 b come out as rounding noise of half a nat or more from one (theta, sigma)
to the next. NUTS cannot follow a potential that jagged: its step size collapses and its trees hit the
maximum depth (coverage study, 30 dB, replicate 99: more than 40 minutes for one chain).

`ConditionedLastLayer` changes the basis of the fixed columns once, before any Gram is formed: with the
stacked, scaled design S = [D / (sigma theta); P4 / s_f; P2 / s_f; B / s_b; C / s_i; I / s_w] of those
columns at the fit and its thin SVD S = U diag(s) V', the columns become X T with T = V diag(1 / s). In
that basis S T = U has orthonormal columns, every Gram entry is at most 1 and the prior's precision
T'T / s_w^2 is at least 1 / (s_w s_max)^2 against rounding of 1e-16: the same model in exact arithmetic
(the log marginal is that of the original weights, log |det T| added back; the weights' posterior is
mapped back by T), computed from rows that keep its information. The first mode's varying columns keep
their own basis (they are recomputed at every theta). `with_rows` finds the basis of the new rows; the
full-weight variant, which differentiates through its rows, keeps the plain `LastLayer` (an SVD's gradient
is unstable where singular values come close).
"""

from __future__ import annotations

import math

import torch

from .lastlayer import LastLayer


class ConditionedLastLayer(LastLayer):
    """`LastLayer` whose fixed output-weight columns are transformed to a basis where the stacked design is
    orthonormal (module docstring); every public method means what it does on `LastLayer`."""

    def _gram(self, D, P4, P2, Bm, Cm):
        kf = self.k - self.nv
        sigma = max(math.sqrt(self.fit_rss / max(self.n, 1)), 1e-300)
        S = torch.cat(
            [
                D[:, :kf] / (sigma * self.theta_fit),
                P4[:, :kf] / self.s_f,
                P2[:, :kf] / self.s_f,
                Bm[:, :kf] / self.s_b,
                Cm[:, :kf] / self.s_i,
                torch.eye(kf, dtype=torch.float64, device=D.device) / self.s_w,
            ]
        )
        _, s, Vh = torch.linalg.svd(S, full_matrices=False)  # s >= 1 / s_w: the prior's rows
        T = Vh.T / s
        self.basis = T
        self.log_det_basis = float(-torch.log(s).sum())  # log |det T|

        def new(X):
            return torch.cat([X[:, :kf] @ T, X[:, kf:]], 1)

        super()._gram(new(D), new(P4), new(P2), new(Bm), new(Cm))
        eye = torch.eye(self.k, dtype=torch.float64, device=D.device)
        eye[:kf, :kf] = T.T @ T  # the prior I / s_w^2 on the original weights, in the new basis
        self.eye = eye / self.s_w**2

    def _to_original(self, v: torch.Tensor) -> torch.Tensor:
        """Weights (k,) or the columns of a (k, m) matrix from the new basis back to the original one."""
        kf = self.k - self.nv
        return torch.cat([self.basis @ v[:kf], v[kf:]], 0)

    def log_marginal(self, log_theta, log_sigma, z=None):
        # log det A = log det A_new - 2 log |det T|, and -1/2 of it enters the log marginal
        return super().log_marginal(log_theta, log_sigma, z) + self.log_det_basis

    def weights_posterior(self, log_theta, log_sigma, z=None):
        mean, cov = super().weights_posterior(log_theta, log_sigma, z)
        mean = self._to_original(mean)
        cov = self._to_original(self._to_original(cov).T)
        return mean, 0.5 * (cov + cov.T)
