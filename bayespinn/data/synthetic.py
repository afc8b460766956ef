"""Synthetic measurements for the two case studies, with white Gaussian noise at a given SNR (Eq. 17-18).

The truth comes from the converged finite-element reference with point loads (`physics.fem`).
SNR (dB) = 10 log10(mean(value_true^2) / sigma^2), over all samples of the file; `None` means clean.
"""

from __future__ import annotations

import numpy as np

from .. import seeding
from ..config import Config
from ..physics.fem import FESettings, fe_response
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


def sample_layout(cfg: Config, seed: int | np.random.SeedSequence) -> Measurements:
    """Where and when the sensors read, without values (value and value_true are zero).

    deflection: `cfg.data.n_points` points uniform over [0, L] x [0, T] (the paper's random 100);
    strain: each gauge of `cfg.sensors` sampled at `cfg.data.sample_rate` over [0, T].
    """
    L, T = cfg.beam.length, cfg.duration
    if cfg.case == "deflection":
        r = seeding.rng(seed, "points")
        n = cfg.data.n_points
        x, t = r.uniform(0.0, L, n), r.uniform(0.0, T, n)
        kind = np.full(n, "deflection")
        y = np.full(n, np.nan)
        sensor = np.full(n, "")
    else:
        times = np.arange(0.0, T + 1e-12, 1.0 / cfg.data.sample_rate)
        S = cfg.sensors
        x = np.concatenate([np.full(times.size, s.x) for s in S])
        t = np.tile(times, len(S))
        y = np.concatenate([np.full(times.size, s.y) for s in S])
        kind = np.full(x.size, "strain")
        sensor = np.concatenate([np.full(times.size, s.name) for s in S])
    z = np.zeros(x.size)
    return Measurements(x, t, z, kind.astype(str), y, sensor.astype(str), z.copy())


def true_values(cfg: Config, layout: Measurements, fe: FESettings | None = None) -> np.ndarray:
    """Noise-free values at the layout's points from the finite-element reference."""
    a_u, a_xx = layout.weights
    return fe_response(cfg.beam, cfg.vehicle, layout.x, layout.t, a_u, a_xx, fe)


def simulate(
    cfg: Config,
    snr_db: float | None,
    seed: int | np.random.SeedSequence = 0,
    fe: FESettings | None = None,
) -> Measurements:
    """A synthetic measurement set for `cfg.case` at `snr_db` (None: clean), a function of the seed."""
    layout = sample_layout(cfg, seed)
    vt = true_values(cfg, layout, fe)
    sigma = sigma_for_snr(vt, snr_db)
    noise = seeding.rng(seed, "noise").standard_normal(vt.size) * sigma
    return Measurements(layout.x, layout.t, vt + noise, layout.kind, layout.y, layout.sensor, vt)
