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

Optional modulated output (``oscillator``, off in the paper profile): the output layer combines the last
hidden layer's features phi_j, and the same features times sin(W tau) and cos(W tau), W the first natural
circular frequency at the current EI times T:

    w = sum_j c_j phi_j + sum_j (a_j sin(W tau) + b_j cos(W tau)) phi_j.

A girder crossed in 2.4 s vibrates freely at its first frequency (about 24 cycles per crossing for the
Exeter girder, 2 % of the deflection); a tanh MLP of (x, t) alone hardly represents that, and the misfit
then biases EI. With the modulation the slow amplitude envelopes are ordinary smooth functions of the
network. The output stays linear in (c, a, b), so `varpro` and the last-layer B-PINN keep working.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor, nn

from .enrich import FreeVibration, StaticEnrichment
from .taylor import (
    Jet,
    autograd_jet,
    cat_jets,
    contract_jet,
    hidden_stack,
    mlp_jet,
    product_jet,
    unstack,
)

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
    time_frequency : None, or omega_1(EI_ref) T [rad]: add the time features sin(W tau), cos(W tau)
        at the first natural frequency for the current EI (see `_input_jet`)
    oscillator : None, or omega_1(EI_ref) T [rad]: the modulated output (module docstring), with
        W = oscillator sqrt(EI / EI_ref)
    extras : fixed basis functions appended to the output layer's, each with its own coefficients (see
        `enrich`): `StaticEnrichment` (the quasi-static deflection of the Gaussian loads) and
        `FreeVibration` (free vibrations of the first modes started at each axle event)
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
        time_frequency: float | None = None,
        oscillator: float | None = None,
        extras: Sequence[StaticEnrichment | FreeVibration] = (),
        dtype: torch.dtype = torch.float32,
    ):
        super().__init__()
        if width < 1 or depth < 1 or members < 1:
            raise ValueError(
                f"width, depth and members must be >= 1, got {width}, {depth}, {members}"
            )
        self.width, self.depth, self.members = int(width), int(depth), int(members)
        self.hard_bc, self.hard_ic = bool(hard_bc), bool(hard_ic)
        if generators is None:
            generators = [torch.Generator().manual_seed(m) for m in range(members)]
        if len(generators) != members:
            raise ValueError(f"need {members} generators, got {len(generators)}")
        self.time_frequency = None if time_frequency is None else float(time_frequency)
        sizes = [2 if self.time_frequency is None else 4] + [width] * depth + [1]
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        for d_in, d_out in zip(sizes[:-1], sizes[1:], strict=True):
            std = math.sqrt(2.0 / (d_in + d_out))  # Glorot normal
            w = torch.stack(
                [
                    torch.randn(d_in, d_out, generator=g, dtype=torch.float64) * std
                    for g in generators
                ]
            )
            self.weights.append(nn.Parameter(w.to(dtype)))
            self.biases.append(nn.Parameter(torch.zeros(members, 1, d_out, dtype=dtype)))
        if self.time_frequency is not None:
            with (
                torch.no_grad()
            ):  # the oscillating features start unused (their w_tt would be huge)
                self.weights[0][:, 2:] = 0.0
        init = torch.as_tensor(log_ei_init, dtype=torch.float64).expand(members).clone()
        self.log_ei = nn.Parameter(init.to(dtype))
        self.oscillator = None if oscillator is None else float(oscillator)
        # coefficients of the sin- and cos-modulated features (weights then bias of each), start at zero
        n_osc = 0 if self.oscillator is None else 2 * (width + 1)
        self.osc_head = nn.Parameter(torch.zeros(members, n_osc, dtype=dtype))
        self.extras = tuple(extras)
        if any(isinstance(e, FreeVibration) for e in self.extras[:-1]):
            raise ValueError("a FreeVibration extra must come last")
        n_extra = sum(e.n_features for e in self.extras)
        self.extra_head = nn.Parameter(torch.zeros(members, n_extra, dtype=dtype))

    # ------------------------------------------------------------------ inputs and outputs
    def _input_jet(self, xi: Tensor, tau: Tensor, kx: int, kt: int) -> Jet:
        """Jet of the MLP input features (M, N, F) along x (d/dxi) and t (d/dtau).

        Features: the position (2 xi - 1, or cos(pi xi) with ``hard_bc``), the time 2 tau - 1 and, with
        ``time_frequency``, sin(W tau) and cos(W tau), W = time_frequency sqrt(EI / EI_ref) (the first
        natural frequency at the current EI times T; EI enters detached, so the features follow EI
        without a gradient through them).
        """
        M = xi.shape[0]
        zero_b = xi.new_zeros(M, 1)  # broadcast zero / constants
        # each feature: (value (M, N), [d/dxi^k for k = 1..kx], [d/dtau^k for k = 1..kt]); None = 0
        feats: list[tuple[Tensor, list, list]] = []
        if self.hard_bc:
            a = math.pi * xi
            c, s = torch.cos(a), torch.sin(a)
            d = [-s, -c, s, c]  # d^k cos(pi xi) / dxi^k = pi^k d[k-1]
            feats.append((c, [math.pi**k * d[k - 1] for k in range(1, kx + 1)], [None] * kt))
        else:
            feats.append(
                (2.0 * xi - 1.0, [zero_b + 2.0] + [None] * (kx - 1) if kx else [], [None] * kt)
            )
        feats.append(
            (2.0 * tau - 1.0, [None] * kx, [zero_b + 2.0] + [None] * (kt - 1) if kt else [])
        )
        if self.time_frequency is not None:
            W = (self.time_frequency * torch.exp(0.5 * self.log_ei.detach())).unsqueeze(
                -1
            )  # (M, 1)
            sn, cs = torch.sin(W * tau), torch.cos(W * tau)
            feats.append((sn, [None] * kx, [W * cs, -W * W * sn][:kt]))
            feats.append((cs, [None] * kx, [-W * sn, -W * W * cs][:kt]))

        def comp(parts: list) -> Tensor | None:
            if all(p is None for p in parts):
                return None
            full = any(p is not None and p.shape[-1] != 1 for p in parts)
            shape = xi.shape if full else (M, 1)
            return torch.stack(
                [xi.new_zeros(shape) if p is None else p.expand(shape) for p in parts], dim=-1
            )

        value = torch.stack([f[0] for f in feats], dim=-1)
        xs = tuple(comp([f[1][k] for f in feats]) for k in range(kx))
        ts = tuple(comp([f[2][k] for f in feats]) for k in range(kt))
        return Jet(value, xs, ts)

    def _envelope(self, xi: Tensor, tau: Tensor, kx: int, kt: int) -> Jet | None:
        """Jet (M, N) of the factor multiplying the MLP output, or None without hard constraints."""
        if not (self.hard_bc or self.hard_ic):
            return None
        env = Jet(torch.ones_like(xi), (None,) * kx, (None,) * kt)
        if self.hard_bc:
            a = math.pi * xi
            s, c = torch.sin(a), torch.cos(a)
            derivs = [c, -s, -c, s]
            env = product_jet(
                env,
                Jet(s, tuple(math.pi**k * derivs[k - 1] for k in range(1, kx + 1)), (None,) * kt),
            )
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
        if self.oscillator is not None or self.extras:
            return contract_jet(self.basis_jet(xi, tau, kx, kt, engine=engine), self.head)
        inp = self._input_jet(xi, tau, kx, kt)
        out = mlp_jet(list(self.weights), list(self.biases), inp, fused=fused).squeeze(-1)
        env = self._envelope(xi, tau, kx, kt)
        if env is not None:
            out = product_jet(env, out)
        return out

    def basis_jet(
        self, xi: Tensor, tau: Tensor, kx: int = 0, kt: int = 0, engine: str = "taylor"
    ) -> Jet:
        """Jet of the basis functions that the output layer combines, components (M, N, width + 1).

        w = sum_j c_j phi_j with c = `head` (the output weights, then the output bias); phi_j is the
        j-th neuron of the last hidden layer (and 1 for the bias), times the hard-constraint factor.
        The jet is linear in c, which `varpro` exploits.
        """
        if engine not in ("taylor", "taylor-unfused"):
            raise ValueError(f"basis_jet needs a Taylor engine, got {engine!r}")
        inp = self._input_jet(xi, tau, kx, kt)
        H, kx_, kt_ = hidden_stack(
            list(self.weights)[:-1], list(self.biases)[:-1], inp, fused=engine == "taylor"
        )
        M, K, N, _ = H.shape
        ones = torch.zeros(M, K, N, 1, dtype=H.dtype, device=H.device)
        ones[:, 0] = 1.0
        B = unstack(torch.cat([H, ones], dim=-1), kx_, kt_)
        env = self._envelope(xi, tau, kx, kt)
        if env is not None:
            e = lambda c: None if c is None else c.unsqueeze(-1)  # noqa: E731
            B = product_jet(
                Jet(e(env.value), tuple(e(c) for c in env.x), tuple(e(c) for c in env.t)), B
            )
        if self.oscillator is not None:
            B = self._modulate(B, tau, kx, kt)
        if self.extras:
            B = cat_jets(B, *(e.jet(xi, tau, kx, kt, self.log_ei) for e in self.extras))
        return B

    def _modulate(self, B: Jet, tau: Tensor, kx: int, kt: int) -> Jet:
        """[B, B sin(W tau), B cos(W tau)] along the feature axis (see the module docstring)."""
        W = (
            (self.oscillator * torch.exp(0.5 * self.log_ei.detach())).view(-1, 1, 1).to(tau.dtype)
        )  # (M, 1, 1)
        a = W * tau.unsqueeze(-1)
        sn, cs = torch.sin(a), torch.cos(a)
        mods = [
            product_jet(B, Jet(v, (None,) * kx, (d1, d2)[:kt]))
            for v, d1, d2 in ((sn, W * cs, -W * W * sn), (cs, -W * sn, -W * W * cs))
        ]
        return cat_jets(B, *mods)

    @property
    def free_vibration(self) -> FreeVibration | None:
        """The `FreeVibration` extra, if any: it is always the last extra, so its features are the
        trailing `FreeVibration.n_features` columns of `basis_jet` and of `head`."""
        return (
            self.extras[-1] if self.extras and isinstance(self.extras[-1], FreeVibration) else None
        )

    @property
    def head(self) -> Tensor:
        """The output layer as one coefficient matrix c (M, D): weights, then bias (D = width + 1),
        then with ``oscillator`` the sin- and cos-modulated coefficients (2 (width + 1) more), then the
        coefficients of the ``extras``."""
        return torch.cat(
            [self.weights[-1][..., 0], self.biases[-1][..., 0], self.osc_head, self.extra_head],
            dim=-1,
        )

    @torch.no_grad()
    def set_head(self, c: Tensor) -> None:
        """Overwrite the output layer with coefficients c (M, D) (see `head`)."""
        w = self.width
        self.weights[-1].copy_(c[:, :w].unsqueeze(-1))
        self.biases[-1].copy_(c[:, w : w + 1].unsqueeze(-1))
        n_osc = self.osc_head.shape[1]
        self.osc_head.copy_(c[:, w + 1 : w + 1 + n_osc])
        self.extra_head.copy_(c[:, w + 1 + n_osc :])

    def head_parameters(self) -> list[nn.Parameter]:
        """The parameters of the output layer (what `varpro` solves for instead of training)."""
        return [self.weights[-1], self.biases[-1], self.osc_head, self.extra_head]

    def member(self, m: int) -> PINN:
        """A single-member copy of member m (same weights, dtype and options)."""
        one = PINN(
            self.width,
            self.depth,
            members=1,
            hard_bc=self.hard_bc,
            hard_ic=self.hard_ic,
            time_frequency=self.time_frequency,
            oscillator=self.oscillator,
            extras=self.extras,
            dtype=self.log_ei.dtype,
        )
        one.load_state_dict(
            {k: v[m : m + 1].detach().clone() for k, v in self.state_dict().items()}
        )
        return one.to(self.log_ei.device)

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
