"""Closed-form modal superposition for moving loads on a simply supported beam, batched over EI.

For mode n (phi_n = sin(k_n x), k_n = n pi / L, omega_n = k_n^2 sqrt(EI/mu), Omega_n = k_n v) and an axle
of load P that enters at t_j, the modal coordinate obeys

    q'' + 2 zeta omega q' + omega^2 q = (2 P / (mu L)) g_n sin(Omega tau),   tau = t - t_j in [0, L/v],

from rest, and vibrates freely after the axle leaves. The forced response is solved exactly (particular
+ homogeneous part, complex form), and so is the free vibration. g_n = 1 for a point load and
exp(-(k_n beta)^2 / 4) for the Gaussian delta of width beta (its image-periodic Fourier coefficient).

Point loads use the *mode-acceleration* form: the exact static deflection (and moment) of the point
load, divided by EI, plus the modal *dynamic correction* q_n - q_n_static for the first `n_modes`
modes. The static part carries no truncation error at all, so deflection and strain both converge
fast; the corrections decay like n^-5. Gaussian loads use plain modal superposition with enough modes
for the smoothed load.

Everything is vectorised numpy; `ModalModel.predict` takes a batch of EI values and is the likelihood
surrogate of the reference posterior.
"""

from __future__ import annotations

import math

import numpy as np

from ..config import Beam, Vehicle


def static_unit_deflection(x: np.ndarray, a: np.ndarray, L: float) -> np.ndarray:
    """EI * deflection [m * N m^2 / N] at x for a unit load at a (both [m], broadcast)."""
    x, a = np.broadcast_arrays(np.asarray(x, float), np.asarray(a, float))
    left = x <= a
    xl = np.where(left, x, L - x)
    al = np.where(left, a, L - a)
    b = L - al
    return b * xl * (L**2 - b**2 - xl**2) / (6.0 * L)


def static_unit_moment(x: np.ndarray, a: np.ndarray, L: float) -> np.ndarray:
    """Sagging bending moment [N m per N] at x for a unit load at a; M = -EI u_xx."""
    x, a = np.broadcast_arrays(np.asarray(x, float), np.asarray(a, float))
    return np.where(x <= a, (L - a) * x / L, a * (L - x) / L)


def modes_for_gaussian(beam: Beam, beta: float, tol: float = 1e-10) -> int:
    """Number of modes after which the Gaussian load factor times n^-2 falls below tol."""
    n = 1
    while math.exp(-((n * math.pi * beta / beam.length) ** 2) / 4.0) / n**2 > tol and n < 4000:
        n += 1
    return n


class ModalModel:
    """Modal solution at fixed observation points, evaluated for any batch of EI values.

    Parameters
    ----------
    beam, vehicle : the girder (EI is ignored: it is the argument of `predict`) and the axles.
    x, t : array (P,), observation positions [m] and times [s].
    a_u, a_xx : array (P,) or float, each observation is a_u * u + a_xx * u_xx; deflection rows use
        (1, 0), strain rows (0, -y).
    n_modes : modes carried in the dynamic correction (point loads) or in the whole sum (Gaussian).
    beta : None for exact point loads, else the Gaussian delta width [m].
    """

    def __init__(
        self,
        beam: Beam,
        vehicle: Vehicle,
        x: np.ndarray,
        t: np.ndarray,
        a_u: np.ndarray | float = 1.0,
        a_xx: np.ndarray | float = 0.0,
        *,
        n_modes: int = 10,
        beta: float | None = None,
    ):
        self.beam, self.vehicle, self.beta = beam, vehicle, beta
        x = np.asarray(x, float).ravel()
        t = np.asarray(t, float).ravel()
        self.x, self.t = x, t
        P = x.size
        a_u = np.broadcast_to(np.asarray(a_u, float), (P,)).copy()
        a_xx = np.broadcast_to(np.asarray(a_xx, float), (P,)).copy()
        if beta is not None and n_modes < modes_for_gaussian(beam, beta, 1e-8):
            n_modes = modes_for_gaussian(beam, beta, 1e-8)
        self.n_modes = int(n_modes)
        L, mu, v = beam.length, beam.mass_per_length, vehicle.speed
        n = np.arange(1, self.n_modes + 1, dtype=float)
        self.k = n * math.pi / L  # (N,)
        self.Omega = self.k * v
        g = np.ones_like(n) if beta is None else np.exp(-((self.k * beta) ** 2) / 4.0)
        self.F = (2.0 / (mu * L)) * vehicle.loads[:, None] * g[None, :]  # (J, N)
        self.tau_e = L / v
        # observation weights of each mode: a_u phi_n + a_xx phi_n''  -> (N, P)
        s = np.sin(self.k[:, None] * x[None, :])
        self.shape = s * (a_u[None, :] - a_xx[None, :] * self.k[:, None] ** 2)
        tau = t[None, :] - vehicle.delays[:, None]  # (J, P)
        self.tau = tau
        self.inside = (tau >= 0.0) & (tau <= self.tau_e)
        self.after = tau > self.tau_e
        ang = self.Omega[None, :, None] * tau[:, None, :]  # (J, N, P)
        # EI-independent bases of the particular solution, already weighted by the mode shapes
        self.sin_basis = np.where(self.inside[:, None, :], np.sin(ang), 0.0) * self.shape[None]
        self.cos_basis = np.where(self.inside[:, None, :], np.cos(ang), 0.0) * self.shape[None]
        # transient terms only where they are non-zero: (indices, tau, shapes) per axle and state
        self.in_sets = [self._subset(self.inside[j], tau[j]) for j in range(tau.shape[0])]
        self.after_sets = [
            self._subset(self.after[j], tau[j] - self.tau_e) for j in range(tau.shape[0])
        ]
        # exact static part of point loads (EI * value), zero for Gaussian loads
        if beta is None:
            pos = np.clip(v * tau, 0.0, L)
            st = a_u[None, :] * static_unit_deflection(x[None, :], pos, L) - a_xx[
                None, :
            ] * static_unit_moment(x[None, :], pos, L)
            self.static_EI = np.sum(vehicle.loads[:, None] * st * self.inside, axis=0)  # (P,)
        else:
            self.static_EI = np.zeros(P)

    def _subset(self, mask: np.ndarray, tau: np.ndarray):
        idx = np.flatnonzero(mask)
        return idx, tau[idx], self.shape[:, idx]

    def _transient(self, coef: np.ndarray, lam1: np.ndarray, subset) -> np.ndarray:
        """sum_n shape_n(p) Re(coef_n exp(lam_n tau_p)) with lam_n = n^2 lam_1, shape (W, Q).

        exp(lam_n tau) = z^(n^2) with z = exp(lam_1 tau): built by the recurrence
        z^(n^2) = z^((n-1)^2) z^(2n-1), two complex products per mode instead of an exp.
        """
        idx, tau, shape = subset
        z = np.exp(lam1[:, None] * tau[None, :])  # (W, Q)
        z2 = z * z
        E = np.empty((lam1.size, self.n_modes, idx.size), dtype=complex)
        E[:, 0] = z
        odd = z
        for n in range(1, self.n_modes):
            odd = odd * z2
            E[:, n] = E[:, n - 1] * odd
        E *= shape[None]
        return np.matmul(coef[:, None, :], E)[:, 0, :].real

    def predict(self, EI: np.ndarray | float) -> np.ndarray:
        """Observations for each EI value.

        Parameters
        ----------
        EI : float or array (W,), flexural rigidity [N m^2].

        Returns
        -------
        array (W, P) (or (P,) for a scalar EI): a_u u + a_xx u_xx at the observation points.
        """
        scalar = np.ndim(EI) == 0
        EI = np.atleast_1d(np.asarray(EI, float))
        zeta = self.beam.damping_ratio
        omega = self.k[None, :] ** 2 * np.sqrt(EI[:, None] / self.beam.mass_per_length)  # (W, N)
        wd = omega * math.sqrt(1.0 - zeta**2)
        lam = -zeta * omega + 1j * wd  # (W, N)
        Om = self.Omega[None, :]
        te = self.tau_e
        sO, cO = np.sin(Om * te), np.cos(Om * te)
        e_te = np.exp(lam * te)
        out = self.static_EI[None, :] / EI[:, None]  # (W, P)
        for j in range(self.F.shape[0]):
            F = self.F[j][None, :]  # (1, N)
            c = F / (omega**2 - Om**2 + 2j * zeta * omega * Om)  # particular: Im(c e^{i Omega tau})
            cr, ci = c.real, c.imag
            coef_sin = cr - F / omega**2 if self.beta is None else cr  # minus the quasi-static part
            out += coef_sin @ self.sin_basis[j] + ci @ self.cos_basis[j]
            # homogeneous part from rest: Re(H) = -Im(c), Re(H lam) = -Omega Re(c)
            H = -ci + 1j * (Om * cr + zeta * omega * ci) / wd  # (W, N)
            idx = self.in_sets[j][0]
            if idx.size:
                out[:, idx] += self._transient(H, lam[:, 0], self.in_sets[j])
            # state when the axle leaves, then free vibration Re(K e^{lam (tau - te)})
            idx = self.after_sets[j][0]
            if idx.size:
                q_e = ci * cO + cr * sO + (H * e_te).real
                qd_e = Om * (cr * cO - ci * sO) + (H * lam * e_te).real
                K = q_e - 1j * (qd_e + zeta * omega * q_e) / wd
                out[:, idx] += self._transient(K, lam[:, 0], self.after_sets[j])
        return out[0] if scalar else out
