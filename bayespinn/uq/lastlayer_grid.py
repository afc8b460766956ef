"""A last-layer model's log marginal likelihood on a whole grid of (theta, sigma) at once.

The ensemble's members read their posterior of EI and of the noise level off grids of the exact last-layer
marginal (`ensemble.sigma_grid`, `ensemble.member_marginal`, `LastLayer.local_sd_log_theta`): several
hundred evaluations per member, each a small Cholesky factorisation plus the first mode's free vibration
re-evaluated at its theta. One at a time, Python's overhead and the vibration's jet took most of a member's
time after training (measured on the quick start: 1221 evaluations, 7 ms each on a loaded 2-core machine, 9 of
its 11 s). Here the G points of a grid are one batch: the vibration's jet at G values of theta in one call,
G precisions stacked and factorised together. The numbers are those of `LastLayer.log_marginal` point by
point, up to the rounding of batched products (float64).

White noise without a damped vibration's PDE rows only; anything else (AR(1) noise, damping) is evaluated
point by point with its `log_marginal`, so the function is always usable.
"""

from __future__ import annotations

import numpy as np
import torch

#: grid points per batch (bounds the memory of the stacked precisions: 256 x 70 x 70 float64 is 10 MB)
BATCH = 256


def log_marginal_grid(ll, log_theta, log_sigma, z=None) -> np.ndarray:
    """log p(y, pseudo-observations | theta, sigma[, z]) at each pair of `log_theta` and `log_sigma`
    (arrays, broadcast against each other to (G,)); float64 numpy (G,), no gradient."""
    lt, ls = np.broadcast_arrays(np.asarray(log_theta, float), np.asarray(log_sigma, float))
    lt, ls = lt.ravel(), ls.ravel()
    T = lambda a: torch.as_tensor(a, dtype=torch.float64)  # noqa: E731
    # a `LastLayer`, duck-typed (it imports this module, not the other way round)
    batched = hasattr(ll, "G_dd") and ll.ar1 is None and (ll.fv is None or ll.pde_v is None)
    if not batched:  # point by point (also any object with a `log_marginal` of its own)
        with torch.no_grad():
            return np.array(
                [float(ll.log_marginal(T(a), T(b), z)) for a, b in zip(lt, ls, strict=True)]
            )
    out = []
    with torch.no_grad():
        for i in range(0, lt.size, BATCH):
            a, b = T(lt[i : i + BATCH]), T(ls[i : i + BATCH])
            lp, bad = _batch(ll, a, b)
            for g in bad:  # rounding lost definiteness: `log_marginal`'s jittered factorisation
                lp[g] = float(ll.log_marginal(a[g], b[g]))
            out.append(lp)
    return np.concatenate(out) if out else np.zeros(0)


def _batch(ll, lt: torch.Tensor, ls: torch.Tensor) -> tuple[np.ndarray, list[int]]:
    """`LastLayer._system` and `log_marginal` for G points at once (white noise), and the points whose
    precision lost definiteness to rounding (the caller recomputes those one by one)."""
    it = torch.exp(-lt)[:, None, None]  # (G, 1, 1)
    inv_s2 = torch.exp(-2 * ls)[:, None, None]
    d2 = inv_s2 * it**2  # the data rows are D / theta
    A = ll.G_dd * d2 + ll.G44 + it * ll.G42 + it**2 * ll.G22 + ll.G_c
    b = ll.g_dy * (inv_s2 * it)[:, 0] + ll.g4f + it[:, 0] * ll.g2f  # (G, k)
    if ll.fv is not None:
        Dv, Cv = _varying(ll, lt)  # (G, n, nv), (G, 2 n_ic, nv)
        s_i2 = ll.s_i**2
        A_fv = (ll.Df.T @ Dv) * d2 + ll.Cf.T @ Cv / s_i2  # (G, kf, nv)
        A_vv = Dv.transpose(1, 2) @ Dv * d2 + Cv.transpose(1, 2) @ Cv / s_i2
        b_v = (Dv.transpose(1, 2) @ ll.y) * (inv_s2 * it)[:, 0]
        A = torch.cat([torch.cat([A, A_fv], 2), torch.cat([A_fv.transpose(1, 2), A_vv], 2)], 1)
        b = torch.cat([b, b_v], 1)
    A = A + ll.eye
    L, info = torch.linalg.cholesky_ex(A)
    bad = torch.nonzero(info).flatten().tolist()
    if bad:  # placeholders: the caller replaces these points' values
        L[bad] = torch.eye(A.shape[-1], dtype=A.dtype)
    w = torch.cholesky_solve(b.unsqueeze(-1), L).squeeze(-1)
    logdet = 2 * torch.log(torch.diagonal(L, dim1=-2, dim2=-1)).sum(-1)
    inv = inv_s2[:, 0, 0]
    lp = -0.5 * (ll.yy * inv + ll.ff) + 0.5 * (b * w).sum(-1) - 0.5 * logdet - ll.n * ls
    return lp.numpy(), bad


def _varying(ll, lt: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """`LastLayer._varying` at G values of log theta: the free vibrations' data design (G, n, nv) and
    initial-condition rows (G, 2 n_ic, nv)."""
    xd, td = ll.xi_d.unsqueeze(0), ll.tau_d.unsqueeze(0)
    jd = ll.fv.jet(xd, td, ll.kx_d, 0, lt, detach=False)
    Dv = ll._design(jd.value, jd.dx(2) if ll.kx_d else None)
    tau_i = getattr(ll, "tau_i", None)
    if tau_i is None:
        tau_i = ll.tau_i = torch.zeros_like(ll.xi_i)
    ji = ll.fv.jet(ll.xi_i.unsqueeze(0), tau_i.unsqueeze(0), 0, 1, lt, detach=False)
    return Dv, torch.cat([ji.value, ji.dt(1)], 1)
