"""Noise, SNR and seeded draws shared by every simulator of measurements (the finite-element truth in
`synthetic` and the vehicle-bridge simulator in `vbi`): sigma for an SNR, AR(1) noise along each sensor's
series, the true common axle-load factor, and named seed streams."""

from __future__ import annotations

import math
import zlib

import numpy as np

from ..config import _check_number
from ..errors import InputError
from .measurements import Measurements


def sigma_for_snr(value_true: np.ndarray, snr_db: float | None) -> float:
    """Noise standard deviation (units of the values) that gives snr_db over these samples."""
    if snr_db is None:
        return 0.0
    power = float(np.mean(np.asarray(value_true) ** 2))
    return float(np.sqrt(power / 10.0 ** (snr_db / 10.0)))


def realised_snr(value: np.ndarray, value_true: np.ndarray) -> float:
    """The SNR [dB] that a noisy file actually has."""
    noise = np.asarray(value) - np.asarray(value_true)
    return float(10.0 * np.log10(np.mean(np.asarray(value_true) ** 2) / np.mean(noise**2)))


LOAD_REL_SD_MAX = 0.2


def _stream(seed: int | np.random.SeedSequence, name: str) -> np.random.SeedSequence:
    """An independent named SeedSequence under a root seed (as `seeding.stream`, for a name that is
    not one of its registered streams)."""
    key = zlib.crc32(name.encode())
    if isinstance(seed, np.random.SeedSequence):
        return np.random.SeedSequence(seed.entropy, spawn_key=tuple(seed.spawn_key) + (key,))
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise InputError("seed", seed, "an integer >= 0 or a numpy SeedSequence")
    return np.random.SeedSequence(int(seed), spawn_key=(key,))


def check_load_rel_sd(load_rel_sd: float) -> float:
    """load_rel_sd as a float in [0, LOAD_REL_SD_MAX]; InputError('vehicle.load_rel_sd') otherwise."""
    v = _check_number("vehicle.load_rel_sd", load_rel_sd, nonneg=True)
    if v > LOAD_REL_SD_MAX:
        raise InputError("vehicle.load_rel_sd", load_rel_sd, f"a number in [0, {LOAD_REL_SD_MAX}]")
    return v


def draw_load_factor(load_rel_sd: float, seed: int | np.random.SeedSequence) -> float:
    """The true common factor on every axle load of one crossing: 1 + load_rel_sd z, z ~ N(0, 1),
    redrawn until positive (a normal truncated to > 0). Exactly 1.0 when load_rel_sd = 0.
    A function of the seed (its own "load_factor" stream, independent of the points and the noise)."""
    sd = check_load_rel_sd(load_rel_sd)
    r = np.random.default_rng(_stream(seed, "load_factor"))
    if sd == 0.0:
        return 1.0
    while True:
        lf = 1.0 + sd * float(r.standard_normal())
        if lf > 0.0:
            return lf


def ar1_noise(z: np.ndarray, layout: Measurements, phi: float) -> np.ndarray:
    """Unit-variance AR(1) noise from i.i.d. standard normals z: e_k = phi e_(k-1) + sqrt(1 - phi^2) z_k along
    each sensor's series in time order (strain gauges), or along all points in time order (scattered
    deflection points: one instrument read at increasing times). Stationary from the first sample."""
    if phi == 0.0:
        return z
    out = np.empty_like(z)
    keys = layout.sensor if np.any(layout.sensor != "") else np.full(len(z), "")
    c = math.sqrt(1.0 - phi * phi)
    for name in np.unique(keys):
        idx = np.flatnonzero(keys == name)
        idx = idx[np.argsort(layout.t[idx], kind="stable")]
        e = z[idx[0]]
        out[idx[0]] = e
        for i in idx[1:]:
            e = phi * e + c * z[i]
            out[i] = e
    return out
