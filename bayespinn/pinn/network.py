"""The PINN: an MLP (xi, tau) -> w in non-dimensional variables, M members at once, plus log EI.

Non-dimensional variables (the scales live in `problem.Scales`):

    xi = x / L in [0, 1],  tau = t / T in [0, 1],  u = U w,  U = P L^3 / (48 EI_ref),

and EI = EI_ref exp(s) with s = ``log_ei`` trainable. The MLP sees z = 2 xi - 1 and 2 tau - 1 in [-1, 1].

All weights carry a leading member axis: weight (M, d_in, d_out), bias (M, 1, d_out), log_ei (M,), so
an ensemble of M networks trains as one module with batched matmuls (``torch.bmm``); a single network
is M = 1. Member m is initialised from its own generator, so it starts from the same weights whether it
trains alone or together with others.

Optional hard constraints (off by default, to stay faithful to the paper):

* ``hard_bc``: w = sin(pi xi) N(cos(pi xi), tau). The product is odd about x = 0 and about x = L, so
  u and every even x-derivative (u_xx included) vanish exactly at both supports.
* ``hard_ic``: w = g(tau) N with g = 1 - exp(-(tau/c)^2), so w = w_tau = 0 at tau = 0.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor, nn

from .taylor import Jet, autograd_jet, mlp_jet, product_jet

#: time constant of the hard initial-condition factor g(tau) = 1 - exp(-(tau/c)^2) (non-dimensional)
HARD_IC_TAU = 0.05
#: derivative engines of `PINN.jet`
ENGINES = ("taylor", "taylor-unfused", "autograd")


class PINN(nn.Module):
    """M independent MLPs (xi, tau) -> w with tanh hidden layers, and their log(EI / EI_ref).

    Parameters
    ----------
    width, depth : neurons per hidden layer and number of hidden layers (paper Table 1: 64, 5)
    members : M, networks trained together (1 for a plain fit)
    generators : M torch.Generators (CPU) for the initial weights, one per member
    log_ei_init : float or sequence (M,), initial log(EI / EI_ref)
    hard_bc, hard_ic : exact boundary / initial conditions by construction (see module docstring)
    dtype : torch dtype of the parameters
    """

    def __init__(
        self,
        width: int = 64,
        depth: int = 5,
        *,
        members: int = 1,
        generators: Sequence[torch.Generator] | None = None,
        log_ei_init: float | Sequence[float] = 0.0,
        hard_bc: bool = False,
        hard_ic: bool = False,
        dtype: torch.dtype = torch.float32,
    ):
        super().__init__()
        if width < 1 or depth < 1 or members < 1:
            raise ValueError(f"width, depth and members must be >= 1, got {width}, {depth}, {members}")
        self.width, self.depth, self.members = int(width), int(depth), int(members)
        self.hard_bc, self.hard_ic = bool(hard_bc), bool(hard_ic)
        if generators is None:
            generators = [torch.Generator().manual_seed(m) for m in range(members)]
        if len(generators) != members:
            raise ValueError(f"need {members} generators, got {len(generators)}")
        sizes = [2] + [width] * depth + [1]
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        for d_in, d_out in zip(sizes[:-1], sizes[1:], strict=True):
            std = math.sqrt(2.0 / (d_in + d_out))  # Glorot normal
            w = torch.stack([torch.randn(d_in, d_out, generator=g, dtype=torch.float64) * std for g in generators])
            self.weights.append(nn.Parameter(w.to(dtype)))
            self.biases.append(nn.Parameter(torch.zeros(members, 1, d_out, dtype=dtype)))
        init = torch.as_tensor(log_ei_init, dtype=torch.float64).expand(members).clone()
        self.log_ei = nn.Parameter(init.to(dtype))

    # ------------------------------------------------------------------ inputs and outputs
    def _input_jet(self, xi: Tensor, tau: Tensor, kx: int, kt: int) -> Jet:
        """Jet of the MLP input features (M, N, 2) along x (d/dxi) and t (d/dtau)."""
        M = xi.shape[0]
        z_t = 2.0 * tau - 1.0
        one = xi.new_ones(M, 1, 1)
        zero = xi.new_zeros(M, 1, 1)
        if self.hard_bc:
            a = math.pi * xi
            c, s = torch.cos(a), torch.sin(a)
            f0 = torch.stack([c, z_t], dim=-1)
            # d^k cos(pi xi) / dxi^k = pi^k (-s, -c, s, c)[k-1]; tau feature constant along x
            derivs = [-s, -c, s, c]
            xs = tuple(
                torch.cat([(math.pi**k * derivs[k - 1]).unsqueeze(-1), torch.zeros_like(xi).unsqueeze(-1)], -1)
                for k in range(1, kx + 1)
            )
        else:
            f0 = torch.stack([2.0 * xi - 1.0, z_t], dim=-1)
            xs = tuple([torch.cat([2.0 * one, zero], -1)] + [None] * (kx - 1)) if kx else ()
        ts = tuple([torch.cat([zero, 2.0 * one], -1)] + [None] * (kt - 1)) if kt else ()
        return Jet(f0, xs, ts)

    def _envelope(self, xi: Tensor, tau: Tensor, kx: int, kt: int) -> Jet | None:
        """Jet (M, N) of the factor multiplying the MLP output, or None without hard constraints."""
        if not (self.hard_bc or self.hard_ic):
            return None
        env = Jet(torch.ones_like(xi), (None,) * kx, (None,) * kt)
        if self.hard_bc:
            a = math.pi * xi
            s, c = torch.sin(a), torch.cos(a)
            derivs = [c, -s, -c, s]
            env = product_jet(env, Jet(s, tuple(math.pi**k * derivs[k - 1] for k in range(1, kx + 1)), (None,) * kt))
        if self.hard_ic:
            r = tau / HARD_IC_TAU
            e = torch.exp(-r * r)
            g = 1.0 - e
            g1 = 2.0 * r * e / HARD_IC_TAU
            g2 = (2.0 - 4.0 * r * r) * e / HARD_IC_TAU**2
            env = product_jet(env, Jet(g, (None,) * kx, (g1, g2)[:kt]))
        return env

    # ------------------------------------------------------------------ evaluation
    def jet(self, xi: Tensor, tau: Tensor, kx: int = 0, kt: int = 0, engine: str = "taylor") -> Jet:
        """w and its derivatives d^k w / dxi^k (k <= kx), d^k w / dtau^k (k <= kt).

        Parameters
        ----------
        xi, tau : Tensor (M, N), non-dimensional position and time in [0, 1]
        kx, kt : derivative orders wanted (kx <= 4, kt <= 2)
        engine : 'taylor' (one forward pass of jets, fused layers with a hand-written backward),
            'taylor-unfused' (the same formulas, autograd through every operation) or 'autograd'
            (nested torch.autograd.grad, the reference)

        Returns
        -------
        Jet with components (M, N); absent (identically zero) components are None.
        """
        if engine == "autograd":
            return autograd_jet(self._plain, xi, tau, kx, kt)
        if engine not in ENGINES:
            raise ValueError(f"engine must be one of {ENGINES}, got {engine!r}")
        fused = engine == "taylor"
        inp = self._input_jet(xi, tau, kx, kt)
        out = mlp_jet(list(self.weights), list(self.biases), inp, fused=fused).squeeze(-1)
        env = self._envelope(xi, tau, kx, kt)
        if env is not None:
            out = product_jet(env, Jet(out.value, out.x + (None,) * (kx - len(out.x)), out.t))
        return out

    def forward(self, xi: Tensor, tau: Tensor) -> Tensor:
        """w (M, N) at non-dimensional points xi, tau (M, N)."""
        return self.jet(xi, tau, 0, 0).value

    def _plain(self, xi: Tensor, tau: Tensor) -> Tensor:
        """w (M, N) through ordinary differentiable ops only (differentiable any number of times)."""
        return self.jet(xi, tau, 0, 0, engine="taylor-unfused").value

    @property
    def EI_ratio(self) -> Tensor:
        """EI / EI_ref per member, shape (M,)."""
        return torch.exp(self.log_ei)
