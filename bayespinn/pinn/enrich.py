"""Static enrichment: the quasi-static deflection of the Gaussian loads as one extra basis function.

The PDE's forcing is a Gaussian of width beta on each axle path (paper Eq. 5, 19-21), a ridge of width
0.025 L in the (x, t) plane that u_xxxx must reproduce. EI is identified through exactly that balance
(EI [u_xxx] = P across the load), and a tanh MLP approximates the fourth derivative of such a ridge
poorly: its EI wanders by percents from step to step. Following the enrichment idea of extended
finite elements, the output layer of the fast profile gets one more basis function, with its own free
coefficient, that carries the ridge exactly:

    E(xi, tau) = 48 sum_j p_j [a_j in [0, 1]] sum_n 2 g_n sin(n pi a_j) sin(n pi xi) / (n pi)^4,

a_j = v (tau - tau_j) T / L the axle position / L, g_n = exp(-(n pi beta / L)^2 / 4) the sine coefficients
of the Gaussian with its images (`losses.moving_load(images=True)`), p_j the axle load / P. E solves
E_xixixixi / 48 = f / q exactly and vanishes with u_xx at both supports; at EI = EI_ref a quasi-static
girder would have w = E. Its coefficient is *not* fixed: it is solved with the rest of the output layer,
and the PDE residual ties it to EI, so EI is still identified by the loss terms of the paper. The
network learns everything else: the dynamics, the initial conditions, any departure from the load model.

Derivatives are exact: d/dxi and d/dtau of the sines shift their phase by pi/2.

E depends on the points alone, and a series of ~300 sines per point cost a tenth of a training step, so
each enrichment keeps the jets of the last few point sets it was asked for (`_JetCache`): the data points
never change during a fit and the collocation points only every `resample_every` steps.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, field

import torch
from torch import Tensor

from .taylor import Jet

#: truncation: the sine series stops where g_n < this (its fourth derivative then converges to it)
SERIES_TOL = 1e-9


def n_terms(beta_rel: float, tol: float = SERIES_TOL) -> int:
    """Terms needed for the series of a Gaussian of width beta_rel (beta / L): g_n < tol beyond."""
    return max(8, int(math.ceil(2.0 * math.sqrt(math.log(1.0 / tol)) / (math.pi * beta_rel))) + 1)


def _compiling() -> bool:
    f = getattr(torch.compiler, "is_compiling", None)  # torch >= 2.3
    return bool(f()) if f is not None else bool(torch._dynamo.is_compiling())


class _JetCache:
    """The jets of the last `size` point sets, keyed by the very tensors (identity and version, so a new or
    modified tensor is a miss). Not kept for points that carry gradients, nor while torch.compile traces;
    not pickled (a copy starts empty)."""

    def __init__(self, size: int = 8):
        self.size = size
        self.items: OrderedDict = OrderedDict()

    @staticmethod
    def usable(xi: Tensor, tau: Tensor) -> bool:
        return not (xi.requires_grad or tau.requires_grad or _compiling())

    def get(self, xi: Tensor, tau: Tensor, kx: int, kt: int, make) -> Jet:
        if not self.usable(xi, tau):
            return make()
        key = (id(xi), id(tau), kx, kt)
        hit = self.items.get(key)
        # the entry holds its tensors, so their ids cannot be reused while it lives
        if (
            hit is not None
            and hit[0] is xi
            and hit[1] is tau
            and hit[2] == (xi._version, tau._version)
        ):
            self.items.move_to_end(key)
            return hit[3]
        jet = make()
        self.items[key] = (xi, tau, (xi._version, tau._version), jet)
        while len(self.items) > self.size:
            self.items.popitem(last=False)
        return jet

    def __getstate__(self) -> dict:
        return {"size": self.size}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["size"])


@dataclass(frozen=True)
class StaticEnrichment:
    """The axles in non-dimensional form (see module docstring).

    loads : (J,) axle loads / P; delays : (J,) entry times / T; speed : v T / L; beta_rel : beta / L.
    """

    loads: tuple[float, ...]
    delays: tuple[float, ...]
    speed: float
    beta_rel: float
    _cache: _JetCache = field(default_factory=_JetCache, init=False, repr=False, compare=False)

    n_features = 1

    def jet(self, xi: Tensor, tau: Tensor, kx: int, kt: int, log_ei: Tensor | None = None) -> Jet:
        """Jet of E at points (M, N): components (M, N, 1) (``log_ei`` is not used); the same Jet object
        again for the same point tensors (its components are never modified in place)."""
        return self._cache.get(xi, tau, kx, kt, lambda: self._jet(xi, tau, kx, kt))

    def _jet(self, xi: Tensor, tau: Tensor, kx: int, kt: int) -> Jet:
        n = n_terms(self.beta_rel)
        k = math.pi * torch.arange(1, n + 1, dtype=xi.dtype, device=xi.device)  # (n,)
        g = 2.0 * torch.exp(-((k * self.beta_rel) ** 2) / 4.0) / k**4 * 48.0
        kxi = xi.unsqueeze(-1) * k  # (M, N, n)
        sx, cx = torch.sin(kxi), torch.cos(kxi)
        # d^m/dxi^m sin(k xi) = k^m sin(k xi + m pi / 2): (sin, cos, -sin, -cos)
        x_parts = [sx, cx, -sx, -cx]
        # time factor per axle: A_m(tau) = sum_j p_j live_j d^m/dtau^m sin(k a_j), m = 0..kt
        A = [torch.zeros_like(kxi) for _ in range(kt + 1)]
        for p, d in zip(self.loads, self.delays, strict=True):
            a = self.speed * (tau - d)
            live = ((a >= 0.0) & (a <= 1.0)).to(xi.dtype).unsqueeze(-1)
            ka = a.unsqueeze(-1) * k
            sa, ca = torch.sin(ka), torch.cos(ka)
            t_parts = [sa, ca, -sa]
            for m in range(kt + 1):
                A[m] = A[m] + (p * live) * (k * self.speed) ** m * t_parts[m]

        def comp(mx: int, mt: int) -> Tensor:
            return ((g * k**mx) * x_parts[mx % 4] * A[mt]).sum(-1, keepdim=True)

        return Jet(
            comp(0, 0),
            tuple(comp(m, 0) for m in range(1, kx + 1)),
            tuple(comp(0, m) for m in range(1, kt + 1)),
        )


@dataclass(frozen=True)
class FreeVibration:
    """Free vibrations of the first modes, started at every axle entry and exit, as basis functions.

    A girder crossed in 2.4 s vibrates freely at its first natural frequency (about 24 cycles per crossing
    of the Exeter girder, 2 % of the deflection). Between two axle events (an axle entering or leaving
    the span) the free part of the response is a fixed combination of the beam's free vibrations, so the
    output layer gets, for modes n = 1..K and events tau_e,

        sin(n pi xi) H(tau - tau_e) exp(-zeta W_n s) {sin, cos}(W_n sqrt(1 - zeta^2) s),  s = tau - tau_e,

    W_n = n^2 W_1 sqrt(EI / EI_ref), W_1 = omega_1(EI_ref) T. Each is an exact solution of the homogeneous
    beam equation with the simply supported boundary conditions at the current EI, so they add the dynamics
    with 2 K (events) coefficients and no freedom to bend the static solution. (The modulated features of
    `network` also represent the vibration, with far more freedom: under noise they absorb noise and bias
    EI.) In the network EI enters detached, like the modulated features: the frequency follows EI between
    steps. The final head solve (`varpro.VaryingColumns`) and the last-layer posterior (`lastlayer`)
    evaluate these columns at every EI they try, so the frequency carries its information about EI there.
    With zero damping they solve the homogeneous PDE exactly (`pde_exact`): their PDE residual is zero.

    events : entry and exit times / T inside [0, 1); modes : K; frequency : W_1 [rad]; damping : zeta.
    """

    events: tuple[float, ...]
    modes: int
    frequency: float
    damping: float = 0.0

    @property
    def n_features(self) -> int:
        return 2 * self.modes * len(self.events)

    @property
    def pde_exact(self) -> bool:
        """True when each feature solves the homogeneous beam equation exactly (zero damping)."""
        return self.damping == 0.0

    def jet(
        self, xi: Tensor, tau: Tensor, kx: int, kt: int, log_ei: Tensor, detach: bool = True
    ) -> Jet:
        """Jet of the features at points (M, N): components (M, N, n_features).

        ``log_ei`` (M,) sets the frequency; with ``detach=False`` the jet is differentiable in it (the
        exact-frequency head solve of `varpro` and the last-layer posterior use that).
        """
        lei = log_ei.detach() if detach else log_ei
        n = torch.arange(1, self.modes + 1, dtype=xi.dtype, device=xi.device)  # (K,)
        k = math.pi * n
        kxi = xi.unsqueeze(-1) * k  # (M, N, K)
        sx, cx = torch.sin(kxi), torch.cos(kxi)
        x_parts = [sx, cx, -sx, -cx]
        W = (self.frequency * torch.exp(0.5 * lei.to(xi.dtype))).view(-1, 1, 1) * n**2  # (M, 1, K)
        z = self.damping
        a, w = z * W, W * math.sqrt(1.0 - z * z)
        vals, d1s, d2s = [], [], []
        for te in self.events:
            s = (tau - te).unsqueeze(-1)  # (M, N, 1)
            on = (s >= 0.0).to(xi.dtype)
            sp = s.clamp_min(0.0)
            e = torch.exp(-a * sp) * on
            sn, cs = torch.sin(w * sp), torch.cos(w * sp)
            # f = e sin: f' = e (-a sin + w cos), f'' = e ((a^2 - w^2) sin - 2 a w cos); likewise for cos
            for f0, f1, f2 in (
                (sn, -a * sn + w * cs, (a * a - w * w) * sn - 2 * a * w * cs),
                (cs, -a * cs - w * sn, (a * a - w * w) * cs + 2 * a * w * sn),
            ):
                vals.append(e * f0)
                d1s.append(e * f1)
                d2s.append(e * f2)
        # columns mode-major, highest mode first: (mode K: event 0 sin, cos, event 1 ...), ..., mode 1, so
        # the first mode's columns are the trailing ones (`lowest`)
        shape = xi.shape + (self.n_features,)

        def cols(X: Tensor, parts: list[Tensor]) -> Tensor:  # X (M, N, K); parts: 2E of (M, N, K)
            return (X.flip(-1).unsqueeze(-1) * torch.stack(parts, -1).flip(-2)).reshape(shape)

        def xfac(m: int) -> Tensor:
            return k**m * x_parts[m % 4]

        X0 = xfac(0)
        return Jet(
            cols(X0, vals),
            tuple(cols(xfac(m), vals) for m in range(1, kx + 1)),
            tuple(cols(X0, d) for d in (d1s, d2s)[:kt]),
        )

    def lowest(self) -> FreeVibration:
        """The first mode alone: its columns are the trailing 2 E columns of this one's (same order)."""
        return FreeVibration(self.events, 1, self.frequency, self.damping)

    def split(self, d_all: int) -> tuple[FreeVibration, int, slice | None]:
        """How a basis of `d_all` columns ending in these features is treated when EI varies.

        Returns (the first mode, re-evaluated at every EI tried; the number of columns before it, which
        stay fixed; the higher modes' columns, whose PDE rows are dropped, or None with damping). The
        higher modes stay at the fitted EI: re-evaluated, their fast phases make the objective jagged
        under noise; being exact homogeneous solutions (zero damping), they need no PDE rows.
        """
        low = self.lowest()
        d_fixed = d_all - low.n_features
        quiet = slice(d_all - self.n_features, d_fixed) if self.pde_exact else None
        return low, d_fixed, quiet
