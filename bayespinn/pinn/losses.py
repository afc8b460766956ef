"""Loss terms of the paper (Eq. 10-15, 19-23), non-dimensional so that each is O(1).

With xi = x/L, tau = t/T, u = U w and EI = EI_ref exp(s) (see `problem.Scales`):

* PDE (Eq. 11-12, 21): the residual of EI u_xxxx + mu u_tt = sum_j p_j delta_beta(x - v (t - t_j))
  divided by the load scale q = P/L,
      R = (1/48) exp(s) w_xixixixi + (mu U / (T^2 q)) w_tautau - f / q,
  an axle contributing only while it is on the span (as `physics.loads.distributed_load`);
  L_f = mean(R^2).
* IC (Eq. 13): mean(w^2) + mean(w_tau^2) at tau = 0 (the sum of the two squared terms).
* BC (Eq. 14): mean(w^2) + mean(w_xixi^2) at xi = 0 and xi = 1.
* data (Eq. 15, 22-23): mean(r^2), r = (a_u u + a_xx u_xx - value) / s_i with s_i the row scale
  (`Problem.row_scales`): deflection rows a_u = 1, strain rows a_xx = -y.

`Objective` combines them: fixed weights, or the paper's adaptive weights alpha_k = L_k / min_k L_k
(detached, recomputed each step). With `Problem.noise_sd` set the objective is *posterior-scaled*:

    sum_i (value_i - pred_i)^2 / (2 sigma^2) + c (w_f L_f + w_i L_i + w_b L_b) + 0.5 ((s - s0)/sd)^2,

c = 0.5 sum_i (s_i / sigma)^2 being the factor that turns the data term's mean into the Gaussian negative
log-likelihood, so the physics penalties keep the same weight relative to the data as in a plain fit,
and the anchor (prior) term is a proper log density on log EI. Every term is per member, shape (M,);
the scalar minimised is their sum (members are independent).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from .network import PINN
from .problem import ProblemTensors
from .sampling import Collocation

TERMS = ("pde", "ic", "bc", "data")
WEIGHTINGS = ("fixed", "adaptive")


def moving_load(xi: Tensor, tau: Tensor, pt: ProblemTensors) -> Tensor:
    """Non-dimensional load f / q (M, N) at points xi, tau (M, N): Gaussian deltas of width beta / L
    on the axle paths, each axle only while on the span (Eq. 19-21)."""
    a = pt.speed * (tau.unsqueeze(-1) - pt.delays)  # (M, N, J) axle positions / L
    live = (a >= 0.0) & (a <= 1.0)
    b = pt.beta
    g = torch.exp(-(((xi.unsqueeze(-1) - a) / b) ** 2)) / (b * math.sqrt(math.pi))
    return (g * live * pt.loads).sum(-1)


def pde_residual(model: PINN, xi: Tensor, tau: Tensor, pt: ProblemTensors, engine: str = "taylor") -> Tensor:
    """R (M, N): non-dimensional residual of the beam equation (see module docstring)."""
    j = model.jet(xi, tau, 4, 2, engine=engine)
    ei = model.EI_ratio.unsqueeze(-1)
    return pt.stiffness * ei * j.dx(4) + pt.inertia * j.dt(2) - moving_load(xi, tau, pt)


def ic_loss(model: PINN, xi: Tensor, tau: Tensor, engine: str = "taylor") -> Tensor:
    """mean(w^2) + mean(w_tau^2) at the initial points, shape (M,)."""
    j = model.jet(xi, tau, 0, 1, engine=engine)
    return (j.value**2).mean(-1) + (j.dt(1) ** 2).mean(-1)


def bc_loss(model: PINN, xi: Tensor, tau: Tensor, engine: str = "taylor") -> Tensor:
    """mean(w^2) + mean(w_xixi^2) at the support points, shape (M,)."""
    j = model.jet(xi, tau, 2, 0, engine=engine)
    return (j.value**2).mean(-1) + (j.dx(2) ** 2).mean(-1)


def data_residual(model: PINN, pt: ProblemTensors, engine: str = "taylor") -> Tensor:
    """r (M, P): scaled misfit (a_u w + a_xx w_xixi) - value at the data points."""
    kx = 2 if pt.needs_curvature else 0
    j = model.jet(pt.xi, pt.tau, kx, 0, engine=engine)
    pred = pt.a_u * j.value if pt.needs_value else 0.0
    if pt.needs_curvature:
        pred = pred + pt.a_xx * j.dx(2)
    return pred - pt.value


@dataclass(frozen=True)
class Objective:
    """The composite loss (Eq. 10) with fixed or adaptive weights.

    Parameters
    ----------
    weighting : 'fixed' (w_k as given) or 'adaptive' (alpha_k = L_k / min L, detached; paper Table 1)
    w_pde, w_ic, w_bc, w_data : fixed weights (ignored by 'adaptive', except that a posterior-scaled
        objective keeps the data weight at 1)
    engine : derivative engine, 'taylor' or 'autograd'
    """

    weighting: str = "fixed"
    w_pde: float = 1.0
    w_ic: float = 1.0
    w_bc: float = 1.0
    w_data: float = 1.0
    engine: str = "taylor"

    def __post_init__(self) -> None:
        if self.weighting not in WEIGHTINGS:
            raise ValueError(f"weighting must be one of {WEIGHTINGS}, got {self.weighting!r}")

    def terms(self, model: PINN, pt: ProblemTensors, col: Collocation) -> dict[str, Tensor]:
        """Each loss term per member, shape (M,): pde, ic, bc, data (+ prior with an anchor)."""
        e = self.engine
        out = {
            "pde": (pde_residual(model, *col.pde, pt, engine=e) ** 2).mean(-1),
            "ic": ic_loss(model, *col.ic, engine=e),
            "bc": bc_loss(model, *col.bc, engine=e),
            "data": (data_residual(model, pt, engine=e) ** 2).mean(-1),
        }
        if pt.anchor is not None:
            loc, sd = pt.anchor
            out["prior"] = 0.5 * ((model.log_ei - loc) / sd) ** 2
        return out

    def weights(self, terms: dict[str, Tensor], posterior: bool) -> dict[str, Tensor | float]:
        """The weight of each of pde, ic, bc, data (detached tensors (M,) when adaptive)."""
        if self.weighting == "fixed":
            w = {"pde": self.w_pde, "ic": self.w_ic, "bc": self.w_bc, "data": self.w_data}
        else:
            stack = torch.stack([terms[k].detach() for k in TERMS])  # (4, M)
            low = stack.min(0).values.clamp_min(torch.finfo(stack.dtype).tiny)
            w = {k: stack[i] / low for i, k in enumerate(TERMS)}
        if posterior:
            w["data"] = 1.0
        return w

    def total(self, terms: dict[str, Tensor], pt: ProblemTensors) -> tuple[Tensor, Tensor]:
        """(scalar to minimise = sum over members, per-member objective (M,))."""
        posterior = pt.data_scale is not None
        w = self.weights(terms, posterior)
        per = sum(w[k] * terms[k] for k in TERMS)
        if posterior:
            per = pt.data_scale * per
        if "prior" in terms:
            per = per + terms["prior"]
        return per.sum(), per
