"""Collocation points in non-dimensional coordinates (xi = x/L, tau = t/T, both in [0, 1]).

Each member draws from its own torch.Generator (CPU), so a member's points do not depend on how many
members train together. Points are drawn on the CPU and then moved to the training device, so the numbers
are the same on every device.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor


class Collocation(NamedTuple):
    """PDE, boundary and initial-condition points, each a pair of (M, N_k) tensors (xi, tau)."""

    pde: tuple[Tensor, Tensor]
    bc: tuple[Tensor, Tensor]
    ic: tuple[Tensor, Tensor]

    def to(self, device, dtype) -> Collocation:
        mv = lambda p: tuple(a.to(device=device, dtype=dtype) for a in p)  # noqa: E731
        return Collocation(mv(self.pde), mv(self.bc), mv(self.ic))


def sample_collocation(
    generators: list[torch.Generator],
    n_pde: int,
    n_bc: int,
    n_ic: int,
    *,
    load_fraction: float = 0.0,
    speed: float = 1.0,
    delays: Tensor | None = None,
    beta: float = 0.025,
) -> Collocation:
    """Draw a fresh set of collocation points for every member.

    Parameters
    ----------
    generators : M CPU generators, one per member
    n_pde : PDE residual points per member, uniform over [0, 1]^2 except a share `load_fraction` drawn
        around the axle paths xi = speed (tau - delay_j) (normal across the path with sd beta), where the
        Gaussian load and the curvature kink live
    n_bc : boundary points (half at xi = 0, half at xi = 1, tau uniform)
    n_ic : initial points (tau = 0, xi uniform)
    speed : v T / L, non-dimensional axle speed; delays : (J,) axle entry times / T; beta : beta / L
    """
    pde_x, pde_t, bc_x, bc_t, ic_x, ic_t = [], [], [], [], [], []
    n_load = int(round(load_fraction * n_pde)) if delays is not None else 0
    for g in generators:
        u = torch.rand(2, n_pde - n_load, generator=g, dtype=torch.float64)
        xs, ts = [u[0]], [u[1]]
        if n_load:
            J = delays.numel()
            j = torch.randint(0, J, (n_load,), generator=g)
            d = delays.detach().cpu().to(torch.float64)[j]
            lo = d.clamp(0.0, 1.0)
            hi = (d + 1.0 / speed).clamp(0.0, 1.0)
            tl = lo + (hi - lo) * torch.rand(n_load, generator=g, dtype=torch.float64)
            xl = speed * (tl - d) + beta * torch.randn(n_load, generator=g, dtype=torch.float64)
            xs.append(xl.clamp(0.0, 1.0))
            ts.append(tl)
        pde_x.append(torch.cat(xs))
        pde_t.append(torch.cat(ts))
        half = n_bc // 2
        bc_x.append(
            torch.cat(
                [
                    torch.zeros(half, dtype=torch.float64),
                    torch.ones(n_bc - half, dtype=torch.float64),
                ]
            )
        )
        bc_t.append(torch.rand(n_bc, generator=g, dtype=torch.float64))
        ic_x.append(torch.rand(n_ic, generator=g, dtype=torch.float64))
        ic_t.append(torch.zeros(n_ic, dtype=torch.float64))
    st = torch.stack
    return Collocation((st(pde_x), st(pde_t)), (st(bc_x), st(bc_t)), (st(ic_x), st(ic_t)))
