"""The uniform pinned girder's response to a crossing whose speed, entry time, damping and axle forces are
parameters, in closed form and vectorised over parameter sets.

For mode n (phi_n = sin(k_n x), k_n = n pi / L, omega_n = k_n^2 sqrt(EI / mu), Omega_n = k_n v) an axle
that enters at t0 + offset / v exerts, during its time on the span tau in [0, L / v], the modal force
(2 / (mu L)) F(tau) sin(Omega_n tau). Each force history here is a sum of harmonics Re(A e^{i gamma tau}):
a constant force is sin(Omega tau) = Re(-i e^{i Omega tau}); a force basis function sin(alpha tau + beta)
(the Hilbert-space Gaussian-process basis of `basis_functions`) times sin(Omega tau) is two harmonics at
Omega -+ alpha. The response to one harmonic from rest is exact (particular plus homogeneous solution), and
so is the free vibration after the axle leaves, as in `physics.modal.ModalModel`, which this generalises.

The mode-acceleration form carries the truncation: the exact static response of the force at its place
(F(tau) times the static influence line, divided by EI) plus the modal dynamic corrections q_n - g_n /
omega_n^2 of the first `n_modes` modes. With constant forces, t0 = 0 and the stated speed this is
`ModalModel` to rounding (tests/test_crossings.py).

Everything is batched over W parameter sets (EI, zeta, v, t0): arrays (W, ..., N modes, U times). Modal
coordinates are computed once per distinct time and combined per distinct sensor (x, weights), so four
strain gauges read at common times cost one set of modal coordinates.
"""

from __future__ import annotations

import math

import numpy as np

from ..physics.modal import static_unit_deflection, static_unit_moment

#: the Hilbert-space basis lives on [-c Te / 2, c Te / 2] around the axle's time on the span [0, Te]
BOUNDARY_FACTOR = 1.5


def basis_frequencies(
    Te: np.ndarray, m: int, start: int = 1
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(alpha (W, m), beta (W, m), half-width Lh (W,)) of the Hilbert-space basis (Solin and Sarkka)
    phi_k(tau) = Lh^(-1/2) sin(alpha_k tau + beta_k), k = start .. start + m - 1, on an axle's time on the
    span tau in [0, Te]: the Laplacian's eigenfunctions on [-Lh, Lh] around the interval's centre,
    Lh = BOUNDARY_FACTOR Te / 2; sqrt of the eigenvalue alpha_k = pi k / (2 Lh)."""
    Te = np.atleast_1d(np.asarray(Te, float))
    Lh = BOUNDARY_FACTOR * Te / 2.0
    alpha = np.pi * np.arange(start, start + m)[None, :] / (2.0 * Lh[:, None])
    beta = alpha * (Lh[:, None] - Te[:, None] / 2.0)
    return alpha, beta, Lh


def basis_functions(tau: np.ndarray, Te: np.ndarray, m: int, start: int = 1) -> np.ndarray:
    """phi_k(tau), k = start .. start + m - 1, for tau (W, P) on [0, Te (W,)]: array (W, m, P)."""
    alpha, beta, Lh = basis_frequencies(Te, m, start)
    return _basis(tau, alpha, beta, Lh)


def _basis(tau: np.ndarray, alpha: np.ndarray, beta: np.ndarray, Lh: np.ndarray) -> np.ndarray:
    return (
        np.sin(alpha[:, :, None] * tau[:, None, :] + beta[:, :, None]) / np.sqrt(Lh)[:, None, None]
    )


def se_spectral_sd(alpha: np.ndarray, scale: np.ndarray, length: np.ndarray) -> np.ndarray:
    """sqrt of the squared-exponential kernel's spectral density S(alpha) = s^2 sqrt(2 pi) l
    exp(-l^2 alpha^2 / 2), for scale s (W,), time scale l (W,) [s] and alpha (W, m) [rad/s]."""
    s, ell = np.asarray(scale, float)[:, None], np.asarray(length, float)[:, None]
    return s * np.sqrt(np.sqrt(2.0 * np.pi) * ell) * np.exp(-0.25 * (ell * alpha) ** 2)


class CrossingModel:
    """Observations a_u u + a_xx u_xx of the uniform pinned girder at fixed (x, t) under moving axles.

    Parameters
    ----------
    length, mass_per_length : the span L [m] and mu [kg/m]
    loads, offsets : arrays (J,), axle loads [N] and offsets behind the first axle [m]
    x, t : arrays (P,), observation positions [m] and times on the data's clock [s]
    a_u, a_xx : arrays (P,) or floats: deflection rows (1, 0), strain rows (0, -y)
    n_modes : modes in the dynamic correction of the constant forces
    n_basis : force basis functions per axle (0: constant forces only)
    basis_modes : modes in the dynamic correction of the basis forces (default n_modes)
    band : (first index, count) of further basis functions per axle, beyond the first n_basis (a band of
        the force's spectrum, `tail`); their columns follow every axle's first n_basis, axle by axle
    """

    def __init__(
        self,
        length: float,
        mass_per_length: float,
        loads,
        offsets,
        x,
        t,
        a_u=1.0,
        a_xx=0.0,
        *,
        n_modes: int = 10,
        n_basis: int = 0,
        basis_modes: int | None = None,
        band: tuple[int, int] | None = None,
    ):
        self.L, self.mu = float(length), float(mass_per_length)
        self.loads = np.asarray(loads, float).ravel()
        self.offsets = np.asarray(offsets, float).ravel()
        x = np.asarray(x, float).ravel()
        t = np.asarray(t, float).ravel()
        P = x.size
        self.x, self.t = x, t
        self.a_u = np.broadcast_to(np.asarray(a_u, float), (P,)).copy()
        self.a_xx = np.broadcast_to(np.asarray(a_xx, float), (P,)).copy()
        self.any_u, self.any_xx = bool(np.any(self.a_u != 0)), bool(np.any(self.a_xx != 0))
        self.n_modes, self.n_basis = int(n_modes), int(n_basis)
        self.basis_modes = min(self.n_modes, int(n_modes if basis_modes is None else basis_modes))
        self.band = None if band is None or int(band[1]) == 0 else (int(band[0]), int(band[1]))
        if self.band is not None and (self.n_basis == 0 or self.band[0] <= self.n_basis):
            raise ValueError(
                f"a band {self.band} must start beyond the {self.n_basis} basis functions"
            )
        self.k = np.arange(1, self.n_modes + 1) * math.pi / self.L  # (N,)
        # distinct sensors (x, a_u, a_xx) and distinct times: modal coordinates once per time
        keys = np.stack([x, self.a_u, self.a_xx], axis=1)
        sensors, self.sensor_of = np.unique(keys, axis=0, return_inverse=True)
        self.sensor_of = self.sensor_of.ravel()
        times, self.time_of = np.unique(t, return_inverse=True)
        self.time_of = self.time_of.ravel()
        self.grouped = sensors.shape[0] * times.size <= 2 * P
        if self.grouped:
            self.times = times
            xs, au, axx = sensors.T
        else:  # scattered points: each its own sensor and time
            self.times, self.time_of = t, np.arange(P)
            self.sensor_of = np.arange(P)
            xs, au, axx = x, self.a_u, self.a_xx
        # observation weight of each mode at each sensor: (N, G)
        self.shape = np.sin(self.k[:, None] * xs[None, :]) * (
            au[None, :] - axx[None, :] * self.k[:, None] ** 2
        )

    @property
    def n_band(self) -> int:
        """Band functions per axle (`band`)."""
        return 0 if self.band is None else self.band[1]

    @property
    def n_columns(self) -> int:
        """Columns of the basis responses: n_basis per axle, then n_band per axle."""
        return (self.n_basis + self.n_band) * self.loads.size

    def _powers(self, z1: np.ndarray, N: int, square: bool) -> np.ndarray:
        """z1^n (or z1^(n^2) with square) for n = 1..N, z1 (W, U) -> (W, N, U): one or two complex
        products per mode instead of an exp (Omega_n = n Omega_1 and lambda_n = n^2 lambda_1)."""
        out = np.empty((z1.shape[0], N, z1.shape[1]), dtype=complex)
        out[:, 0] = z1
        if square:
            z2, odd = z1 * z1, z1
            for n in range(1, N):
                odd = odd * z2
                out[:, n] = out[:, n - 1] * odd
        else:
            for n in range(1, N):
                out[:, n] = out[:, n - 1] * z1
        return out

    def _contract(self, coef: np.ndarray, e: np.ndarray) -> np.ndarray:
        """Re(sum_n shape_n coef_n e_n): coef (W, K, N), e (W, N, U) -> (W, K, G, U) per distinct sensor
        (grouped), or (W, K, 1, P) at the scattered points."""
        N = coef.shape[-1]
        if self.grouped:
            cs = coef[:, :, None, :] * self.shape[:N].T[None, None]  # (W, K, G, N)
            return np.matmul(cs, e[:, None]).real
        return np.matmul(coef, e * self.shape[:N][None]).real[:, :, None, :]

    def _gather(self, E: np.ndarray) -> np.ndarray:
        """(W, K, G, U) per sensor and time -> (W, K, P) at the observations."""
        if self.grouped:
            return E[:, :, self.sensor_of, self.time_of]
        return E[:, :, 0, :]

    def _harmonics(self, A, gamma, e_in, pre, lam, omega, wd, zeta, Te, e_lam, e_af, inside, after):
        """Dynamic corrections q_n - Re(A e^{i gamma tau}) / omega_n^2 of the modes to forcing
        Re(A e^{i gamma tau}) on [0, Te] from rest, and the free vibration after the exit, observed:
        (W, K, G, U).

        A, gamma (W, K, N); the harmonic e^{i gamma tau} = pre (W, K, U) x e_in (W, N, U) (pre = None: 1);
        lam, omega, wd (W, N); zeta, Te (W,); e_lam = e^{lam tau} and e_af = e^{lam (tau - Te)} (W, N, U);
        inside, after (W, U) masks."""
        om, z = omega[:, None, :], zeta[:, None, None]
        c = A / (om**2 - gamma**2 + 2j * z * om * gamma)
        H = -c.real + 1j * (z * om * c.real - gamma * c.imag) / wd[:, None, :]
        lam_k = lam[:, None, :]
        if pre is None:
            forced = self._contract(c - A / om**2, e_in)
        else:  # e^{i gamma_k tau} = pre_k e^{i Omega_n tau}: the mode sum first, then the factor
            forced = (self._contract_c(c - A / om**2, e_in) * pre[:, :, None, :]).real
        E_in = forced + self._contract(H, e_lam)
        g_te = np.exp(1j * gamma * Te[:, None, None])
        l_te = np.exp(lam_k * Te[:, None, None])
        q_e = (c * g_te).real + (H * l_te).real
        qd_e = (1j * gamma * c * g_te).real + (lam_k * H * l_te).real
        Kc = q_e - 1j * (qd_e + z * om * q_e) / wd[:, None, :]
        E_af = self._contract(Kc, e_af)
        return np.where(inside[:, None, None, :], E_in, 0.0) + np.where(
            after[:, None, None, :], E_af, 0.0
        )

    def _contract_c(self, coef: np.ndarray, e: np.ndarray) -> np.ndarray:
        """`_contract` without taking the real part (the harmonic's own factor multiplies it first)."""
        N = coef.shape[-1]
        if self.grouped:
            cs = coef[:, :, None, :] * self.shape[:N].T[None, None]
            return np.matmul(cs, e[:, None])
        return np.matmul(coef, e * self.shape[:N][None])[:, :, None, :]

    def responses(self, EI, zeta, v, t0, *, basis: bool = False):
        """The constant-force response (W, P) and, with basis=True, the responses to each axle's force basis
        functions P_j phi_m(tau_j) (W, P, J (m + b); column j m + i, then the band's J m + j b + i), for
        parameter sets EI [N m^2], zeta [-], v [m/s], t0 [s] (arrays (W,) or floats)."""
        EI, zeta, v, t0 = (np.atleast_1d(np.asarray(a, float)) for a in (EI, zeta, v, t0))
        EI, zeta, v, t0 = np.broadcast_arrays(EI, zeta, v, t0)
        W, N, M, B = EI.size, self.n_modes, self.n_basis, self.n_band
        Nb, J = self.basis_modes, self.loads.size
        omega = self.k[None, :] ** 2 * np.sqrt(EI[:, None] / self.mu)  # (W, N)
        wd = omega * np.sqrt(1.0 - zeta[:, None] ** 2)
        lam = -zeta[:, None] * omega + 1j * wd
        Omega = self.k[None, :] * v[:, None]
        Te = self.L / v
        mean = np.zeros((W, self.x.size))
        R = np.zeros((W, self.x.size, self.n_columns)) if basis and M else None
        if R is not None:
            alpha, beta, Lh = basis_frequencies(Te, M)
            if B:  # the band's functions after the first M, one basis of M + B per axle
                ab, bb, _ = basis_frequencies(Te, B, self.band[0])
                alpha, beta = np.concatenate([alpha, ab], 1), np.concatenate([beta, bb], 1)
        for j, (Pj, oj) in enumerate(zip(self.loads, self.offsets, strict=True)):
            F = 2.0 * Pj / (self.mu * self.L)
            tau = self.times[None, :] - t0[:, None] - oj / v[:, None]  # (W, U)
            inside = (tau >= 0.0) & (tau <= Te[:, None])
            after = tau > Te[:, None]
            tau_in = np.where(inside, tau, 0.0)
            e_af = self._powers(
                np.exp(lam[:, :1] * np.where(after, tau - Te[:, None], 0.0)), N, True
            )
            e_lam = self._powers(np.exp(lam[:, :1] * tau_in), N, True)
            e_om = self._powers(np.exp(1j * Omega[:, :1] * tau_in), N, False)  # (W, N, U)
            A = np.full((W, 1, N), -1j * F)
            E = self._harmonics(
                A, Omega[:, None, :], e_om, None, lam, omega, wd, zeta, Te, e_lam, e_af,
                inside, after,
            )  # fmt: skip
            mean += self._gather(E)[:, 0]
            # exact static part at the observation points
            tp = self.t[None, :] - t0[:, None] - oj / v[:, None]  # (W, P)
            on = (tp >= 0.0) & (tp <= Te[:, None])
            pos = np.clip(v[:, None] * tp, 0.0, self.L)
            st = np.zeros_like(pos)
            if self.any_u:
                st += self.a_u * static_unit_deflection(self.x[None, :], pos, self.L)
            if self.any_xx:
                st -= self.a_xx * static_unit_moment(self.x[None, :], pos, self.L)
            st = np.where(on, st, 0.0) * (Pj / EI[:, None])
            mean += st
            if R is None:
                continue
            # basis j: Lh^-1/2 sin(alpha tau + beta) sin(Omega tau) = two harmonics Omega -+ alpha
            s = 0.5 / np.sqrt(Lh)[:, None, None]
            a_k = alpha[:, :, None]
            ones = np.ones((1, 1, Nb))
            A1 = F * s * np.exp(-1j * beta)[:, :, None] * ones
            A2 = -F * s * np.exp(1j * beta)[:, :, None] * ones
            # the basis at each distinct time, then at the observations (their times' columns)
            phi = _basis(tau_in, alpha, beta, Lh)[:, :, self.time_of]
            basis_st = st[:, None, :] * phi
            low, high = slice(j * M, (j + 1) * M), slice(J * M + j * B, J * M + (j + 1) * B)
            if Nb == 0:  # the quasi-static response alone
                R[:, :, low] = np.transpose(basis_st[:, :M], (0, 2, 1))
                R[:, :, high] = np.transpose(basis_st[:, M:], (0, 2, 1))
                continue
            e_a = np.exp(-1j * alpha[:, :, None] * tau_in[:, None, :])  # (W, M, U)
            rest = (lam[:, :Nb], omega[:, :Nb], wd[:, :Nb], zeta, Te, e_lam[:, :Nb], e_af[:, :Nb])
            E1 = self._harmonics(
                A1, Omega[:, None, :Nb] - a_k, e_om[:, :Nb], e_a, *rest, inside, after
            )
            E2 = self._harmonics(
                A2, Omega[:, None, :Nb] + a_k, e_om[:, :Nb], np.conj(e_a), *rest, inside, after
            )
            Rj = self._gather(E1 + E2)  # (W, M, P)
            Rj += basis_st
            R[:, :, low] = np.transpose(Rj[:, :M], (0, 2, 1))
            R[:, :, high] = np.transpose(Rj[:, M:], (0, 2, 1))
        return (mean, R) if basis else mean

    def predict(self, EI, zeta, v, t0) -> np.ndarray:
        """The constant-force response (W, P)."""
        return self.responses(EI, zeta, v, t0)
