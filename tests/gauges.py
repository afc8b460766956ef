"""The three sensors the crossing tests read: two strain gauges (6 m and 10 m, 0.4 m below the neutral axis)
and a deflection point at 13 m, each sampled over the same window."""

from __future__ import annotations

import numpy as np

SENSORS = [(6.0, 0.0, -0.4), (10.0, 0.0, -0.4), (13.0, 1.0, 0.0)]


def three_gauges(duration: float, rate: float):
    """Stacked rows (x, t, deflection weight, curvature weight) of the three sensors read at `rate` Hz."""
    t = np.arange(0.0, duration, 1 / rate)
    x = np.concatenate([np.full(t.size, a) for a, _, _ in SENSORS])
    a_u = np.concatenate([np.full(t.size, b) for _, b, _ in SENSORS])
    a_xx = np.concatenate([np.full(t.size, c) for _, _, c in SENSORS])
    return x, np.tile(t, len(SENSORS)), a_u, a_xx
