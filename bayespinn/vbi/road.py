"""ISO 8608 road roughness: a profile synthesised as a sum of cosines with random phases.

ISO 8608 describes a road's vertical profile r(x) by its one-sided displacement PSD
Gd(n) = Gd(n0) (n / n0)^-w [m^3], n the spatial frequency [cycles/m], n0 = 0.1 cycles/m, waviness
w = 2. The standard synthesis is r(x) = sum_i A_i cos(2 pi n_i x + phi_i) with A_i = sqrt(2 Gd(n_i) dn),
equally spaced n_i = i dn over the band ISO 8608 classifies (0.011 to 2.83 cycles/m) and phases phi_i
uniform on [0, 2 pi), so that var r = sum_i Gd(n_i) dn, the band's integral of Gd. Here dn = 1 / P with P
the profile's period (at least 409.6 m, well beyond approach + span), so the sum is evaluated exactly on a
uniform grid by an inverse FFT, and between grid points by a cubic spline (spacing 1 cm, about 35 points
per shortest wavelength: interpolation error below 1e-6 of the amplitude). The elevation r is positive
upward, so a vehicle's contact point sits at beam deflection minus r (deflection positive downward).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from ..errors import InputError

#: ISO 8608 reference spatial frequency [cycles/m] and waviness
N0 = 0.1
WAVINESS = 2.0
#: the band ISO 8608 classifies roads over [cycles/m]
N_MIN, N_MAX = 0.011, 2.83
#: grid spacing of the synthesised profile [m] and its shortest period [m]
DX = 0.0125
MIN_PERIOD = 409.6


def iso8608_psd(n: np.ndarray, gd0: float, waviness: float = WAVINESS) -> np.ndarray:
    """Gd(n) = gd0 (n / n0)^-w [m^3] at spatial frequencies n [cycles/m]."""
    return gd0 * (np.asarray(n, float) / N0) ** (-waviness)


@dataclass(frozen=True)
class RoadProfile:
    """A road elevation r(x) [m] (positive up) over [x_start, x_start + period), x in the span's
    coordinate (the span is [0, L]; the approach lies at x < 0)."""

    x_start: float
    grid: np.ndarray  # elevation on x_start + DX * arange(N)
    spline: CubicSpline | None

    def elevation(self, x: np.ndarray) -> np.ndarray:
        """r(x) [m]."""
        if self.spline is None:
            return np.zeros(np.shape(x))
        return self.spline(np.asarray(x, float) - self.x_start)

    def slope(self, x: np.ndarray) -> np.ndarray:
        """dr/dx [-]."""
        if self.spline is None:
            return np.zeros(np.shape(x))
        return self.spline(np.asarray(x, float) - self.x_start, 1)

    @property
    def is_flat(self) -> bool:
        """A smooth road (roughness 0)."""
        return self.spline is None


def flat_road() -> RoadProfile:
    """r = 0 everywhere."""
    return RoadProfile(0.0, np.zeros(1), None)


def _period(length: float) -> tuple[float, int]:
    n = int(2 ** math.ceil(math.log2(max(MIN_PERIOD, 2.0 * length) / DX)))
    return n * DX, n


def from_components(
    x_start: float, length: float, index: np.ndarray, amplitude: np.ndarray, phase: np.ndarray
) -> RoadProfile:
    """The profile sum_k amplitude_k cos(2 pi (index_k / P) (x - x_start) + phase_k), P the period
    chosen for `length` (`_period`); `index` are integer multiples of 1 / P."""
    P, N = _period(length)
    spec = np.zeros(N // 2 + 1, complex)
    idx = np.asarray(index, int)
    if idx.size and (idx.min() < 1 or idx.max() >= N // 2):
        raise InputError("road components", [int(idx.min()), int(idx.max())], f"in [1, {N // 2})")
    spec[idx] = 0.5 * N * np.asarray(amplitude, float) * np.exp(1j * np.asarray(phase, float))
    grid = np.fft.irfft(spec, n=N)
    # periodic extension by one point so the spline covers the whole period smoothly
    xs = DX * np.arange(N + 1)
    spline = CubicSpline(xs, np.append(grid, grid[0]), bc_type="periodic")
    return RoadProfile(float(x_start), grid, spline)


def iso8608_road(
    gd0: float,
    x_start: float,
    length: float,
    seed: np.random.SeedSequence | int,
    n_min: float = N_MIN,
    n_max: float = N_MAX,
) -> RoadProfile:
    """A random ISO 8608 profile with Gd(n0) = gd0 [m^3] covering [x_start, x_start + length] [m]; the
    phases from `seed`. gd0 = 0 gives the flat road."""
    if not math.isfinite(gd0) or gd0 < 0:
        raise InputError("road.roughness", gd0, "Gd(n0) in m^3 >= 0")
    if gd0 == 0.0:
        return flat_road()
    P, _ = _period(length)
    dn = 1.0 / P
    index = np.arange(math.ceil(n_min / dn), math.floor(n_max / dn) + 1)
    n = index * dn
    amp = np.sqrt(2.0 * iso8608_psd(n, gd0) * dn)
    phase = np.random.default_rng(seed).uniform(0.0, 2.0 * math.pi, index.size)
    return from_components(x_start, length, index, amp, phase)


def band_variance(gd0: float, n_min: float = N_MIN, n_max: float = N_MAX) -> float:
    """The integral of Gd over [n_min, n_max] for w = 2: gd0 n0^2 (1/n_min - 1/n_max) [m^2]."""
    return gd0 * N0**2 * (1.0 / n_min - 1.0 / n_max)
