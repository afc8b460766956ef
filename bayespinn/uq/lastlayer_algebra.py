"""The small tensor algebra the last-layer model (`uq.lastlayer`) is built of: the jet of a trained
member's output-layer basis (`feature_jet`), a Cholesky factor that restores definiteness lost to rounding,
the pieces of the AR(1)-whitened Gram products, and the log density of z = atanh rho under a uniform rho.
Apart from the model so that the B-PINN samplers and the studies can use them without it.
"""

from __future__ import annotations

import logging
import math

import torch

from ..pinn.network import PINN
from ..pinn.taylor import Jet

#: the last layer's logger: its messages read as they did when this was part of `uq.lastlayer`
log = logging.getLogger("bayespinn.uq.lastlayer")


def feature_jet(
    model: PINN, member: int, xi: torch.Tensor, tau: torch.Tensor, kx: int, kt: int
) -> Jet:
    """Jet of the output layer's basis functions (N, D) of one member at points (N,), float64.

    The basis is `PINN.basis_jet`: the last hidden layer's activations, the constant (the output bias),
    and with the fast profile's options the static enrichment and the free vibrations.
    """
    net = (
        model
        if (model.members == 1 and member == 0 and model.log_ei.dtype == torch.float64)
        else (model.member(member).double())
    )
    with torch.no_grad():
        j = net.basis_jet(xi.double().unsqueeze(0), tau.double().unsqueeze(0), kx, kt)
    return j.map(lambda c: c[0])


def _cholesky(A: torch.Tensor) -> torch.Tensor:
    """Cholesky factor of a precision that is positive definite in exact arithmetic (positive semi-definite
    data and physics terms plus the weights' prior): where rounding in its largest terms loses definiteness,
    the smallest diagonal jitter (1e-14 to 1e-6 of its largest diagonal entry) that restores it."""
    L, info = torch.linalg.cholesky_ex(A)
    if int(info) == 0:
        return L
    top = A.detach().diagonal().abs().max()
    eye = torch.eye(A.shape[-1], dtype=A.dtype)
    for k in range(-14, -5):
        L, info = torch.linalg.cholesky_ex(A + (10.0**k * top) * eye)
        if int(info) == 0:
            log.debug("last layer: precision made definite with jitter 1e%d of its diagonal", k)
            return L
    raise torch.linalg.LinAlgError(
        f"the last layer's precision is not positive definite (leading minor {int(info)}) even with "
        "a jitter of 1e-6 of its largest diagonal entry"
    )


def _t(X: torch.Tensor) -> torch.Tensor:
    return X.T if X.dim() == 2 else X


def _pieces(Xf, Xc, Xp, Yf, Yc, Yp) -> tuple:
    """(Xf'Yf, Xc'Yc, Xc'Yp + Xp'Yc, Xp'Yp): with rho and c2 = 1 / (1 - rho^2), X'P(rho)Y is
    Xf'Yf + c2 (Xc'Yc - rho (Xc'Yp + Xp'Yc) + rho^2 Xp'Yp) for the first (f), current (c) and previous (p)
    rows of the noise series (`ar1.AR1Noise`)."""
    return (_t(Xf) @ Yf, _t(Xc) @ Yc, _t(Xc) @ Yp + _t(Xp) @ Yc, _t(Xp) @ Yp)


def combine_pieces(pieces: tuple, z: torch.Tensor) -> torch.Tensor:
    """X'P(rho)Y from its four `_pieces` at rho = tanh z: Xf'Yf + (Xc'Yc - rho (Xc'Yp + Xp'Yc) + rho^2 Xp'Yp)
    / (1 - rho^2) (differentiable in z)."""
    a, b, x, d = pieces
    rho, c2 = torch.tanh(z), torch.cosh(z) ** 2
    return a + c2 * (b - rho * x + rho**2 * d)


def whiten_rows(
    X: torch.Tensor, cur: torch.Tensor, prev: torch.Tensor, z: torch.Tensor
) -> torch.Tensor:
    """Rows of X (n, ...) whitened along AR(1) noise series: x_k -> (x_k - rho x_(k-1)) / sqrt(1 - rho^2) for
    every non-first sample k (`cur`, its predecessor `prev`: `ar1.AR1Noise`), rho = tanh z; differentiable
    in z. The torch twin of `ar1.AR1Noise.whiten`, for both last layers."""
    rho, c = torch.tanh(z), torch.cosh(z)
    return X.index_copy(0, cur, (X[cur] - rho * X[prev]) * c)


def _log_cosh(z: torch.Tensor) -> torch.Tensor:
    a = z.abs()
    return a + torch.log1p(torch.exp(-2.0 * a)) - math.log(2.0)


def log_prior_z(z: torch.Tensor) -> torch.Tensor:
    """log density of z = atanh rho under a uniform rho on (-1, 1): log sech^2 z (the torch twin of
    `ar1.AR1Noise.log_prior`, differentiable)."""
    return -2.0 * _log_cosh(z)
