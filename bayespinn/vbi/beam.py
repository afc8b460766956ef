"""The simulator's own girder: Euler-Bernoulli beam elements assembled in banded form.

Written apart from the analysis model (`bayespinn.physics`) so that data made here test it honestly.
Each node carries deflection w (positive down) and slope theta = dw/dx; an element's matrices are
integrated by 4-point Gauss-Legendre quadrature of the cubic Hermite interpolation (exact for the
polynomial degrees involved), not taken from closed-form tables. Segment-wise EI: the mesh puts a node
on every segment boundary, and each element takes its segment's EI. Supports: w = 0 at both ends and a
rotational spring k on each end slope (k = inf clamps it). Constrained degrees of freedom stay in the
vectors (so the band structure and indices are simple) with identity rows in every solve.

Damping is Rayleigh, C = a M + b K, with the damping ratio exact on the first two modes: a realistic
girder's damping that the analysis (the same ratio on every mode) does not describe exactly.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg as sla

from ..config import Beam
from ..errors import InputError

#: half bandwidth of the assembled matrices (two nodes of two dofs)
BW = 3

_GAUSS_X, _GAUSS_W = np.polynomial.legendre.leggauss(4)


def hermite(xi: np.ndarray, h: float, deriv: int = 0) -> np.ndarray:
    """Cubic Hermite basis on an element of length h at local xi in [0, 1]: shape (4, P) for the
    element dofs (w0, theta0, w1, theta1); deriv = 0, 1 or 2 gives w, dw/dx or d2w/dx2."""
    xi = np.atleast_1d(np.asarray(xi, float))
    one = np.ones_like(xi)
    if deriv == 0:
        rows = [
            (1 - xi) ** 2 * (1 + 2 * xi),
            h * xi * (1 - xi) ** 2,
            xi**2 * (3 - 2 * xi),
            h * xi**2 * (xi - 1),
        ]
    elif deriv == 1:
        rows = [
            6 * xi * (xi - 1) / h,
            (1 - xi) * (1 - 3 * xi),
            6 * xi * (1 - xi) / h,
            xi * (3 * xi - 2),
        ]
    elif deriv == 2:
        rows = [(12 * xi - 6) / h**2, (6 * xi - 4) / h, (6 - 12 * xi) / h**2, (6 * xi - 2) / h]
    else:
        raise ValueError("deriv must be 0, 1 or 2")
    return np.stack([r * one for r in rows])


def _element(h: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit-EI stiffness and unit-mass matrices (4, 4) of one element by Gauss quadrature."""
    xi = 0.5 * (_GAUSS_X + 1.0)
    w = 0.5 * h * _GAUSS_W
    N, B = hermite(xi, h, 0), hermite(xi, h, 2)
    return (B * w) @ B.T, (N * w) @ N.T


def to_banded(A: np.ndarray) -> np.ndarray:
    """Dense (n, n) -> LAPACK band storage (2 BW + 1, n) for `scipy.linalg.solve_banded`."""
    n = A.shape[0]
    ab = np.zeros((2 * BW + 1, n))
    for k in range(-BW, BW + 1):
        d = np.diagonal(A, k)
        if k >= 0:
            ab[BW - k, k:] = d
        else:
            ab[BW - k, : n + k] = d
    return ab


class SimBeam:
    """The assembled girder.

    Parameters
    ----------
    beam : the true girder (length, EI or EI per segment, mass, damping ratio, bearing springs).
    n_elements : at least this many elements, rounded up to a multiple of the number of segments.
    """

    def __init__(self, beam: Beam, n_elements: int = 120):
        if isinstance(n_elements, bool) or not isinstance(n_elements, int) or n_elements < 2:
            raise InputError("vbi n_elements", n_elements, "an integer >= 2")
        segs = np.asarray(beam.segments, float)
        per = math.ceil(n_elements / segs.size)
        ne = per * segs.size
        self.beam = beam
        self.length = beam.length
        self.n_elements = ne
        self.h = beam.length / ne
        self.ndof = 2 * (ne + 1)
        ke, me = _element(self.h)
        ei = np.repeat(segs, per)
        K = np.zeros((self.ndof, self.ndof))
        M = np.zeros((self.ndof, self.ndof))
        for e in range(ne):
            s = slice(2 * e, 2 * e + 4)
            K[s, s] += ei[e] * ke
            M[s, s] += beam.mass_per_length * me
        fixed = [0, self.ndof - 2]
        for dof, k in zip((1, self.ndof - 1), beam.rotational_stiffness, strict=True):
            if math.isinf(k):
                fixed.append(dof)
            else:
                K[dof, dof] += k
        self.fixed = np.array(sorted(fixed))
        self.free = np.ones(self.ndof, bool)
        self.free[self.fixed] = False
        for A in (K, M):
            A[self.fixed, :] = 0.0
            A[:, self.fixed] = 0.0
        self.K, self.M = K, M
        self.omega = self._lowest(2)
        z = beam.damping_ratio
        w1, w2 = self.omega
        self.rayleigh = (2 * z * w1 * w2 / (w1 + w2), 2 * z / (w1 + w2))
        self.C = self.rayleigh[0] * M + self.rayleigh[1] * K

    def _lowest(self, n: int) -> np.ndarray:
        f = self.free
        w2 = sla.eigh(
            self.K[np.ix_(f, f)],
            self.M[np.ix_(f, f)],
            eigvals_only=True,
            subset_by_index=[0, n - 1],
        )
        return np.sqrt(w2)

    def locate(self, x: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Element index and local coordinate xi in [0, 1] of positions x in [0, L]."""
        x = np.clip(np.atleast_1d(np.asarray(x, float)), 0.0, self.length)
        e = np.minimum((x / self.h).astype(int), self.n_elements - 1)
        return e, x / self.h - e

    def contact(self, x: float) -> tuple[int, np.ndarray, np.ndarray]:
        """First dof of the element under x, and the shape vectors of w and dw/dx there (constrained
        dofs zeroed, so a load over a support goes into the support)."""
        e, xi = self.locate(x)
        d0 = 2 * int(e[0])
        mask = self.free[d0 : d0 + 4]
        return d0, hermite(xi, self.h, 0)[:, 0] * mask, hermite(xi, self.h, 1)[:, 0] * mask

    def rows(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For positions x (P,): the element dofs (P, 4) and the basis rows of w and w_xx (P, 4)."""
        e, xi = self.locate(x)
        dofs = 2 * e[:, None] + np.arange(4)[None, :]
        return dofs, hermite(xi, self.h, 0).T, hermite(xi, self.h, 2).T
