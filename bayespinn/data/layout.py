"""Where and when the sensors read: the layout every simulator of measurements fills with values."""

from __future__ import annotations

import numpy as np

from ..config import Config
from .measurements import Measurements


def layout_over(cfg: Config, duration: float, rng: np.random.Generator) -> Measurements:
    """The sensors' readings over [0, duration] with values zero: for the deflection case
    `cfg.data.n_points` points uniform over [0, L] x [0, duration] drawn from rng; for the strain case
    each gauge of `cfg.sensors` sampled at `cfg.data.sample_rate`."""
    L = cfg.beam.length
    if cfg.case == "deflection":
        n = cfg.data.n_points
        x, t = rng.uniform(0.0, L, n), rng.uniform(0.0, duration, n)
        kind, y, sensor = np.full(n, "deflection"), np.full(n, np.nan), np.full(n, "")
    else:
        times = np.arange(0.0, duration + 1e-12, 1.0 / cfg.data.sample_rate)
        S = cfg.sensors
        x = np.concatenate([np.full(times.size, s.x) for s in S])
        t = np.tile(times, len(S))
        y = np.concatenate([np.full(times.size, s.y) for s in S])
        kind = np.full(x.size, "strain")
        sensor = np.concatenate([np.full(times.size, s.name) for s in S])
    z = np.zeros(x.size)
    return Measurements(x, t, z, kind.astype(str), y, sensor.astype(str), z.copy())
