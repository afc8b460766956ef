"""Cubic-Hermite Euler-Bernoulli beam elements (`physics.girder`): the four shape functions and their
x-derivatives (`hermite`), the element holding a position and its local coordinate (`element_of`), and the
unit element stiffness and consistent mass. The girder's finite-element model assembles these, and the
reduced modal surrogate (`physics.fe_modal`) reads responses back with the same shape functions.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError


def hermite(xi: np.ndarray, h: float, deriv: int = 0) -> np.ndarray:
    """d^k/dx^k of the four Hermite shape functions (w_i, theta_i, w_j, theta_j) at local xi in [0, 1].

    Parameters
    ----------
    xi : array (P,), local coordinate (x - x_i) / h.
    h : element length [m].
    deriv : k in 0..3, the x-derivative order.

    Returns
    -------
    array (4, P).
    """
    xi = np.asarray(xi, float)
    one = np.ones_like(xi)
    if deriv == 0:
        rows = [
            1 - 3 * xi**2 + 2 * xi**3,
            h * (xi - 2 * xi**2 + xi**3),
            3 * xi**2 - 2 * xi**3,
            h * (xi**3 - xi**2),
        ]
    elif deriv == 1:
        rows = [
            (-6 * xi + 6 * xi**2) / h,
            1 - 4 * xi + 3 * xi**2,
            (6 * xi - 6 * xi**2) / h,
            3 * xi**2 - 2 * xi,
        ]
    elif deriv == 2:
        rows = [(-6 + 12 * xi) / h**2, (-4 + 6 * xi) / h, (6 - 12 * xi) / h**2, (-2 + 6 * xi) / h]
    elif deriv == 3:
        rows = [12 * one / h**3, 6 * one / h**2, -12 * one / h**3, 6 * one / h**2]
    else:
        raise InputError("deriv", deriv, "0, 1, 2 or 3")
    return np.stack(rows)


def element_of(x: np.ndarray, h: float, n_elements: int) -> tuple[np.ndarray, np.ndarray]:
    """(element index, local xi) of positions x [m]: e = min(floor(x / h), n - 1), clipped at 0."""
    x = np.asarray(x, float)
    e = np.clip(np.floor(x / h).astype(int), 0, n_elements - 1)
    return e, x / h - e


def _element_matrices(h: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit-EI element stiffness and unit-mu consistent mass of a Hermite element of length h."""
    k = (1.0 / h**3) * np.array(
        [
            [12, 6 * h, -12, 6 * h],
            [6 * h, 4 * h**2, -6 * h, 2 * h**2],
            [-12, -6 * h, 12, -6 * h],
            [6 * h, 2 * h**2, -6 * h, 4 * h**2],
        ]
    )
    m = (h / 420) * np.array(
        [
            [156, 22 * h, 54, -13 * h],
            [22 * h, 4 * h**2, 13 * h, -3 * h**2],
            [54, 13 * h, 156, -22 * h],
            [-13 * h, -3 * h**2, -22 * h, 4 * h**2],
        ]
    )
    return k, m
