"""Variable projection: the output layer and log EI solved exactly at every step.

The network's output w = sum_j c_j phi_j is linear in the output layer c (M, D) (D = width + 1, see
`PINN.basis_jet`), and every loss term is a sum of squares of residuals that are linear in c for a fixed
s = log(EI / EI_ref). The PDE rows are linear in exp(s) as well:

    loss(c, s) = || (e^s A1 + A2) c - b_f ||^2 + || A3 c - b_3 ||^2  (+ prior(s) / data scale)

with A1 the stiffness rows, A2 the inertia rows, A3 the initial, boundary and data rows (each scaled by
sqrt(weight / count)). For a given s the best c solves the normal equations G(s) c = g(s),

    G(s) = e^{2s} A1'A1 + e^s (A1'A2 + A2'A1) + A2'A2 + A3'A3,   g(s) = e^s A1'b_f + A2'b_f + A3'b_3,

and the reduced loss J(s) = b'b - g' G^{-1} g is minimised over s by a golden-section search (batched over
members) around the current s. The hidden layers are then trained by Adam on the loss at the solved
(c, s): by the envelope theorem that gradient is the gradient of the reduced objective. This is the
hybrid least-squares / gradient-descent scheme of Cyr et al. (2020, "Robust training and initialization
of deep neural networks: an adaptive basis viewpoint") extended to the unknown EI; it converges far
faster than training the output layer and EI by Adam, which matters because EI is identified only
through the precise balance of the PDE at the load.

Exact frequency (`VaryingColumns`): the free-vibration columns (`enrich.FreeVibration`) are functions of
EI themselves. During training they are evaluated at the current EI (the frequency follows EI between
steps); for the final solve, `head_system(..., vary=fv)` keeps them apart and re-evaluates them at every
s the golden search tries, so that J(s) includes what the vibration's frequency says about EI (the first
mode's; the higher modes stay at the current EI, see `head_system`). Only
the blocks that involve them are recomputed per s (rows of the data, the initial conditions and, with
damping, the PDE; with zero damping their PDE rows vanish identically, and at the supports they vanish
by construction).

The Gram blocks are accumulated in float64 with a tiny relative ridge so that nearly collinear basis
functions do not break the solve.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from .enrich import FreeVibration
from .losses import data_order, moving_load, pde_scale, whiten_rows
from .problem import ProblemTensors
from .sampling import Collocation
from .taylor import Jet

#: relative ridge added to the normal equations (times their mean diagonal)
RIDGE = 1e-11
#: golden-section iterations for s (bracket shrinks by 0.618 each: 32 -> 2e-7 of its width, far below
#: the step-to-step change of s; each iteration costs one Cholesky solve)
GOLDEN_ITERS = 32
_INVPHI = (math.sqrt(5.0) - 1.0) / 2.0


@dataclass(frozen=True)
class VaryingColumns:
    """The trailing basis columns whose functions depend on s (free vibrations), kept apart.

    Holds the points and row weights of each term and the fixed columns' rows there (float64), so that
    `blocks(s)` gives the Gram blocks that involve the varying columns at any s.

    fv : the FreeVibration; pde : None (zero damping) or (xi, tau, c1, c2, A1f, A2f, bf);
    ic : (xi, tau, r, rows of value, rows of rate); data : (xi, tau, kx, a_u, a_xx, r, Adf, bd)
    """

    fv: FreeVibration
    pde: tuple | None
    ic: tuple
    data: tuple
    whiten: object = None  # the ProblemTensors whose AR(1) whitening the data rows take, or None

    def blocks(self, s: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """(G_fv (M, Df, Fv), G_vv (M, Fv, Fv), g_v (M, Fv)) at s (M,)."""
        e = torch.exp(s)[:, None, None]
        xi, tau, r, Cv0, Cv1 = self.ic
        j = self.fv.jet(xi, tau, 0, 1, s, detach=False)
        V0, V1 = j.value * r, j.dt(1) * r
        G_fv = _gram(Cv0, V0) + _gram(Cv1, V1)
        G_vv = _gram(V0, V0) + _gram(V1, V1)
        xi, tau, kx, a_u, a_xx, r, Adf, bd = self.data
        Adv = _data_rows(self.fv.jet(xi, tau, kx, 0, s, detach=False), a_u, a_xx) * r
        if self.whiten is not None:
            Adv = whiten_rows(Adv, self.whiten)
        G_fv = G_fv + _gram(Adf, Adv)
        G_vv = G_vv + _gram(Adv, Adv)
        g_v = _gram(Adv, bd)[..., 0]
        if self.pde is not None:
            xi, tau, c1, c2, A1f, A2f, bf = self.pde
            j = self.fv.jet(xi, tau, 4, 2, s, detach=False)
            Rv = e * j.dx(4) * c1 + j.dt(2) * c2
            G_fv = G_fv + e * _gram(A1f, Rv) + _gram(A2f, Rv)
            G_vv = G_vv + _gram(Rv, Rv)
            g_v = g_v + _gram(Rv, bf)[..., 0]
        return G_fv, G_vv, g_v


@dataclass(frozen=True)
class HeadSystem:
    """Gram blocks (float64) of the head least-squares problem, per member.

    P11, P12, P22 : (M, D, D); q1, q2 : (M, D); bb : (M,) (see module docstring); vary : the
    s-dependent trailing columns, or None (then D is the whole basis, else the fixed columns only).
    """

    P11: Tensor
    P12: Tensor
    P22: Tensor
    q1: Tensor
    q2: Tensor
    bb: Tensor
    vary: VaryingColumns | None = None

    def gram(self, s: Tensor) -> tuple[Tensor, Tensor]:
        """G(s) (M, D, D) with the ridge, and g(s) (M, D), for s (M,)."""
        e = torch.exp(s)[:, None, None]
        G = e * e * self.P11 + e * self.P12 + self.P22
        g = e[..., 0] * self.q1 + self.q2
        if self.vary is not None:
            G_fv, G_vv, g_v = self.vary.blocks(s)
            G = torch.cat(
                [torch.cat([G, G_fv], -1), torch.cat([G_fv.transpose(1, 2), G_vv], -1)], -2
            )
            g = torch.cat([g, g_v], -1)
        diag = G.diagonal(dim1=-2, dim2=-1)
        lam = RIDGE * diag.mean(-1).clamp_min(1e-300)
        G = G + lam[:, None, None] * torch.eye(G.shape[-1], dtype=G.dtype, device=G.device)
        return G, g

    def solve(self, s: Tensor) -> tuple[Tensor, Tensor]:
        """(c (M, D), J(s) (M,)): the best head for s and the reduced loss."""
        G, g = self.gram(s)
        L, info = torch.linalg.cholesky_ex(G)
        if bool((info > 0).any()):  # not numerically positive definite: fall back to LU
            c = torch.linalg.solve(G, g.unsqueeze(-1))[..., 0]
        else:
            c = torch.cholesky_solve(g.unsqueeze(-1), L)[..., 0]
        J = self.bb - (g * c).sum(-1)
        return c, J


def _data_rows(j: Jet, a_u: Tensor | None, a_xx: Tensor | None) -> Tensor:
    """Rows a_u phi + a_xx phi_xixi (M, P, D) of the data term from the basis jet at the data points."""
    out = a_u[None, :, None] * j.value if a_u is not None else 0.0
    if a_xx is not None:
        out = out + a_xx[None, :, None] * j.dx(2)
    return out


def _gram(A: Tensor, B: Tensor | None = None) -> Tensor:
    B = A if B is None else B
    return torch.bmm(A.transpose(1, 2), B)


def head_system(
    basis: dict[str, Jet],
    pt: ProblemTensors,
    col: Collocation,
    weights: dict[str, float | Tensor],
    images: bool = False,
    vary: FreeVibration | None = None,
) -> HeadSystem:
    """Assemble the Gram blocks from the basis jets (any dtype; computed in float64, no gradient).

    Parameters
    ----------
    basis : jets of the basis functions at 'pde', 'ic', 'bc', 'data' (components (M, N, D))
    pt, col : problem tensors and collocation points
    weights : weight of each term, floats or (M,) tensors (the objective's current weights)
    vary : the network's FreeVibration (its trailing columns of the basis): evaluate those at every s
        (see `VaryingColumns`) instead of taking them from ``basis``
    """
    dd = torch.float64
    quiet_pde = None
    if vary is not None:
        # the first mode varies with s, the higher modes stay (`FreeVibration.split`)
        vary, d_fixed, quiet_pde = vary.split(basis["pde"].value.shape[-1])
        basis = {k: j.map(lambda c: c[..., :d_fixed]) for k, j in basis.items()}

    def w(name: str, n: int) -> Tensor | float:
        v = weights[name]
        v = v.to(dd).reshape(-1, 1, 1) if torch.is_tensor(v) else float(v)
        return (v / n) ** 0.5 if torch.is_tensor(v) else math.sqrt(v / n)

    with torch.no_grad():
        jp = basis["pde"]
        nf = jp.value.shape[1]
        k = pde_scale(pt)
        rf = w("pde", nf)
        A1 = jp.dx(4).to(dd) * (rf * k * pt.stiffness)
        A2 = jp.dt(2).to(dd) * (rf * k * pt.inertia)
        if quiet_pde is not None:
            A1[..., quiet_pde] = 0.0
            A2[..., quiet_pde] = 0.0
        f = moving_load(*col.pde, pt, images).to(dd)
        bf = f.unsqueeze(-1) * (rf * k)  # (M, Nf, 1)
        P11 = _gram(A1)
        P12 = _gram(A1, A2)
        P12 = P12 + P12.transpose(1, 2)
        P22 = _gram(A2)
        q1 = _gram(A1, bf)[..., 0]
        q2 = _gram(A2, bf)[..., 0]
        bb = (bf**2).sum((1, 2))
        ji, jb, jd = basis["ic"], basis["bc"], basis["data"]
        ri, rb = w("ic", ji.value.shape[1]), w("bc", jb.value.shape[1])
        for blk in (ji.value * ri, ji.dt(1) * ri, jb.value * rb, jb.dx(2) * rb):
            blk = blk.to(dd)
            P22 = P22 + _gram(blk)
        nd = jd.value.shape[1]
        rd = w("data", nd)
        a_u = pt.a_u.to(dd) if pt.needs_value else None
        a_xx = pt.a_xx.to(dd) if pt.needs_curvature else None
        Ad = whiten_rows(_data_rows(jd.map(lambda c: c.to(dd)), a_u, a_xx) * rd, pt)
        bd = whiten_rows(pt.value.to(dd).unsqueeze(-1) * rd, pt)
        P22 = P22 + _gram(Ad)
        q2 = q2 + _gram(Ad, bd)[..., 0]
        bb = bb + (bd**2).sum((1, 2))
        vc = None
        if vary is not None:
            D = lambda a: a.to(dd) if torch.is_tensor(a) else a  # noqa: E731
            pde = None
            if not vary.pde_exact:
                pde = (
                    D(col.pde[0]),
                    D(col.pde[1]),
                    D(rf * k * pt.stiffness),
                    D(rf * k * pt.inertia),
                    A1,
                    A2,
                    bf,
                )
            ic = (D(col.ic[0]), D(col.ic[1]), ri, D(ji.value * ri), D(ji.dt(1) * ri))
            data = (D(pt.xi), D(pt.tau), data_order(pt), a_u, a_xx, rd, Ad, bd)
            vc = VaryingColumns(vary, pde, ic, data, pt if pt.whiten is not None else None)
    return HeadSystem(P11, P12, P22, q1, q2, bb, vc)


def solve_head(
    system: HeadSystem,
    s0: Tensor,
    *,
    half_width: float = 0.25,
    s_max: float = 3.0,
    data_scale: float | Tensor | None = None,
    anchor: tuple[Tensor, float] | None = None,
    optimise_s: bool = True,
) -> tuple[Tensor, Tensor]:
    """The best head c (M, D) and s = log(EI/EI_ref) (M,) near s0 (M,), both float64.

    Minimises data_scale J(s) + 0.5 ((s - loc)/sd)^2 (data_scale = 1 and no prior term by default)
    over s in [s0 - half_width, s0 + half_width] (clipped to +-s_max) by golden-section search.
    """
    dd = torch.float64
    s0 = s0.detach().to(dd)
    if data_scale is None:
        scale = 1.0
    elif torch.is_tensor(data_scale):  # one factor per member
        scale = data_scale.detach().to(dd)
    else:
        scale = float(data_scale)

    def objective(s: Tensor) -> Tensor:
        _, J = system.solve(s)
        out = scale * J
        if anchor is not None:
            loc, sd = anchor
            out = out + 0.5 * ((s - loc.to(dd)) / sd) ** 2
        return out

    if optimise_s:
        a = (s0 - half_width).clamp(-s_max, s_max)
        b = (s0 + half_width).clamp(-s_max, s_max)
        c = b - _INVPHI * (b - a)
        d = a + _INVPHI * (b - a)
        fc, fd = objective(c), objective(d)
        for _ in range(GOLDEN_ITERS):
            left = fc < fd  # minimum in [a, d]
            b = torch.where(left, d, b)
            a = torch.where(left, a, c)
            new_c = b - _INVPHI * (b - a)
            new_d = a + _INVPHI * (b - a)
            # reuse one evaluation: when left, the new d is the old c
            c_next = torch.where(left, new_c, d)
            d_next = torch.where(left, c, new_d)
            f_new = objective(torch.where(left, c_next, d_next))
            fc, fd = torch.where(left, f_new, fd), torch.where(left, fc, f_new)
            c, d = c_next, d_next
        s = 0.5 * (a + b)
    else:
        s = s0
    head, _ = system.solve(s)
    return head, s
