"""The girder's resonant response to force content the axle-force basis does not reach.

The fluctuating-force law (`likelihood`) describes each axle's dynamic force below about 5 Hz (its basis
stops there, and its responses carry the first mode alone). A lorry on a rough road also puts force into
the girder at its own frequencies, and the girder answers at them: measured on the crossings study with
every analysis parameter at its truth (`studies/force_law_check.py`), what that law leaves is the first
mode, coupled to the lorry's sprung bodies, and the second mode (four times the first frequency).

Each of the first `MODES` modes' coordinates therefore gets a zero-mean Gaussian-process term in time, the
response of a damped oscillator to broadband force: on the window from the first axle's entry to the end of
the recording (before the entry the girder is at rest), q_n(t) = sum_k w_k sin(a_k (t - t0)), w_k ~
N(0, d_k^2), with d_k^2 proportional to the oscillator's normalised power spectrum

    H(a) = (2 z w a)^2 / ((w^2 - a^2)^2 + (2 z w a)^2)        (1 at the resonance a = w),

scaled so that q_n's mean square over the window is (rho_n A_n)^2: A_n the static modal amplitude of the
lorry's whole weight at the antinode (2 sum P / (mu L w_n^2)), rho_n the inferred relative amplitude. Its
observations are q_n times the mode's shape at each sensor, sin(k_n x) (a_u - a_xx k_n^2). The mode's
frequency and damping: for the first, the girder's first mode coupled to each axle's sprung body
(`coupled_mode`) when the analysis carries the bodies, else the bare mode at the analysis' damping; for
the second, the bare second frequency and its own inferred damping ratio. The sines' frequencies are fixed
per crossing (spacing pi / window, within `BANDS` of the mode's frequency at the EI prior's median, below
the data's Nyquist frequency): a fixed basis, its weights' spectrum moving with the parameters.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: modes with a resonant term (0: none, the force law alone), and each one's band of basis frequencies about its frequency at the EI
#: prior's median (the first wide: a heavy lorry's suspensions move the coupled mode by up to a quarter
#: and damp it by up to 0.2; the second about its bare frequency)
MODES = 2
BANDS = ((0.3, 2.0), (0.5, 1.5))
#: the relative amplitude rho_n's prior: log-normal, median 5 % of the static modal amplitude, log-sd 1.5
#: (weak: 90 % of the prior between 0.4 % and 59 %)
AMPLITUDE_MEDIAN, AMPLITUDE_LOG_SD = 0.05, 1.5
#: their parameters' names: each mode's log relative amplitude, the second mode's log damping ratio
NAMES = ("log_q1", "log_q2", "log_z2")
#: damping ratios below this are taken at it: as z -> 0 the weights' sds tend to a finite limit (a line
#: spread over the basis frequencies about it), which this reaches to rounding; at 0 they would be 0 / 0
MIN_DAMPING = 1e-6
G = 9.81


def bare_frequency(n: int, length: float, mass_per_length: float, EI):
    """omega_n [rad/s] of the pinned uniform girder: (n pi / L)^2 sqrt(EI / mu), EI a float or array."""
    return (n * math.pi / length) ** 2 * np.sqrt(np.asarray(EI, float) / mass_per_length)


def coupled_mode(length, mass_per_length, loads, offsets, EI, zeta, fb, zb):
    """(omega [rad/s], damping ratio), arrays (W,), of the girder's first mode coupled to each axle's
    sprung body (mass P_j / g, bounce fb [Hz], damping ratio zb), the lorry centred on the span and frozen
    (the convective terms dropped): the complex eigenvalue of the (1 + J)-degree system nearest the bare
    first frequency. EI, zeta, fb, zb: arrays (W,) or floats."""
    EI, zeta, fb, zb = np.broadcast_arrays(
        *(np.atleast_1d(np.asarray(a, float)) for a in (EI, zeta, fb, zb))
    )
    L, mu = float(length), float(mass_per_length)
    W = EI.size
    w1 = bare_frequency(1, L, mu, EI)
    m = np.asarray(loads, float).ravel() / G
    off = np.asarray(offsets, float).ravel()
    x = L / 2 + float(np.max(off)) / 2 - off
    phi = np.where((x > 0) & (x < L), np.sin(math.pi * x / L), 0.0)
    J, n = m.size, m.size + 1
    M1 = mu * L / 2
    wb = 2 * math.pi * fb
    a = np.zeros((J, n))  # relative displacement of body j: a_j . (q, z_1 .. z_J)
    a[:, 0], a[np.arange(J), 1 + np.arange(J)] = -phi, 1.0
    outer = np.einsum("ji,jk->jik", a, a) * m[:, None, None]  # (J, n, n)
    K = np.zeros((W, n, n))
    C = np.zeros((W, n, n))
    K[:, 0, 0], C[:, 0, 0] = M1 * w1**2, 2 * zeta * w1 * M1
    K += (wb**2)[:, None, None] * outer.sum(0)[None]
    C += (2 * zb * wb)[:, None, None] * outer.sum(0)[None]
    minv = 1.0 / np.r_[M1, m]
    A = np.zeros((W, 2 * n, 2 * n))
    A[:, :n, n:] = np.eye(n)
    A[:, n:, :n] = -minv[None, :, None] * K
    A[:, n:, n:] = -minv[None, :, None] * C
    ev = np.linalg.eigvals(A)
    ev = np.where(ev.imag > 0, ev, np.inf)
    e = ev[np.arange(W), np.argmin(np.abs(np.abs(ev) - w1[:, None]), axis=1)]
    return np.abs(e), -e.real / np.abs(e)


def normalised_spectrum(a: np.ndarray, w: np.ndarray, z: np.ndarray) -> np.ndarray:
    """H(a) of the module docstring for frequencies a (K,) and oscillators w, z (W,): (W, K)."""
    w, z = w[:, None], z[:, None]
    c = (2 * z * w * a[None]) ** 2
    return c / ((w**2 - a[None] ** 2) ** 2 + c)


@dataclass
class Resonance:
    """One crossing's resonant terms: the fixed basis frequencies per mode and what scales them."""

    length: float
    mass_per_length: float
    loads: np.ndarray
    offsets: np.ndarray
    entry_time: float
    window: float
    freqs: tuple[np.ndarray, ...]

    @classmethod
    def build(cls, model, speed: float, entry_time: float, EI_median: float) -> Resonance:
        """For a crossing model (`forward.CrossingModel`) at its stated speed and entry time."""
        times = np.unique(model.t)
        dt = float(np.median(np.diff(times))) if times.size > 1 else 1.0
        window = max(float(times.max()) - entry_time, model.L / speed) + dt
        freqs = []
        for n, (lo, hi) in zip(range(1, MODES + 1), BANDS[:MODES], strict=True):
            w = float(bare_frequency(n, model.L, model.mu, EI_median))
            a = math.pi * np.arange(1, int(hi * w * window / math.pi) + 2) / window
            freqs.append(a[(a > lo * w) & (a < min(hi * w, math.pi / dt))])
        return cls(model.L, model.mu, model.loads, model.offsets, entry_time, window, tuple(freqs))

    @property
    def n_columns(self) -> int:
        return int(sum(f.size for f in self.freqs))

    def columns(self, model, t0: np.ndarray) -> np.ndarray:
        """The basis' observations at model's rows for entry times t0 (W,): (W, P, n_columns)."""
        t0 = np.atleast_1d(np.asarray(t0, float))
        tau = model.t[None, :] - t0[:, None]  # (W, P)
        inside = (tau >= 0) & (tau <= self.window)
        out = []
        for n, a in zip(range(1, MODES + 1), self.freqs, strict=True):
            k = n * math.pi / self.length
            shape = np.sin(k * model.x) * (model.a_u - model.a_xx * k * k)  # (P,)
            s = np.sin(tau[:, :, None] * a[None, None, :]) * (inside * shape[None])[:, :, None]
            out.append(s)
        return np.concatenate(out, axis=2)

    def sds(self, EI, zeta, q1, q2, z2, body=None) -> np.ndarray:
        """The weights' sds (W, n_columns) for EI, the analysis' damping, the relative amplitudes q1, q2,
        the second mode's damping z2 (arrays (W,)); body: (fb, zb) arrays when the analysis carries the
        lorry's sprung bodies (the first mode then coupled to them)."""
        EI = np.atleast_1d(np.asarray(EI, float))
        w1 = bare_frequency(1, self.length, self.mass_per_length, EI)
        if body is None:
            wc, zc = w1, np.broadcast_to(np.asarray(zeta, float), EI.shape)
        else:
            wc, zc = coupled_mode(
                self.length, self.mass_per_length, self.loads, self.offsets, EI, zeta, *body
            )
        weight = float(np.sum(self.loads))
        out = []
        for n, (w, z, q) in enumerate(((wc, zc, q1), (4 * w1, z2, q2)), start=1):
            a = self.freqs[n - 1]
            if a.size == 0:
                continue
            # an undamped mode: the normalised weights' limit as z -> 0 (finite), not 0 / 0
            z = np.maximum(np.broadcast_to(np.asarray(z, float), EI.shape), MIN_DAMPING)
            H = normalised_spectrum(a, w, z)
            wn = (n * n) * w1
            amp = (
                np.asarray(q, float)[:, None]
                * 2
                * weight
                / (self.mass_per_length * self.length * wn**2)[:, None]
            )
            out.append(amp * np.sqrt(2 * H / np.maximum(H.sum(1, keepdims=True), 1e-300)))
        return np.concatenate(out, axis=1) if out else np.zeros((EI.size, 0))
