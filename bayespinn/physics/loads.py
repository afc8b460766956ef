"""Moving loads: where each axle is, and the Gaussian approximation of the Dirac delta (paper Eq. 5, 19-20)."""

from __future__ import annotations

import numpy as np

from ..config import Beam, Vehicle


def axle_positions(vehicle: Vehicle, t: np.ndarray) -> np.ndarray:
    """Position of each axle along the span [m] at times t [s]; shape (J, *t.shape).

    Positions outside [0, L] mean the axle is not on the span.
    """
    t = np.asarray(t, dtype=float)
    return vehicle.speed * (t[None, ...] - vehicle.delays.reshape((-1,) + (1,) * t.ndim))


def on_span(beam: Beam, vehicle: Vehicle, t: np.ndarray) -> np.ndarray:
    """Boolean (J, *t.shape): axle j is on the span at time t."""
    a = axle_positions(vehicle, t)
    return (a >= 0.0) & (a <= beam.length)


def gaussian_delta(s: np.ndarray, beta: float) -> np.ndarray:
    """Gaussian approximation of delta(s) with width beta [m] (Eq. 5): exp(-s^2/beta^2)/(beta sqrt(pi)) [1/m]."""
    s = np.asarray(s, dtype=float)
    return np.exp(-((s / beta) ** 2)) / (beta * np.sqrt(np.pi))


def distributed_load(
    beam: Beam, vehicle: Vehicle, x: np.ndarray, t: np.ndarray, beta: float
) -> np.ndarray:
    """Right-hand side of Eq. 21, sum_j p_j delta_beta(x - v (t - t_j)) [N/m], for axles on the span.

    An axle contributes only while it is on the span, so the load vanishes before the first axle
    enters and after the last one leaves, as it does for the point loads of the reference solutions.
    """
    x = np.asarray(x, dtype=float)
    a = axle_positions(vehicle, t)
    live = (a >= 0.0) & (a <= beam.length)
    p = vehicle.loads.reshape((-1,) + (1,) * np.ndim(t))
    return np.sum(p * live * gaussian_delta(x[None, ...] - a, beta), axis=0)


def quantity_weights(quantity: str) -> tuple[float, float]:
    """The (deflection, curvature) weights a predictor's modal model reads for `quantity`: what every
    predictor's `quantity` argument means (the fit check and the report call them alike)."""
    if quantity == "deflection":
        return (1.0, 0.0)
    if quantity in ("curvature", "moment"):
        return (0.0, 1.0)
    raise ValueError(f"quantity must be deflection, moment or curvature, got {quantity!r}")
