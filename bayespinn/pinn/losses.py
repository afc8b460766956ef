"""Loss terms of the paper (Eq. 10-15, 19-23), non-dimensional so that each is O(1).

With xi = x/L, tau = t/T, u = U w and EI = EI_ref exp(s) (see `problem.Scales`):

* PDE (Eq. 11-12, 21): the residual of EI u_xxxx + mu u_tt = sum_j p_j delta_beta(x - v (t - t_j))
  divided by the peak intensity of a Gaussian load of P, P / (sqrt(pi) beta), so |R| <= ~1:
      R = sqrt(pi) (beta/L) [(1/48) exp(s) w_xixixixi + (mu U / (T^2 q)) w_tautau - f / q],  q = P/L,
  an axle contributing only while it is on the span (as `physics.loads.distributed_load`);
  L_f = mean(R^2).
* IC (Eq. 13): mean(w^2) + mean(w_tau^2) at tau = 0 (the sum of the two squared terms).
* BC (Eq. 14): mean(w^2) + mean(w_xixi^2) at xi = 0 and xi = 1.
* data (Eq. 15, 22-23): mean(r^2), r = (a_u u + a_xx u_xx - value) / s_i with s_i the row scale
  (`Problem.row_scales`): deflection rows a_u = 1, strain rows a_xx = -y; with AR(1) noise
  (`Problem.noise_ar1`) r whitened along each sensor's series first (`whiten_rows`).

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
from .taylor import Jet

TERMS = ("pde", "ic", "bc", "data")
WEIGHTINGS = ("fixed", "adaptive")


def moving_load(xi: Tensor, tau: Tensor, pt: ProblemTensors, images: bool = False) -> Tensor:
    """Non-dimensional load f / q (M, N) at points xi, tau (M, N): Gaussian deltas of width beta / L
    on the axle paths, each axle only while on the span (Eq. 19-21).

    With ``images`` each Gaussian also carries its negative mirror images about the supports
    (-delta(x + a) - delta(x - (2L - a))): the odd extension that the modal solution's Gaussian load
    uses (g_n = exp(-(k_n beta)^2 / 4)), so that `beta.beta_bias_factor` matches exactly what the
    PINN solves. The load then rises smoothly from zero as an axle enters. Without images this is
    `physics.loads.distributed_load` / q.
    """
    a = pt.speed * (tau.unsqueeze(-1) - pt.delays)  # (M, N, J) axle positions / L
    live = (a >= 0.0) & (a <= 1.0)
    b = pt.beta
    x = xi.unsqueeze(-1)
    c = 1.0 / (b * math.sqrt(math.pi))
    g = torch.exp(-(((x - a) / b) ** 2))
    if images:
        g = g - torch.exp(-(((x + a) / b) ** 2)) - torch.exp(-(((x + a - 2.0) / b) ** 2))
    return c * (g * live * pt.loads).sum(-1)


#: derivative orders (kx, kt) each point set needs; data needs kx = 2 only for strain rows
ORDERS = {"pde": (4, 2), "ic": (0, 1), "bc": (2, 0)}


def data_order(pt: ProblemTensors) -> int:
    """x-order the data rows need: 2 when any row is a strain (curvature), else 0."""
    return 2 if pt.needs_curvature else 0


def pde_scale(pt: ProblemTensors) -> float | Tensor:
    """The factor the residual (in units of q = P / L) is multiplied by: sqrt(pi) beta / L with
    ``pde_norm='peak'`` (divided by the peak intensity of a Gaussian load of P), 1 with 'load'."""
    return pt.beta * math.sqrt(math.pi) if pt.pde_norm == "peak" else 1.0


def pde_residual_from_jet(
    j: Jet, ei_ratio: Tensor, xi: Tensor, tau: Tensor, pt: ProblemTensors, images: bool = False
) -> Tensor:
    """R (M, N) from the jet of w at the PDE points (see module docstring)."""
    r = (
        pt.stiffness * ei_ratio.unsqueeze(-1) * j.dx(4)
        + pt.inertia * j.dt(2)
        - moving_load(xi, tau, pt, images)
    )
    return r * pde_scale(pt)


def pde_residual(
    model: PINN,
    xi: Tensor,
    tau: Tensor,
    pt: ProblemTensors,
    engine: str = "taylor",
    images: bool = False,
) -> Tensor:
    """R (M, N): non-dimensional residual of the beam equation divided by the peak intensity of a
    Gaussian load, 1 / (sqrt(pi) beta / L) (see module docstring)."""
    j = model.jet(xi, tau, 4, 2, engine=engine)
    return pde_residual_from_jet(j, model.EI_ratio, xi, tau, pt, images)


def ic_loss(j: Jet) -> Tensor:
    """mean(w^2) + mean(w_tau^2) over the initial points, from the jet of w there, shape (M,)."""
    return (j.value**2).mean(-1) + (j.dt(1) ** 2).mean(-1)


def bc_loss(j: Jet) -> Tensor:
    """mean(w^2) + mean(w_xixi^2) over the support points, from the jet of w there, shape (M,)."""
    return (j.value**2).mean(-1) + (j.dx(2) ** 2).mean(-1)


def data_prediction(j: Jet, pt: ProblemTensors) -> Tensor:
    """Scaled predictions a_u w + a_xx w_xixi (M, P) from the jet of w at the data points."""
    pred = pt.a_u * j.value if pt.needs_value else 0.0
    if pt.needs_curvature:
        pred = pred + pt.a_xx * j.dx(2)
    return pred


def whiten_rows(x: Tensor, pt: ProblemTensors) -> Tensor:
    """Rows of x (M, P, ...) along the data points whitened for AR(1) noise (`ProblemTensors.whiten`):
    x_k -> (x_k - rho x_(k-1)) / sqrt(1 - rho^2) for every non-first sample of a series; x itself for white
    noise."""
    if pt.whiten is None:
        return x
    cur, prev, rho, c = pt.whiten
    return x.index_copy(1, cur, (x[:, cur] - rho * x[:, prev]) * c)


def data_residual(model: PINN, pt: ProblemTensors, engine: str = "taylor") -> Tensor:
    """r (M, P): scaled misfit (a_u w + a_xx w_xixi) - value at the data points."""
    j = model.jet(pt.xi, pt.tau, data_order(pt), 0, engine=engine)
    return whiten_rows(data_prediction(j, pt) - pt.value, pt)


def field_jets(
    model: PINN, pt: ProblemTensors, col: Collocation, engine: str = "taylor", basis: bool = False
) -> dict[str, Jet]:
    """Jets of w (or, with ``basis``, of the output layer's basis functions) at every point set."""
    f = model.basis_jet if basis else model.jet
    return {
        "pde": f(*col.pde, *ORDERS["pde"], engine=engine),
        "ic": f(*col.ic, *ORDERS["ic"], engine=engine),
        "bc": f(*col.bc, *ORDERS["bc"], engine=engine),
        "data": f(pt.xi, pt.tau, data_order(pt), 0, engine=engine),
    }


def terms_from_jets(
    jets: dict[str, Jet],
    ei_ratio: Tensor,
    pt: ProblemTensors,
    col: Collocation,
    images: bool = False,
) -> dict[str, Tensor]:
    """The four loss terms per member (M,) from the jets of w at each point set."""
    return {
        "pde": (pde_residual_from_jet(jets["pde"], ei_ratio, *col.pde, pt, images) ** 2).mean(-1),
        "ic": ic_loss(jets["ic"]),
        "bc": bc_loss(jets["bc"]),
        "data": (whiten_rows(data_prediction(jets["data"], pt) - pt.value, pt) ** 2).mean(-1),
    }


def prior_term(log_ei: Tensor, pt: ProblemTensors) -> Tensor:
    """0.5 ((s - loc) / sd)^2 per member (M,), s = log(EI / EI_ref)."""
    loc, sd = pt.anchor
    return 0.5 * ((log_ei - loc) / sd) ** 2


@dataclass(frozen=True)
class Objective:
    """The composite loss (Eq. 10) with fixed or adaptive weights.

    Parameters
    ----------
    weighting : 'fixed' (w_k as given) or 'adaptive' (alpha_k = L_k / min L, detached; paper Table 1)
    w_pde, w_ic, w_bc, w_data : fixed weights (ignored by 'adaptive', except that a posterior-scaled
        objective keeps the data weight at 1)
    engine : derivative engine, 'taylor' or 'autograd'
    images : Gaussian loads with their mirror images about the supports (see `moving_load`)
    """

    weighting: str = "fixed"
    w_pde: float = 1.0
    w_ic: float = 1.0
    w_bc: float = 1.0
    w_data: float = 1.0
    engine: str = "taylor"
    images: bool = False

    def __post_init__(self) -> None:
        if self.weighting not in WEIGHTINGS:
            raise ValueError(f"weighting must be one of {WEIGHTINGS}, got {self.weighting!r}")

    def terms(self, model: PINN, pt: ProblemTensors, col: Collocation) -> dict[str, Tensor]:
        """Each loss term per member, shape (M,): pde, ic, bc, data (+ prior with an anchor)."""
        jets = field_jets(model, pt, col, self.engine)
        out = terms_from_jets(jets, model.EI_ratio, pt, col, self.images)
        if pt.anchor is not None:
            out["prior"] = prior_term(model.log_ei, pt)
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
