"""Real girders: segment-wise EI, rotational springs at the bearings, Hermite beam elements.

A `Girder` has its flexural rigidity piecewise constant over n equal segments counted from the left
support, and a rotational spring of stiffness k [N m/rad] at each support (0 = pin, `math.inf` =
clamped); the deflection is zero at both supports. `GirderFE` discretises it with cubic-Hermite
Euler-Bernoulli elements (nodal w and theta, exact element stiffness with the element's EI, consistent
mass). The element count is rounded up to a multiple of the segment count, so segment edges fall on
nodes and the stiffness is affine in the parameters,

    K(theta) = sum_s EI_s K_s + k_l e_l e_l^T + k_r e_r e_r^T,

with e_l, e_r the support rotation dofs (a clamped end has its rotation dof removed instead). The
pieces (`segment_stiffness`, `M`, `spring_dofs`, `stiffness`, `rows`) are what the reduced modal
surrogate (`fe_modal`) is built from. A point load at a is distributed to its element's nodes by the
shape functions (the consistent nodal load, `rows(a)`), and responses anywhere are read back with the
same shape functions; the element containing x is min(floor(x / h), n - 1) everywhere, so an
observation at a node takes its right-hand element, in the FE solve and in the surrogate alike.

Time integration (`GirderFE.solve`) is Newmark's average-acceleration rule, as in `fem.py`, with modal
damping (the girder's zeta on every mode).

Measured (tests/test_girder.py):

* statics: nodal values are exact (midspan point load: P L^3/48, /192 and 7 P L^3/768 EI to 1e-9,
  pinned, clamped, propped); between nodes the FE field is the cubic interpolant of exact nodal
  values, so a uniform load's deflection at element midpoints is off by exactly q h^4 / (384 EI)
  (order 4) and the deflection under a point load between nodes by P xi^3 (1 - xi)^3 h^3 / (3 EI)
  (order 3); a two-segment girder matches the virtual-work closed form to 1e-9;
* natural frequencies against the closed forms (beta L) for pinned, clamped-clamped and
  clamped-pinned beams: observed order of the error under mesh halving 3.90-4.00 on the first three
  modes (6 -> 12 -> 24 elements), i.e. h^4 for consistent mass; relative error at the default 96
  elements at most 1.2e-7 (mode 3, clamped), about 5e-8 of it eigensolver rounding;
* the uniform pinned girder reproduces `fem.FEBeam` (same mesh and steps) to 5e-10 relative RMS and
  the closed-form `ModalModel` to 8.3e-5 for the Exeter deflection case at 12 000 steps (Newmark's
  time error); one such crossing (96 elements, 12 000 steps) takes about 0.4 s.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
from scipy.linalg.lapack import dpotrf, dpotrs

from ..config import Beam, Vehicle, _check_number
from ..errors import InputError
from ..threads import one_blas_thread
from .hermite import _element_matrices, element_of, hermite


def _as_list(name: str, value: Any) -> list:
    """A tuple, list or 1-d array as a list; anything else is an InputError."""
    if isinstance(value, np.ndarray):
        return list(value.ravel())
    if isinstance(value, list | tuple):
        return list(value)
    raise InputError(name, value, "a sequence of numbers")


@dataclass(frozen=True)
class Girder:
    """A girder with piecewise-constant EI and rotational springs at its two supports.

    Attributes
    ----------
    length : float, span L [m]
    EI : tuple of float, flexural rigidity of each of the n equal segments, left to right [N m^2];
        one value is a uniform girder (a bare number is accepted and stored as a 1-tuple)
    mass_per_length : float, mu [kg/m] (uniform)
    section_depth : float, overall depth [m]; the flange fibres sit at y = -depth/2, +depth/2
    damping_ratio : float, modal damping ratio zeta [-] in [0, 1)
    rotational_stiffness : (float, float), bearing springs (left, right) [N m/rad]; 0 is a pin,
        `math.inf` a clamped end
    """

    length: float
    EI: tuple[float, ...]
    mass_per_length: float
    section_depth: float
    damping_ratio: float = 0.0
    rotational_stiffness: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        for name in ("length", "mass_per_length", "section_depth"):
            object.__setattr__(
                self, name, _check_number(f"beam.{name}", getattr(self, name), positive=True)
            )
        raw = self.EI
        if isinstance(raw, int | float | np.integer | np.floating) and not isinstance(raw, bool):
            raw = (raw,)
        values = _as_list("beam.EI", raw)
        if not values:
            raise InputError("beam.EI", raw, "at least one segment value")
        ei = tuple(_check_number(f"beam.EI[{i}]", v, positive=True) for i, v in enumerate(values))
        object.__setattr__(self, "EI", ei)
        z = _check_number("beam.damping_ratio", self.damping_ratio, nonneg=True)
        if z >= 1:
            raise InputError("beam.damping_ratio", self.damping_ratio, "a number in [0, 1)")
        object.__setattr__(self, "damping_ratio", z)
        ks = _as_list("beam.rotational_stiffness", self.rotational_stiffness)
        if len(ks) != 2:
            raise InputError(
                "beam.rotational_stiffness", self.rotational_stiffness, "two values (left, right)"
            )
        out = []
        for i, k in enumerate(ks):
            name = f"beam.rotational_stiffness[{i}]"
            if isinstance(k, bool) or not isinstance(k, int | float | np.integer | np.floating):
                raise InputError(name, k, "a number >= 0 N m/rad, or inf (clamped)")
            kf = float(k)
            if math.isnan(kf) or kf < 0:
                raise InputError(name, k, "a number >= 0 N m/rad, or inf (clamped)")
            out.append(kf)
        object.__setattr__(self, "rotational_stiffness", (out[0], out[1]))

    @property
    def n_segments(self) -> int:
        """Number of equal EI segments."""
        return len(self.EI)

    @property
    def clamped(self) -> tuple[bool, bool]:
        """(left, right): whether each end is clamped (infinite rotational stiffness)."""
        return tuple(math.isinf(k) for k in self.rotational_stiffness)  # type: ignore[return-value]

    def segment_edges(self) -> np.ndarray:
        """Segment boundaries [m], shape (n_segments + 1,), from 0 to L."""
        return np.linspace(0.0, self.length, self.n_segments + 1)

    def segment_of(self, x: np.ndarray | float) -> np.ndarray:
        """Index of the segment containing x (an edge belongs to the segment on its right; L to the last)."""
        x = np.asarray(x, float)
        s = np.floor(x / self.length * self.n_segments).astype(int)
        return np.clip(s, 0, self.n_segments - 1)

    def ei_at(self, x: np.ndarray | float) -> np.ndarray:
        """EI [N m^2] at positions x [m] (an edge takes the segment on its right)."""
        return np.asarray(self.EI, float)[self.segment_of(x)]

    @classmethod
    def from_beam(
        cls,
        beam: Beam,
        EI: Sequence[float] | float | None = None,
        rotational_stiffness: tuple[float, float] = (0.0, 0.0),
    ) -> Girder:
        """A girder with the geometry, mass and damping of a config `Beam`.

        Parameters
        ----------
        beam : the configured (uniform, pinned) beam.
        EI : segment values [N m^2]; None keeps the beam's uniform EI.
        rotational_stiffness : bearing springs (left, right) [N m/rad].
        """
        return cls(
            length=beam.length,
            EI=(beam.EI,) if EI is None else EI,  # type: ignore[arg-type]
            mass_per_length=beam.mass_per_length,
            section_depth=beam.section_depth,
            damping_ratio=beam.damping_ratio,
            rotational_stiffness=rotational_stiffness,
        )


def _check_elements(n_elements: Any, n_segments: int) -> int:
    if isinstance(n_elements, bool) or not isinstance(n_elements, int | np.integer):
        raise InputError("fe.n_elements", n_elements, "an integer >= 2")
    if n_elements < 2:
        raise InputError("fe.n_elements", n_elements, "an integer >= 2")
    return int(-(-int(n_elements) // n_segments) * n_segments)


class GirderFE:
    """Assembled Hermite-element model of a `Girder`.

    Parameters
    ----------
    girder : the girder.
    n_elements : element count, rounded up to a multiple of the segment count (default 96).

    Attributes
    ----------
    n_elements, h : element count and length [m].
    free : indices of the free dofs in the full numbering (2 i = w_i, 2 i + 1 = theta_i); w at both
        supports is removed, and so is the rotation of a clamped end.
    spring_dofs : (left, right) free-dof index of each support rotation, None where clamped.
    segment_stiffness : array (S, nf, nf), K_s: the stiffness of segment s with unit EI.
    M, K, C : mass, stiffness (the girder's own EI and springs) and modal damping matrices (nf, nf).
    """

    @one_blas_thread
    def __init__(self, girder: Girder, n_elements: int = 96):
        if not isinstance(girder, Girder):
            raise InputError("girder", girder, "a Girder")
        self.girder = girder
        S = girder.n_segments
        ne = _check_elements(n_elements, S)
        self.n_elements = ne
        self.h = h = girder.length / ne
        k, m = _element_matrices(h)
        nd = 2 * (ne + 1)
        self.ndof_full = nd
        per = ne // S
        Ks = np.zeros((S, nd, nd))
        M = np.zeros((nd, nd))
        for e in range(ne):
            s = slice(2 * e, 2 * e + 4)
            Ks[e // per, s, s] += k
            M[s, s] += m
        removed = [0, 2 * ne]
        cl, cr = girder.clamped
        if cl:
            removed.append(1)
        if cr:
            removed.append(2 * ne + 1)
        self.free = np.setdiff1d(np.arange(nd), removed)
        #: full dof -> free dof index, -1 where removed
        self.dof_map = np.full(nd, -1)
        self.dof_map[self.free] = np.arange(self.free.size)
        self.ndof = int(self.free.size)
        ix = np.ix_(self.free, self.free)
        self.segment_stiffness = np.ascontiguousarray(Ks[:, ix[0], ix[1]])
        self.M = girder.mass_per_length * M[ix]
        self.spring_dofs = (
            None if cl else int(self.dof_map[1]),
            None if cr else int(self.dof_map[2 * ne + 1]),
        )
        self.K = self.stiffness(girder.EI, girder.rotational_stiffness)
        self.C = self._modal_damping(girder.damping_ratio)

    # ---- assembly pieces ------------------------------------------------------------------------

    def stiffness(
        self, EI: Sequence[float] | np.ndarray, springs: Sequence[float] = (0.0, 0.0)
    ) -> np.ndarray:
        """K(theta) = sum_s EI_s K_s + k_l e_l e_l^T + k_r e_r e_r^T on the free dofs, (nf, nf).

        Springs at clamped ends (removed dofs) are ignored; elsewhere they must be finite.
        """
        EI = np.asarray(EI, float)
        if EI.shape != (self.girder.n_segments,):
            raise InputError("EI", EI.tolist(), f"{self.girder.n_segments} segment values")
        K = np.tensordot(EI, self.segment_stiffness, axes=1)
        for d, k in zip(self.spring_dofs, springs, strict=True):
            if d is not None:
                if not math.isfinite(k):
                    raise InputError(
                        "rotational_stiffness", k, "a finite spring at a free rotation"
                    )
                K[d, d] += k
        return K

    def rows(
        self,
        x: np.ndarray | float,
        a_u: np.ndarray | float = 1.0,
        a_xx: np.ndarray | float = 0.0,
        a_x: np.ndarray | float = 0.0,
        a_xxx: np.ndarray | float = 0.0,
    ) -> sp.csr_matrix:
        """Sparse (P, nf) rows r_p with r_p . U = a_u u + a_x u_x + a_xx u_xx + a_xxx u_xxx at x_p.

        With a_u = 1 (and the rest 0) a row is also the consistent nodal load vector of a unit point
        load at x_p. Removed dofs carry zero displacement and are dropped.
        """
        x = np.atleast_1d(np.asarray(x, float)).ravel()
        P = x.size
        e, xi = element_of(x, self.h, self.n_elements)
        vals = np.zeros((P, 4))
        for d, a in enumerate((a_u, a_x, a_xx, a_xxx)):
            a = np.broadcast_to(np.asarray(a, float), (P,))
            if np.any(a != 0.0):
                vals += a[:, None] * hermite(xi, self.h, d).T
        cols = self.dof_map[2 * e[:, None] + np.arange(4)[None, :]]
        keep = cols >= 0
        r = np.broadcast_to(np.arange(P)[:, None], (P, 4))
        return sp.csr_matrix((vals[keep], (r[keep], cols[keep])), shape=(P, self.ndof))

    def point_load(self, a: float, P: float = 1.0) -> np.ndarray:
        """Consistent free-dof load vector [N, N m] of a point load P [N] at a [m] in [0, L]."""
        return P * np.asarray(self.rows([a]).todense()).ravel()

    def load_vector(self, vehicle: Vehicle, t: float, load_factor: float = 1.0) -> np.ndarray:
        """Consistent free-dof load vector of the axles on the span at time t [s]."""
        F = np.zeros(self.ndof)
        L = self.girder.length
        for P, d in zip(vehicle.loads, vehicle.delays, strict=True):
            a = vehicle.speed * (t - d)
            if 0.0 <= a <= L:
                F += load_factor * P * np.asarray(self.rows([a]).todense()).ravel()
        return F

    def full(self, U: np.ndarray) -> np.ndarray:
        """Free-dof vectors (..., nf) to the full numbering (..., 2 (n + 1)), zeros where removed."""
        U = np.asarray(U, float)
        out = np.zeros(U.shape[:-1] + (self.ndof_full,))
        out[..., self.free] = U
        return out

    # ---- analyses ---------------------------------------------------------------------------------

    @one_blas_thread
    def static(self, load_vector: np.ndarray) -> np.ndarray:
        """Static displacements K^-1 F on the free dofs; F shaped (nf,) or (nf, m)."""
        return sla.solve(self.K, np.asarray(load_vector, float), assume_a="pos")

    @one_blas_thread
    def eigen(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """The n lowest natural circular frequencies [rad/s] (n,) and mass-normalised modes (nf, n).

        Each mode's sign makes its largest deflection (w dof) positive.
        """
        if isinstance(n, bool) or not isinstance(n, int | np.integer) or not 1 <= n <= self.ndof:
            raise InputError("n", n, f"an integer in [1, {self.ndof}]")
        w2, phi = sla.eigh(self.K, self.M, subset_by_index=[0, int(n) - 1])
        w_rows = (self.free % 2) == 0
        big = np.argmax(np.abs(phi[w_rows]), axis=0)
        sign = np.sign(phi[w_rows][big, np.arange(phi.shape[1])])
        return np.sqrt(w2), phi * np.where(sign == 0, 1.0, sign)

    def _modal_damping(self, zeta: float) -> np.ndarray:
        if zeta == 0.0:
            return np.zeros_like(self.K)
        w2, phi = sla.eigh(self.K, self.M)
        Mphi = self.M @ phi
        return Mphi @ np.diag(2 * zeta * np.sqrt(w2)) @ Mphi.T

    def solve(
        self, vehicle: Vehicle, t_end: float, n_steps: int, load_factor: float = 1.0
    ) -> GirderResponse:
        """Integrate a crossing from rest over [0, t_end] [s], n_steps Newmark average-acceleration steps.

        load_factor multiplies every axle load.
        """
        if not isinstance(vehicle, Vehicle):
            raise InputError("vehicle", vehicle, "a Vehicle")
        t_end = _check_number("t_end", t_end, positive=True)
        if isinstance(n_steps, bool) or not isinstance(n_steps, int | np.integer) or n_steps < 2:
            raise InputError("n_steps", n_steps, "an integer >= 2")
        lf = _check_number("load_factor", load_factor, positive=True)
        n = int(n_steps)
        times = np.arange(n + 1) * (t_end / n)
        L = self.girder.length

        def block(i0: int, i1: int) -> np.ndarray:
            """Load vectors of steps i0..i1-1, (i1 - i0, nf)."""
            t = times[i0:i1]
            F = np.zeros((t.size, self.ndof))
            for P, d in zip(vehicle.loads, vehicle.delays, strict=True):
                a = vehicle.speed * (t - d)
                on = np.flatnonzero((a >= 0.0) & (a <= L))
                if on.size:
                    R = self.rows(a[on]).tocoo()
                    np.add.at(F, (on[R.row], R.col), lf * P * R.data)
            return F

        return self._newmark(block, t_end, n)

    @one_blas_thread
    def solve_forced(self, force, t_end: float, n: int) -> GirderResponse:
        """Integrate from rest under force(t) -> free-dof load vector, n Newmark steps over [0, t_end]."""
        dt = t_end / n

        def block(i0: int, i1: int) -> np.ndarray:
            return np.array([force(i * dt) for i in range(i0, i1)]).reshape(i1 - i0, self.ndof)

        return self._newmark(block, t_end, n)

    @one_blas_thread
    def _newmark(self, block, t_end: float, n: int) -> GirderResponse:
        """Newmark average acceleration from rest; block(i0, i1) gives the load vectors of steps i0..i1-1."""
        dt = t_end / n
        K, M, C = self.K, self.M, self.C
        a0, a1, a2 = 4.0 / dt**2, 2.0 / dt, 4.0 / dt  # 1/(beta dt^2), gamma/(beta dt), 1/(beta dt)
        chol, info = dpotrf(K + a0 * M + a1 * C, lower=0)
        if info != 0:
            raise InputError("girder", self.girder, "a positive definite stiffness")
        nf = K.shape[0]
        U = np.zeros((n + 1, nf))
        V = np.zeros((n + 1, nf))
        damped = bool(np.any(C))
        chunk = 2048
        F = block(0, min(chunk, n + 1))
        A = sla.solve(M, F[0], assume_a="pos")  # from rest: M A0 = F(0)
        for i in range(n):
            k = (i + 1) % chunk
            if k == 0:
                F = block(i + 1, min(i + 1 + chunk, n + 1))
            rhs = F[k] + M @ (a0 * U[i] + a2 * V[i] + A)
            if damped:
                rhs += C @ (a1 * U[i] + V[i])
            u, _ = dpotrs(chol, rhs, lower=0)
            U[i + 1] = u
            A_new = a0 * (u - U[i]) - a2 * V[i] - A
            V[i + 1] = V[i] + 0.5 * dt * (A + A_new)
            A = A_new
        return GirderResponse(self, dt, U, V)


@dataclass
class GirderResponse:
    """Free-dof displacement and velocity histories; `sample` interpolates them anywhere."""

    fe: GirderFE
    dt: float
    U: np.ndarray  # (n_steps + 1, nf)
    V: np.ndarray

    def sample(
        self,
        x: np.ndarray,
        t: np.ndarray,
        a_u: np.ndarray | float = 1.0,
        a_xx: np.ndarray | float = 0.0,
    ) -> np.ndarray:
        """a_u u + a_xx u_xx at points (x [m], t [s]); arrays of one shape P, result (P,).

        Shape functions in space, cubic Hermite interpolation of (u, u_t) in time, as `FEResponse`.
        """
        x = np.asarray(x, float).ravel()
        t = np.asarray(t, float).ravel()
        R = self.fe.rows(x, a_u, a_xx)  # (P, nf) sparse
        n = self.U.shape[0] - 1
        s = np.clip(t / self.dt, 0.0, n)
        k = np.minimum(s.astype(int), n - 1)
        r = s - k
        h00, h10 = 2 * r**3 - 3 * r**2 + 1, r**3 - 2 * r**2 + r
        h01, h11 = -2 * r**3 + 3 * r**2, r**3 - r**2
        coo = R.tocoo()
        p, d, v = coo.row, coo.col, coo.data
        vals = v * (
            h00[p] * self.U[k[p], d]
            + h10[p] * self.dt * self.V[k[p], d]
            + h01[p] * self.U[k[p] + 1, d]
            + h11[p] * self.dt * self.V[k[p] + 1, d]
        )
        return np.bincount(p, weights=vals, minlength=x.size)
