"""The axle force's spectrum above the fluctuating-force law's basis, from the road and the suspension: a
band of further force basis functions (`forward.CrossingModel(band=...)`), common to the axles, reaching
the road's shortest wavelength, whose prior sds follow from ISO 8608 roughness seen through a sprung body.

Why. The fluctuating-force law's spectrum (an inertial squared exponential) falls off fast above its peak,
near the body's bounce, while a suspension passes the road's short wavelengths into the contact force with
a spectrum that stays up to the speed times the road's shortest wavelength. That content drives the
girder's modes in that range resonantly and rides on the quasi-static response, and a law without it reads
the response's timing (hence speed and EI) wrongly. A band over 0.5-1.6 times the first mode alone closed
under a quarter of that error on one crossing; carried to the road's reach, with every mode in it dynamic
in the basis responses (`basis_modes`), it removes most of it on three of the worst, not on all
(docs/methods.md, "The road's short wavelengths"). The reference carries it for a sprung vehicle with
fluctuating forces (`peak.terms`); with moving forces there is no body to pass the road's spectrum.

The prior. A body of mass m on a spring and damper (bounce angular frequency w_b, damping ratio z_b) over a
road r(x) driven at speed v: the contact force's dynamic part is m times the body's acceleration, whose
transfer from the road's height is w^2 T(w), T^2 = (w_b^4 + (2 z_b w_b w)^2) / ((w_b^2 - w^2)^2 +
(2 z_b w_b w)^2). ISO 8608 gives the road's one-sided displacement PSD Gd(n) = Gd(n0) (n / n0)^-2 (n0 = 0.1
cycles/m), so at speed v the height's one-sided PSD in time is Gd(n0) n0^2 v / f^2 [m^2/Hz], and the
relative force's (per unit static load) is w^4 T^2 Gd(n0) n0^2 v / (f^2 g^2). The Hilbert-space basis
wants the two-sided density in angular frequency of the kernel convention k(r) = (1/2pi) int S e^(i w r):
S = half the one-sided PSD per Hz. Its median takes Gd(n0) at the boundary of roads of classes A and B
(32e-6 m^3); the level is then inferred, `tail` on a log-normal prior (median 1, log-sd `TAIL_LOG_SD`, so
classes A to C within its 95 % range). Above v `ROAD_N_MAX` (ISO 8608's shortest wavelength, 0.35 m)
the law states nothing, so the band ends there.

A lorry's axles ride the same road, and once the approach's transient has died each one's force, as a
function of its own time on the span, is nearly the same history: the band is one set of weights shared
by the axles (its columns the axles' summed), each axle's force its load times it.
"""

from __future__ import annotations

import math

import numpy as np

from .forward import BOUNDARY_FACTOR

#: ISO 8608's reference spatial frequency [cycles/m] and its band's upper end (wavelength 0.35 m)
ROAD_N0, ROAD_N_MAX = 0.1, 2.83
#: Gd(n0) at the boundary of road classes A and B [m^3] (ISO 8608: class A up to 32e-6, B to 128e-6)
BOUNDARY_GD0 = 32e-6
#: the band's level about that median: log-normal, log-sd (in sd, not variance)
TAIL_LOG_SD = 1.0
#: the band's reach: None, from the law's basis to the road's (v ROAD_N_MAX); or (lo, hi) in units of the
#: girder's first angular frequency at the EI prior's median (`studies/force_timing_check.py --band-range`)
BAND: tuple[float, float] | None = None
G = 9.81


def band_of(length: float, mu: float, EI: float, speed: float, n_basis: int) -> tuple[int, int]:
    """(first index, count) of the Hilbert-space basis functions (`forward.basis_frequencies` at the
    axle time on the span L / speed) beyond the n_basis functions the force law already has, up to the
    band's top (`top`: the road's reach, or `BAND` times the first mode's angular frequency at EI, when
    set); count 0 when none is left."""
    Lh = BOUNDARY_FACTOR * (length / speed) / 2.0
    per = math.pi / (2.0 * Lh)  # spacing of alpha_k = k per
    lo = n_basis + 1
    if BAND is not None:
        lo = max(lo, math.ceil(BAND[0] * mode_frequencies(length, mu, EI, 1)[0] / per))
    hi = math.floor(top(length, mu, EI, speed) / per)
    return (lo, max(0, hi - lo + 1))


def reach(speed: float) -> float:
    """The highest angular frequency [rad/s] of the road's force at `speed`: 2 pi v ROAD_N_MAX."""
    return 2.0 * math.pi * speed * ROAD_N_MAX


def mode_frequencies(length: float, mu: float, EI: float, n: int) -> np.ndarray:
    """The pinned girder's first n angular frequencies [rad/s] at EI."""
    return (math.pi * np.arange(1, n + 1) / length) ** 2 * math.sqrt(EI / mu)


def top(length: float, mu: float, EI: float, speed: float) -> float:
    """The band's highest angular frequency [rad/s]: the road's reach, or BAND[1] times the first mode's."""
    if BAND is None:
        return reach(speed)
    return BAND[1] * float(mode_frequencies(length, mu, EI, 1)[0])


def basis_modes(length: float, mu: float, EI: float, speed: float, n_modes: int) -> int:
    """Modes whose response to the force basis is integrated dynamically: those with an angular frequency
    (at EI) within the band's top, at least the first, at most n_modes. The others respond
    quasi-statically, which is exact well below their frequency."""
    w = mode_frequencies(length, mu, EI, n_modes)
    return int(min(n_modes, max(1, int(np.sum(w <= top(length, mu, EI, speed))))))


def relative_force_sd(alpha: np.ndarray, speed, fb, zb) -> np.ndarray:
    """sqrt of the two-sided spectral density S(alpha) (module docstring) of a sprung body's relative
    contact force on a road at the class A/B boundary, at angular frequencies alpha (W, m) [rad/s], for
    speed [m/s], bounce frequency fb [Hz] and damping ratio zb, each (W,) or a float; zero above the
    road band's reach v ROAD_N_MAX."""
    a = np.asarray(alpha, float)
    v, fb, zb = (
        np.broadcast_to(np.asarray(q, float), a.shape[:1])[:, None] for q in (speed, fb, zb)
    )
    wb = 2.0 * math.pi * fb
    f = a / (2.0 * math.pi)
    T2 = (wb**4 + (2 * zb * wb * a) ** 2) / ((wb**2 - a**2) ** 2 + (2 * zb * wb * a) ** 2)
    one_sided = a**4 * T2 * BOUNDARY_GD0 * ROAD_N0**2 * v / (f**2 * G**2)
    return np.where(f <= v * ROAD_N_MAX, np.sqrt(0.5 * one_sided), 0.0)
