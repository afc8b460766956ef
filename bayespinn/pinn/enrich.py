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

**The forced response, not only the static one.** Under a moving load mode n is driven at the frequency
Omega_n = n pi v / L at which the axle crosses its half-waves, and its particular (forced) response is the
static one amplified by D_n = 1 / (1 - r_n^2), r_n = Omega_n / omega_n = alpha / n at EI_ref's frequencies
(alpha = v / (2 f1 L); with damping zeta a phase too). The static shape alone leaves that amplification to
the enrichment's free coefficient, and the data cannot tell an amplified first mode from a softer girder:
fitted to the exact response with the free vibrations of the first three modes, the static enrichment's
coefficient comes out 1 / (1 - alpha^2) (1.004 at alpha = 0.064, 1.042 at 0.2; `tests/test_enrich.py`),
and the PDE then turns that coefficient into an EI low by the same factor, a bias of several posterior sds
on fast crossings. With `frequency` given, the enrichment is the forced response at the current EI:

    E(xi, tau; EI) = E_static + sum_{n <= K_a} (D_n(EI) - 1) E_n + (EI_ref / EI) sum_{n > K_a} r_n^2 E_n

(D_n with the damping's phase; r_n at EI_ref), E_n the n-th term of the static series. It solves
EI E_xixixixi / 48 + inertia E_tautau = f / q at that EI (the particular solution of every mode: the free
vibrations carry the homogeneous rest), exactly for the first K_a modes and to O(r_n^4) for the rest, and
the fit's coefficient is EI_ref / EI whatever the speed. K_a (`amplified_modes`) follows the bridge: the
smallest K with (r_1 / (K + 1))^2 (K + 1)^-4 below AMPLIFIED_TOL (with EI down to EI_ref / 4), so the
first-order tail errs by less than that share of the first mode's static deflection: 5 modes at the Exeter
girder's alpha, 10 at 0.2. The parts that depend on EI are kept per point set like the static jet; EI
enters detached, like the free vibrations' frequency: the amplification follows EI between steps.

E depends on the points alone, and a series of ~300 sines per point cost a tenth of a training step, so
each enrichment keeps the jets of the last few point sets it was asked for (`_JetCache`): the data points
never change during a fit and the collocation points only every `resample_every` steps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import torch
from torch import Tensor

from .jet_cache import _JetCache
from .taylor import Jet

#: truncation: the sine series stops where g_n < this (its fourth derivative then converges to it)
SERIES_TOL = 1e-9
#: modes whose dynamic amplification is left out contribute less than this share of mode 1's static part
AMPLIFIED_TOL = 1e-7
#: EI may fall this far below EI_ref (r_n grows as EI falls) before K_a would need one more mode
AMPLIFIED_EI_MARGIN = 4.0
#: r_n^2 is clamped below this, a guard for EIs far off in a diverging fit (a bridge has alpha < 0.5)
MAX_R2 = 0.81


def n_terms(beta_rel: float, tol: float = SERIES_TOL) -> int:
    """Terms needed for the series of a Gaussian of width beta_rel (beta / L): g_n < tol beyond."""
    return max(8, int(math.ceil(2.0 * math.sqrt(math.log(1.0 / tol)) / (math.pi * beta_rel))) + 1)


def forced_amplification(
    r1: float, n: Tensor, log_ei: Tensor, damping: float
) -> tuple[Tensor, Tensor | None]:
    """(D_n - 1, the quadrature part or None without damping) of modes n (K,) at log(EI / EI_ref) (M,), for
    r_1 = Omega_1 / omega_1 at EI_ref: mode n's forced response is (1 + a_n) sin(Omega_n t) +
    b_n cos(Omega_n t) times its static amplitude; shapes (M, K)."""
    r = r1 / (n * torch.exp(0.5 * log_ei).unsqueeze(-1))  # Omega_n / omega_n
    r2 = (r * r).clamp(max=MAX_R2)
    z = damping
    if z == 0.0:
        return 1.0 / (1.0 - r2) - 1.0, None
    den = (1.0 - r2) ** 2 + (2.0 * z) ** 2 * r2
    return (1.0 - r2) / den - 1.0, -2.0 * z * r2.sqrt() / den


@dataclass(frozen=True)
class StaticEnrichment:
    """The axles in non-dimensional form (see module docstring).

    loads : (J,) axle loads / P; delays : (J,) entry times / T; speed : v T / L; beta_rel : beta / L;
    frequency : None (the quasi-static enrichment), or W_1 = omega_1(EI_ref) T [rad]: the forced response
    at the current EI (module docstring); damping : zeta, the modal damping ratio (with `frequency`).
    """

    loads: tuple[float, ...]
    delays: tuple[float, ...]
    speed: float
    beta_rel: float
    frequency: float | None = None
    damping: float = 0.0
    _cache: _JetCache = field(default_factory=_JetCache, init=False, repr=False, compare=False)
    _modes: _JetCache = field(default_factory=_JetCache, init=False, repr=False, compare=False)

    n_features = 1

    @property
    def amplified_modes(self) -> int:
        """K_a: the modes whose forced amplification the enrichment carries (0: quasi-static)."""
        if self.frequency is None:
            return 0
        r1_sq = AMPLIFIED_EI_MARGIN * (math.pi * self.speed / self.frequency) ** 2
        return max(1, math.ceil((r1_sq / AMPLIFIED_TOL) ** (1.0 / 6.0)) - 1)

    def amplification(self, log_ei: Tensor) -> tuple[Tensor, Tensor | None]:
        """(D_n - 1, its quadrature part or None without damping) for n = 1..K_a at log(EI / EI_ref)
        (M,): the forced response of mode n is (1 + a_n) sin(Omega_n t) + b_n cos(Omega_n t) times its
        static amplitude; shapes (M, K_a)."""
        K = self.amplified_modes
        n = torch.arange(1, K + 1, dtype=log_ei.dtype, device=log_ei.device)
        return forced_amplification(self._r1(), n, log_ei, self.damping)

    def _r1(self) -> float:
        """r_1 at EI_ref: Omega_1 / omega_1 = pi (v T / L) / W_1 (alpha at EI_ref)."""
        return math.pi * self.speed / self.frequency

    def jet(self, xi: Tensor, tau: Tensor, kx: int, kt: int, log_ei: Tensor | None = None) -> Jet:
        """Jet of E at points (M, N): components (M, N, 1). Quasi-static (no `frequency`, or no
        ``log_ei``): the same Jet object again for the same point tensors (its components are never
        modified in place). Forced: the static jet plus the amplified share at ``log_ei`` (M,), detached:
        modes 1..K_a exactly, the rest to first order in r_n^2 (D_n - 1 = r_n^2 / theta + O(r_n^4),
        theta = EI / EI_ref), so that the PDE residual of every mode is solved, not only the deflection."""
        static = self._cache.get(xi, tau, kx, kt, lambda: self._jet(xi, tau, kx, kt))
        if self.frequency is None or log_ei is None:
            return static
        K = self.amplified_modes
        parts = self._modes.get(xi, tau, kx, kt, lambda: self._mode_jets(xi, tau, kx, kt, K))
        lei = log_ei.detach().to(xi.dtype)
        a, b = self.amplification(lei)
        theta = torch.exp(lei).view(-1, 1, 1)
        # (jet, its weight over the last axis): modes 1..K_a, then the tails
        weighted = [(parts[0], a.unsqueeze(1)), (parts[2], 1.0 / theta)]
        if b is not None:
            weighted += [(parts[1], b.unsqueeze(1)), (parts[3], 1.0 / theta.sqrt())]

        def add(base: Tensor, *cs: Tensor) -> Tensor:
            out = base
            for c, (_, w) in zip(cs, weighted, strict=True):
                out = out + (c * w).sum(-1, keepdim=True)
            return out

        jets = [j for j, _ in weighted]
        return Jet(
            add(static.value, *(j.value for j in jets)),
            tuple(add(*z) for z in zip(static.x, *(j.x for j in jets), strict=True)),
            tuple(add(*z) for z in zip(static.t, *(j.t for j in jets), strict=True)),
        )

    def _series(
        self,
        xi: Tensor,
        tau: Tensor,
        kx: int,
        kt: int,
        modes: range,
        *,
        total: bool,
        phase: int = 0,
        weight=None,
    ) -> Jet:
        """Jet of the terms `modes` of the static series, summed (components (M, N, 1)) or per mode
        ((M, N, len(modes))); phase 1 puts cos(k a) in place of sin(k a) (the damped response's
        quadrature); weight(n) (a tensor over the modes) multiplies each term."""
        n = torch.arange(modes.start, modes.stop, dtype=xi.dtype, device=xi.device)
        k = math.pi * n
        g = 2.0 * torch.exp(-((k * self.beta_rel) ** 2) / 4.0) / k**4 * 48.0
        if weight is not None:
            g = g * weight(n)
        kxi = xi.unsqueeze(-1) * k  # (M, N, n)
        sx, cx = torch.sin(kxi), torch.cos(kxi)
        # d^m/dxi^m sin(k xi) = k^m sin(k xi + m pi / 2): (sin, cos, -sin, -cos)
        x_parts = [sx, cx, -sx, -cx]
        # time factor per axle: A_m(tau) = sum_j p_j live_j d^m/dtau^m sin(k a_j + phase pi / 2)
        A = [torch.zeros_like(kxi) for _ in range(kt + 1)]
        for p, d in zip(self.loads, self.delays, strict=True):
            a = self.speed * (tau - d)
            live = ((a >= 0.0) & (a <= 1.0)).to(xi.dtype).unsqueeze(-1)
            ka = a.unsqueeze(-1) * k
            sa, ca = torch.sin(ka), torch.cos(ka)
            t_parts = [sa, ca, -sa, -ca][phase:]
            for m in range(kt + 1):
                A[m] = A[m] + (p * live) * (k * self.speed) ** m * t_parts[m]

        def comp(mx: int, mt: int) -> Tensor:
            c = (g * k**mx) * x_parts[mx % 4] * A[mt]
            return c.sum(-1, keepdim=True) if total else c

        return Jet(
            comp(0, 0),
            tuple(comp(m, 0) for m in range(1, kx + 1)),
            tuple(comp(0, m) for m in range(1, kt + 1)),
        )

    def _jet(self, xi: Tensor, tau: Tensor, kx: int, kt: int) -> Jet:
        return self._series(xi, tau, kx, kt, range(1, n_terms(self.beta_rel) + 1), total=True)

    def _mode_jets(self, xi: Tensor, tau: Tensor, kx: int, kt: int, K: int) -> tuple:
        """(modes 1..K per mode, their quadrature or None, the tail sum_{n > K} r_n^2 E_n at EI_ref, its
        quadrature -2 zeta r_n E_n^cos or None): the parts of the forced response that depend on EI."""
        head = range(1, K + 1)
        tail = range(K + 1, max(n_terms(self.beta_rel), K) + 1)
        r1 = self._r1()
        sin_part = self._series(xi, tau, kx, kt, head, total=False)
        tail_sin = self._series(xi, tau, kx, kt, tail, total=True, weight=lambda n: (r1 / n) ** 2)
        if not self.damping:
            return sin_part, None, tail_sin, None
        z = self.damping
        cos_part = self._series(xi, tau, kx, kt, head, total=False, phase=1)
        tail_cos = self._series(
            xi, tau, kx, kt, tail, total=True, phase=1, weight=lambda n: -2.0 * z * r1 / n
        )
        return sin_part, cos_part, tail_sin, tail_cos


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


#: transients of modes above K_v are below this share of the first mode's static amplitude (module
#: docstring of `TiedVibration`): 100x below the noise at the highest SNR bayespinn is meant for (40 dB)
TRANSIENT_TOL = 1e-4


def transient_modes(r1: float, tol: float = TRANSIENT_TOL) -> int:
    """K_v: the modes whose free vibrations `TiedVibration` carries, for r_1 = alpha at EI_ref.

    Mode n's free vibration from an axle event has amplitude r_n S_n = r_1 n^-5 S_1 (S_n its static
    amplitude, ~ n^-4): the smallest K with 2 r_1 (K + 1)^-5 below `tol` (r doubled: EI may be down to
    EI_ref / 4, `AMPLIFIED_EI_MARGIN`), at least 1. 3 modes at the Exeter girder's alpha (0.021), 5 at 0.2."""
    K = 1
    while 2.0 * r1 * (K + 1) ** -5 >= tol and K < 64:
        K += 1
    return K


@dataclass(frozen=True)
class TiedVibration(FreeVibration):
    """The free vibrations that the axles start, with the amplitudes the physics gives them: one column per mode.

    `FreeVibration` gives each mode two free coefficients per axle event (an entry or an exit). A truck of
    J axles has 2 J events, so K modes cost 4 J K coefficients (60 for five axles and three modes), which
    the data must pay for: fitted to noise they widen EI's posterior and bias it. Bridge 9 of the family
    (10.8 m, four axles, alpha 0.044, 30 dB): the B-PINN's sd was 2.54x the reference's and its mean 7.1
    reference sds low; a linear analog of the last layer shows the same from the free amplitudes alone
    (sd 2.7x, 10.9 sds low; tied: 1.11x, -0.28 sd; `tests/test_enrich.py`), and with tied amplitudes the
    B-PINN gives 1.10x and -0.67 sd. But those amplitudes are not free. From rest, the state of mode n is continuous
    across every event, and the forced response the enrichment carries is not: an axle entering starts
    S [(1 + a_n) sin(Omega_n s) + b_n cos(Omega_n s)] (S its static amplitude, a_n and b_n the amplification of
    `forced_amplification`), with displacement S b_n and velocity S (1 + a_n) Omega_n at s = 0; leaving at
    s_e = L / v, it stops with (-1)^n times those. So each event starts the free vibration that cancels
    that jump, with amplitudes fixed by the axle's load, the mode and EI:

        h_n(s) = e^{-zeta W_n s} (A sin(w_n s) + B cos(w_n s)),  B = -S b_n,  A = (-S (1 + a_n) Omega_n + zeta W_n B) / w_n

    at an entry, (-1)^(n+1) times that at an exit (w_n = W_n sqrt(1 - zeta^2)). Summed over the events, mode n's
    free vibration is one function of EI, and its column's coefficient is the enrichment's (the initial
    conditions tie the two: at the first entry the enrichment's velocity is the column's with the opposite
    sign). Each column is an exact homogeneous solution (zero damping), so its PDE residual is zero, and the
    total of enrichment and columns is the exact modal response of the Gaussian loads for the first K_v modes
    (`transient_modes`; checked against `physics.modal.ModalModel` in the tests). The modes above K_v start
    vibrations below `TRANSIENT_TOL` of the first mode's static amplitude; the network keeps any rest.

    loads, delays, speed, beta_rel : as `StaticEnrichment`'s; events, modes, frequency, damping : as
    `FreeVibration`'s (events are kept for the record; the jet uses the axles).
    """

    loads: tuple[float, ...] = ()
    delays: tuple[float, ...] = ()
    speed: float = 1.0
    beta_rel: float = 0.025

    @property
    def n_features(self) -> int:
        return self.modes

    _parts: _JetCache = field(default_factory=_JetCache, init=False, repr=False, compare=False)

    def _fixed(self, xi: Tensor, tau: Tensor, kx: int) -> tuple:
        """What does not depend on EI at these points: the mode shapes' x-derivatives 0..kx (M, N, K) and,
        per event (an axle entering or leaving inside the window), the time since it (M, N, E, 1), whether
        it has happened, and its load times its sign per mode (E, K)."""
        n = torch.arange(1, self.modes + 1, dtype=xi.dtype, device=xi.device)  # (K,)
        k = math.pi * n
        kxi = xi.unsqueeze(-1) * k  # (M, N, K)
        sx, cx = torch.sin(kxi), torch.cos(kxi)
        x_parts = [sx, cx, -sx, -cx]
        X = [k**m * x_parts[m % 4] for m in range(kx + 1)]
        t0, load, leaves = [], [], []
        for p, d in zip(self.loads, self.delays, strict=True):
            for t, out in ((d, False), (d + 1.0 / self.speed, True)):
                if t < 1.0:
                    t0.append(t)
                    load.append(p)
                    leaves.append(out)
        opts = {"dtype": xi.dtype, "device": xi.device}
        exit_sign = -((-1.0) ** n)  # (-1)^(n + 1), (K,)
        lv = torch.tensor(leaves, device=xi.device).unsqueeze(-1)
        c = torch.tensor(load, **opts).unsqueeze(-1) * torch.where(
            lv, exit_sign, torch.ones_like(n)
        )
        s = tau.unsqueeze(-1) - torch.tensor(t0, **opts)  # (M, N, E)
        sp = s.clamp_min(0.0).unsqueeze(-1)  # (M, N, E, 1)
        on = (s >= 0.0).to(xi.dtype).unsqueeze(-1)
        return n, X, sp, on, c

    def jet(
        self, xi: Tensor, tau: Tensor, kx: int, kt: int, log_ei: Tensor, detach: bool = True
    ) -> Jet:
        """Jet of the K columns (highest mode first, as `FreeVibration`) at points (M, N): (M, N, K).
        The parts that do not depend on EI are kept per point set (`_JetCache`), so re-evaluating the columns
        at another EI (the last layer's NUTS) costs only the EI-dependent ones."""
        lei = (log_ei.detach() if detach else log_ei).to(xi.dtype)
        n, X, sp, on, c = self._parts.get(xi, tau, kx, -1, lambda: self._fixed(xi, tau, kx))
        k = math.pi * n
        # static amplitude per unit load (the enrichment's series coefficient) and the entry amplitudes
        S = 2.0 * torch.exp(-((k * self.beta_rel) ** 2) / 4.0) / k**4 * 48.0  # (K,)
        a, b = forced_amplification(math.pi * self.speed / self.frequency, n, lei, self.damping)
        a, b = a.unsqueeze(1), (None if b is None else b.unsqueeze(1))  # (M, 1, K)
        W = (self.frequency * torch.exp(0.5 * lei)).view(-1, 1, 1) * n**2  # (M, 1, K)
        z = self.damping
        dec, w = z * W, W * math.sqrt(1.0 - z * z)
        Om = k * self.speed
        B0 = torch.zeros_like(a) if b is None else -b
        A0 = (-(1.0 + a) * Om + dec * B0) / w
        A0, B0 = A0 * S, B0 * S
        dec4, w4 = dec.unsqueeze(2), w.unsqueeze(2)  # (M, 1, 1, K)
        A, B = A0.unsqueeze(2) * c, B0.unsqueeze(2) * c  # (M, 1, E, K)
        e = torch.exp(-dec4 * sp) * on
        ang = w4 * sp
        sn, cs = torch.sin(ang), torch.cos(ang)
        T = [(e * (A * sn + B * cs)).sum(2)]
        if kt >= 1:
            T.append((e * (A * (-dec4 * sn + w4 * cs) + B * (-dec4 * cs - w4 * sn))).sum(2))
        if kt >= 2:
            c2 = dec4 * dec4 - w4 * w4
            T.append(
                (e * (A * (c2 * sn - 2 * dec4 * w4 * cs) + B * (c2 * cs + 2 * dec4 * w4 * sn))).sum(
                    2
                )
            )
        return Jet(
            (X[0] * T[0]).flip(-1),
            tuple((X[m] * T[0]).flip(-1) for m in range(1, kx + 1)),
            tuple((X[0] * T[m]).flip(-1) for m in range(1, kt + 1)),
        )

    def lowest(self) -> TiedVibration:
        """The first mode alone: its column is the trailing one of this one's."""
        return replace(self, modes=1)
