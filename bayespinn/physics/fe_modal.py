"""Reduced modal surrogate of a real girder, batched over theta = (EI per segment, springs, load factor).

The likelihood surrogate for a `girder.Girder` (piecewise-constant EI over S segments, rotational
springs at the bearings, axle loads times a common load factor): predictions at fixed observation
points for W parameter sets at once, consistent with the Hermite FE model `girder.GirderFE` (same
mesh, same shape functions). Mode-acceleration form, for each theta:

    y(t) = LF [ c^T K^-1 F(t)  +  sum_{n <= N} c^T phi_n (q_n(t) - f_n(t) / omega_n^2) ]

* Static part, exact for the FE model. On the pinned structure (w = 0 at the supports, rotations
  free) the girder is statically determinate, so its FE flexibility is exactly linear in 1 / EI_s:
  K_pin^-1 = sum_s F_s / EI_s, F_s = EI0_s^2 K0^-1 K_s K0^-1 (one reference inverse at set-up). The
  springs, a rank-2 term, enter by the Woodbury identity written with gamma = k / (1 + k e^T K_pin^-1 e),
  so that k = 0 (pin) and k = inf (clamped) are both regular. Per theta: (W, S) x (S, P) products.
  Against per-point FE solves: within 2e-8 of the largest value (the test allows 1e-7).
* Modes by Ritz reduction. K(theta) = sum_s EI_s K_s + k_l e_l e_l^T + k_r e_r e_r^T is affine, so
  it is projected once on an M-orthonormal basis: the template's first N + 2 modes, their first-order
  changes K0^-1 K_s phi_n with each segment's EI and, for inferred springs, the end-moment shapes
  K0^-1 e and K0^-1 M K0^-1 e; candidate directions with a residual below 1e-6 are dropped (r = 35
  for N = 10 and 5 segments). Per theta: one r x r symmetric eigenproblem (batched `numpy.linalg.eigh`).
* Modal coordinates, exact. The forcing of one unit axle, f_n(tau) = phi_n(v tau), is a cubic in
  time on each element (Hermite shape functions), so q'' + 2 zeta omega q' + omega^2 q = f is solved
  in closed form: on each element the particular solution sum_k a_k f^(k) / omega^(k+2) (a_k from
  (1 + 2 zeta u + u^2)^-1, exact for cubics) plus Re(H_i exp(s (tau - tau_i))); H_i is carried from
  rest across the node crossings (where the 2nd and 3rd derivatives of f jump) and into free
  vibration once the axle leaves. Axles are superposed with their delays. At the observation times
  the exponentials factor into exp(i omega_d t) (powers of one step on a uniform time grid) and
  per-element factors, gathered by one sparse product; with damping the decays are split into time
  blocks so that nothing overflows.

Measured (tests/test_girder.py; 100 elements, N = 10; relative RMS, against the RMS response):

* damaged Exeter girder (segment 4 of 5 at 70 %) against 20 000 Newmark steps of `GirderFE.solve`:
  bearings k = 2 EI / L: 5.1e-5 (deflection, 100 random points, 1 axle at 7.1 m/s), 4.1e-4 (strain,
  4 gauges at 200 Hz, the 4-axle truck), 5.2e-6 / 3.3e-4 (3 axles, alpha = v / (2 f1 L) = 0.1);
  clamped: 1.5e-6, 9.2e-6, 3.5e-7, 1.4e-5; bearings with zeta = 0.02, to 1.5 T: 2.0e-6. The
  differences are Newmark's time error: for the bearings' strain they fall to 1.5e-4 at 80 000 steps;
* uniform pinned girder against the closed-form `ModalModel`, to 1.3 T: deflection 2.5e-7
  (zeta = 0.02: 4.6e-8); strain 4.4e-4 at 96 elements, 1.7e-4 at 192: the FE curvature is linear in
  each element, so it is off while an axle is in a gauge's element (FE discretisation, as in `fem.py`);
* the reduced basis against every FE dof (exact FE modes), 16 draws with EI_s x exp(0.5 N(0,1)) and
  springs x exp(1.5 N(0,1)): at most 3.0e-7 (deflection), 3.5e-6 (strain); at most 1.1e-4 over 64
  draws with EI_s x exp(N(0,1)) and springs x exp(3 N(0,1));
* mode truncation (against 40 exact modes, bearings): N = 6: 2.3e-6 / 4.4e-5, N = 10: 3.0e-7 /
  1.6e-5 (deflection / strain);
* speed, one thread, 5 segments, springs inferred (theta of dimension 8), median of 60 batches:
  3200-5000 evaluations per second for W = 32 or 64, deflection (P = 100) or strain (P = 2676),
  over two runs with the machine's other core busy; set-up 0.02-0.05 s.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from ..config import Vehicle
from ..errors import InputError
from .girder import Girder, GirderFE, element_of, hermite

#: relative residual below which a candidate Ritz direction is dropped (see the module docstring)
RITZ_RTOL = 1e-6
#: exact reference modes carried beyond n_modes in the Ritz basis
RITZ_EXTRA_MODES = 2
#: damping exponents are kept below this within a time block (exp(200) is far from overflow)
_MAX_DECAY = 200.0


def _series(zeta: float) -> np.ndarray:
    """a_k with (1 + 2 zeta u + u^2)^-1 = sum_k a_k u^k: the particular solution of
    q'' + 2 zeta omega q' + omega^2 q = f for a cubic f is sum_k a_k f^(k) / omega^(k+2)."""
    return np.array([1.0, -2 * zeta, 4 * zeta**2 - 1.0, 4 * zeta - 8 * zeta**3])


def _extend_mass_orthonormal(
    V: np.ndarray, X: np.ndarray, M: np.ndarray, Lm: np.ndarray, rtol: float
) -> np.ndarray:
    """V (M-orthonormal) extended by the part of span(X) M-orthogonal to it.

    Block Gram-Schmidt against V (twice), then a pivoted QR in the M^(1/2) metric (M = Lm Lm^T) that
    drops directions whose residual is below rtol of the candidate's own M-norm.
    """
    X = X / np.sqrt(np.einsum("ij,ij->j", X, M @ X))
    for _ in range(2):
        X = X - V @ (V.T @ (M @ X))
    Q, R, _ = sla.qr(Lm.T @ X, mode="economic", pivoting=True)
    rank = int(np.sum(np.abs(np.diag(R)) > rtol))
    if rank == 0:
        return V
    new = sla.solve_triangular(Lm.T, Q[:, :rank], lower=False)
    for _ in range(2):
        new = new - V @ (V.T @ (M @ new))
    Lg = np.linalg.cholesky(new.T @ M @ new)
    new = sla.solve_triangular(Lg, new.T, lower=True).T
    return np.concatenate([V, new], axis=1)


def _uniform_step(t: np.ndarray) -> float | None:
    """The step of a sorted, uniformly spaced time array (to 1e-12 s), else None."""
    if t.size < 3:
        return None
    dt = (t[-1] - t[0]) / (t.size - 1)
    if dt <= 0 or np.max(np.abs(t - (t[0] + dt * np.arange(t.size)))) > 1e-12 * max(1.0, t[-1]):
        return None
    return float(dt)


class GirderModalModel:
    """Modal surrogate of a `Girder` crossing at fixed observation points, batched over parameters.

    Parameters
    ----------
    girder : template girder: length, mass, depth, damping and segment count; its EI (and its
        springs) is the reference point of the reduced basis; its springs are used as given when
        they are not inferred (math.inf clamps an end).
    vehicle : the axles (their loads are multiplied by the load factor of `predict`).
    x, t : array (P,), observation positions [m] in [0, L] and times [s] >= 0.
    a_u, a_xx : array (P,) or float; each observation is a_u u + a_xx u_xx (strain: a_u = 0, a_xx = -y).
    n_modes : modes in the dynamic correction (default 10).
    infer_springs : True when the bearing springs are parameters of `predict`.
    n_elements : FE elements (rounded up to a multiple of the segment count; default 96).
    basis : "ritz" (reduced basis: fast) or "full" (every FE dof, i.e. the exact FE modes: slow,
        for checks).
    """

    def __init__(
        self,
        girder: Girder,
        vehicle: Vehicle,
        x: np.ndarray,
        t: np.ndarray,
        a_u: np.ndarray | float = 1.0,
        a_xx: np.ndarray | float = 0.0,
        *,
        n_modes: int = 10,
        infer_springs: bool = False,
        n_elements: int = 96,
        basis: str = "ritz",
    ):
        if not isinstance(girder, Girder):
            raise InputError("girder", girder, "a Girder")
        if not isinstance(vehicle, Vehicle):
            raise InputError("vehicle", vehicle, "a Vehicle")
        if not isinstance(infer_springs, bool):
            raise InputError("infer_springs", infer_springs, "True or False")
        if basis not in ("ritz", "full"):
            raise InputError("basis", basis, "'ritz' or 'full'")
        if isinstance(n_modes, bool) or not isinstance(n_modes, int | np.integer) or n_modes < 1:
            raise InputError("n_modes", n_modes, "an integer >= 1")
        L = girder.length
        x, t, a_u, a_xx = self._check_points(x, t, a_u, a_xx, L)
        P = x.size
        self.girder, self.vehicle, self.infer_springs = girder, vehicle, infer_springs
        self.x, self.t, self.P = x, t, P
        self.S = girder.n_segments
        self.zeta = girder.damping_ratio
        self.template_springs = np.array(girder.rotational_stiffness, float)
        # pinned structure (both support rotations free): the static part, and the modes when the
        # springs are inferred; otherwise the modes use the template (clamped rotations removed)
        fe_pin = GirderFE(replace(girder, rotational_stiffness=(0.0, 0.0)), n_elements)
        fe = fe_pin if infer_springs else GirderFE(girder, n_elements)
        self.fe = fe
        ne, h = fe.n_elements, fe.h
        self.n_elements, self.h = ne, h
        v = vehicle.speed
        self.loads, self.delays = vehicle.loads, vehicle.delays
        self.tau_e = L / v
        self.Dt = h / v  # time for an axle to cross one element

        # distinct observation rows (x, a_u, a_xx) and distinct times
        rows_u, row_of = np.unique(np.stack([x, a_u, a_xx], axis=1), axis=0, return_inverse=True)
        self.row_of = row_of.ravel()
        self.U = rows_u.shape[0]
        t_u, time_of = np.unique(t, return_inverse=True)
        self.t_u, self.time_of, self.T = t_u, time_of.ravel(), t_u.size

        # axles at the observation times: element, local coordinate, on the span
        a_pj = v * (t[:, None] - self.delays[None, :])  # (P, J)
        on_pj = (a_pj >= 0.0) & (a_pj <= L)
        self._static_setup(fe_pin, rows_u, a_pj, on_pj)

        # ---- reduced basis and the theta-independent projections ------------------------------------
        if basis == "full":
            Lm = np.linalg.cholesky(fe.M)
            V = sla.solve_triangular(Lm, np.eye(fe.ndof), lower=True).T  # V^T M V = I
        else:
            V = self._ritz_basis(fe, int(n_modes))
        self.V, self.r = V, V.shape[1]
        self.n_modes = int(min(n_modes, self.r))
        self.Kr_seg = np.stack([V.T @ Ks @ V for Ks in fe.segment_stiffness])  # (S, r, r)
        self.spring_vecs = [None if d is None else V[d].copy() for d in fe.spring_dofs]
        C = fe.rows(rows_u[:, 0], rows_u[:, 1], rows_u[:, 2])  # (U, nf)
        self.CV = np.asarray(C @ V)  # (U, r)
        Vfull = np.zeros((fe.ndof_full, self.r))
        Vfull[fe.free] = V
        Ve = np.stack([Vfull[2 * np.arange(ne) + m] for m in range(4)], axis=1)  # (ne, 4, r)
        # jumps of d^k/dtau^k phi(v tau), k = 0..3, where the axle enters (0), crosses node i (i)
        # and leaves (ne): the particular solutions of neighbouring intervals differ by these
        start, end = (
            np.stack(
                [v**k * np.einsum("m,imr->ir", hermite(np.array(xi0), h, k), Ve) for k in range(4)],
                1,
            )
            for xi0 in (0.0, 1.0)
        )  # (ne, 4, r) each
        jump = np.zeros((ne + 1, 4, self.r))
        jump[:ne] -= start
        jump[1:] += end
        self.F_jump = jump.reshape((ne + 1) * 4, self.r)
        # particular-part rows R_k[t] = sum_j P_j [on] v^k phi^(k)(a_j(t)), k = 1..3
        a_tj = v * (t_u[:, None] - self.delays[None, :])  # (T, J)
        on_tj = (a_tj >= 0.0) & (a_tj <= L)
        e_tj, xi_tj = element_of(np.where(on_tj, a_tj, 0.0), h, ne)
        J = self.loads.size
        R = np.zeros((3, self.T, self.r))
        for k in (1, 2, 3):
            Nk = hermite(xi_tj.ravel(), h, k).T.reshape(self.T, J, 4)
            w = (self.loads[None, :, None] * on_tj[..., None] * v**k) * Nk
            R[k - 1] = np.einsum("tjm,tjmr->tr", w, Ve[e_tj])
        self.R = R.transpose(1, 0, 2).reshape(self.T, 3 * self.r)  # [R_1 R_2 R_3]
        # interval of each (t, j): element 0..ne-1 on the span, ne after it, ne + 1 before entry
        I_tj = np.where(on_tj, e_tj, np.where(a_tj > L, ne, ne + 1))
        self.S_hom = sp.csr_matrix(
            (
                np.broadcast_to(self.loads, (self.T, J)).ravel(),
                (np.repeat(np.arange(self.T), J), (I_tj + (ne + 2) * np.arange(J)).ravel()),
            ),
            shape=(self.T, J * (ne + 2)),
        )
        self.series = _series(self.zeta)
        self.t_step = _uniform_step(t_u)

    # ---- set-up ----------------------------------------------------------------------------------

    @staticmethod
    def _check_points(x: Any, t: Any, a_u: Any, a_xx: Any, L: float):
        try:
            x = np.asarray(x, float).ravel()
            t = np.asarray(t, float).ravel()
        except (TypeError, ValueError):
            raise InputError("x, t", (x, t), "arrays of numbers") from None
        if x.size == 0 or x.shape != t.shape:
            raise InputError("x, t", (x.shape, t.shape), "two non-empty arrays of one shape")
        if not np.all(np.isfinite(x)) or x.min() < 0 or x.max() > L:
            raise InputError("x", x.tolist(), f"positions in [0, {L}] m")
        if not np.all(np.isfinite(t)) or t.min() < 0:
            raise InputError("t", t.tolist(), "finite times >= 0 s")
        out = []
        for name, a in (("a_u", a_u), ("a_xx", a_xx)):
            try:
                a = np.broadcast_to(np.asarray(a, float), x.shape).copy()
            except (TypeError, ValueError):
                raise InputError(name, a, f"a number or an array ({x.size},)") from None
            if not np.all(np.isfinite(a)):
                raise InputError(name, a.tolist(), "finite weights")
            out.append(a)
        return x, t, out[0], out[1]

    def _static_setup(self, fe: GirderFE, rows_u: np.ndarray, a_pj, on_pj) -> None:
        """Flexibility form of the exact FE static response (see the module docstring)."""
        girder, S, nf = self.girder, self.S, fe.ndof
        EI0 = np.asarray(girder.EI, float)
        K0 = fe.stiffness(EI0)  # pinned: statically determinate, K^-1 is linear in 1/EI_s
        K0inv = sla.cho_solve(sla.cho_factor(K0), np.eye(nf))
        K0inv = 0.5 * (K0inv + K0inv.T)
        F = np.stack([EI0[s] ** 2 * (K0inv @ fe.segment_stiffness[s] @ K0inv) for s in range(S)])
        ends = list(fe.spring_dofs)  # both free on the pinned structure
        C = fe.rows(rows_u[:, 0], rows_u[:, 1], rows_u[:, 2]).toarray()  # (U, nf)
        pp, jj = np.nonzero(on_pj)
        e, xi = element_of(a_pj[pp, jj], fe.h, fe.n_elements)
        cols = fe.dof_map[2 * e[:, None] + np.arange(4)[None, :]]
        keep = cols >= 0
        vals = (self.loads[jj][:, None] * hermite(xi, fe.h, 0).T)[keep]
        rows = np.broadcast_to(pp[:, None], cols.shape)[keep]
        Lp = sp.csr_matrix((vals, (rows, cols[keep])), shape=(self.P, nf))  # loads at each t_p
        CF = np.einsum("un,snm->sum", C, F, optimize=True)  # (S, U, nf)
        CFp = CF[:, self.row_of]  # (S, P, nf)
        self.Q0 = np.stack([np.asarray(Lp.multiply(CFp[s]).sum(axis=1)).ravel() for s in range(S)])
        self.Qc = CFp[:, :, ends]  # (S, P, 2): c_p^T F_s e
        self.Qf = np.stack([Lp @ F[s][:, ends] for s in range(S)])  # (S, P, 2): e^T F_s f_p
        self.A_end = F[:, ends][:, :, ends]  # (S, 2, 2): e^T F_s e

    def _ritz_basis(self, fe: GirderFE, n_modes: int) -> np.ndarray:
        """Reference modes, their first-order changes K0^-1 K_s phi_n with each segment's EI, and
        the static end-moment shapes K0^-1 e and K0^-1 M K0^-1 e of inferred springs."""
        girder = self.girder
        EI0 = np.asarray(girder.EI, float)
        ks0 = []
        for d, k in zip(fe.spring_dofs, girder.rotational_stiffness, strict=True):
            if d is None:
                ks0.append(0.0)
            elif math.isinf(k):  # inferred spring on a clamped template: a stiff reference
                ks0.append(1e3 * float(EI0.mean()) / girder.length)
            else:
                ks0.append(k)
        K0 = fe.stiffness(EI0, ks0)
        m = min(n_modes + RITZ_EXTRA_MODES, fe.ndof - 1)
        _, phi = sla.eigh(K0, fe.M, subset_by_index=[0, m - 1])
        fac = sla.cho_factor(K0)
        vecs = []
        X = phi[:, : min(n_modes, m)]
        if self.S > 1:
            for Ks in fe.segment_stiffness:
                vecs.append(sla.cho_solve(fac, Ks @ X))
        if self.infer_springs:
            for d in fe.spring_dofs:
                y = np.zeros(fe.ndof)
                y[d] = 1.0
                y = sla.cho_solve(fac, y)
                vecs.append(np.stack([y, sla.cho_solve(fac, fe.M @ y)], axis=1))
        if not vecs:
            return phi
        Lm = np.linalg.cholesky(fe.M)
        return _extend_mass_orthonormal(phi, np.concatenate(vecs, axis=1), fe.M, Lm, RITZ_RTOL)

    # ---- evaluation ------------------------------------------------------------------------------

    def _check_theta(self, EI: Any, springs: Any, load_factor: Any):
        try:
            EI = np.asarray(EI, float)
        except (TypeError, ValueError):
            raise InputError("EI", EI, f"an array (W, {self.S}) of numbers") from None
        if EI.ndim == 1 and EI.shape[0] == self.S:
            EI = EI[None, :]
        if EI.ndim != 2 or EI.shape[1] != self.S or EI.shape[0] < 1:
            raise InputError("EI", EI.shape, f"an array (W, {self.S}) of segment values")
        W = EI.shape[0]
        if not np.all(np.isfinite(EI)) or np.any(EI <= 0):
            raise InputError("EI", EI.tolist(), "finite values > 0 N m^2")
        if springs is None:
            if self.infer_springs and not np.all(np.isfinite(self.template_springs)):
                raise InputError("springs", None, "finite springs (W, 2): the template is clamped")
            ks = np.broadcast_to(self.template_springs, (W, 2))
        else:
            if not self.infer_springs:
                raise InputError("springs", springs, "None (springs are fixed unless inferred)")
            try:
                ks = np.asarray(springs, float)
            except (TypeError, ValueError):
                raise InputError("springs", springs, f"an array ({W}, 2) of numbers") from None
            if ks.shape == (2,):
                ks = np.broadcast_to(ks, (W, 2))
            if ks.shape != (W, 2):
                raise InputError("springs", ks.shape, f"an array ({W}, 2)")
            if not np.all(np.isfinite(ks)) or np.any(ks < 0):
                raise InputError("springs", ks.tolist(), "finite values >= 0 N m/rad")
        if load_factor is None:
            lf = np.ones(W)
        else:
            try:
                lf = np.broadcast_to(np.asarray(load_factor, float), (W,))
            except (TypeError, ValueError):
                raise InputError(
                    "load_factor", load_factor, f"a number or an array ({W},)"
                ) from None
            if not np.all(np.isfinite(lf)):
                raise InputError("load_factor", lf.tolist(), "finite values")
        return EI, ks, lf

    def static_part(self, EI: np.ndarray, ks: np.ndarray) -> np.ndarray:
        """Exact FE static response to the axles (load factor 1) at the observations, (W, P).

        EI (W, S) [N m^2], ks (W, 2) [N m/rad] (inf = clamped).
        """
        g = 1.0 / EI  # (W, S)
        W, P = g.shape[0], self.P
        q0 = g @ self.Q0  # (W, P)
        qc = (g @ self.Qc.reshape(self.S, -1)).reshape(W, P, 2)
        qf = (g @ self.Qf.reshape(self.S, -1)).reshape(W, P, 2)
        A = np.einsum("ws,sef->wef", g, self.A_end)
        a, b, d = A[:, 0, 0], A[:, 0, 1], A[:, 1, 1]
        with np.errstate(invalid="ignore", divide="ignore"):
            gl = np.where(np.isinf(ks[:, 0]), 1.0 / a, ks[:, 0] / (1.0 + ks[:, 0] * a))
            gr = np.where(np.isinf(ks[:, 1]), 1.0 / d, ks[:, 1] / (1.0 + ks[:, 1] * d))
        det = 1.0 - gl * gr * b * b
        x00, x11, x01 = gl / det, gr / det, -gl * gr * b / det
        corr = qc[:, :, 0] * (x00[:, None] * qf[:, :, 0] + x01[:, None] * qf[:, :, 1]) + qc[
            :, :, 1
        ] * (x01[:, None] * qf[:, :, 0] + x11[:, None] * qf[:, :, 1])
        return q0 - corr

    def modes(self, EI: np.ndarray, ks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Circular frequencies [rad/s] (W, n) and basis coordinates (W, r, n) of the first n modes."""
        Kr = np.einsum("ws,sab->wab", EI, self.Kr_seg)
        for i, vec in enumerate(self.spring_vecs):
            if vec is not None:
                Kr += ks[:, i, None, None] * np.outer(vec, vec)[None]
        lam, Y = np.linalg.eigh(Kr)
        n = self.n_modes
        return np.sqrt(np.maximum(lam[:, :n], 0.0)), np.ascontiguousarray(Y[:, :, :n])

    def _phase(self, wd: np.ndarray) -> np.ndarray:
        """exp(i wd t) at the distinct times, (T, W, n); powers of one step on a uniform grid."""
        if self.t_step is None:
            return np.exp(1j * self.t_u[:, None, None] * wd[None])
        B = 32
        m = -(-self.T // B)
        z = np.exp(1j * self.t_step * wd)
        small = np.empty((B,) + wd.shape, dtype=complex)  # z^k, k < B
        small[0] = 1.0
        small[1:] = z[None]
        np.cumprod(small, axis=0, out=small)
        big = np.empty((m,) + wd.shape, dtype=complex)  # z^(B k) e^{i wd t_0}
        big[0] = np.exp(1j * self.t_u[0] * wd)
        big[1:] = (small[-1] * z)[None]
        np.cumprod(big, axis=0, out=big)
        return (big[:, None] * small[None]).reshape((m * B,) + wd.shape)[: self.T]

    def dynamic_part(self, omega: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """sum_j P_j (q_n - q_n,static) of each mode at the distinct times, (T, W, n)."""
        W, n = omega.shape
        zeta, a, ne, J = self.zeta, self.series, self.n_elements, self.loads.size
        wd = omega * math.sqrt(1.0 - zeta**2)
        inv = 1.0 / omega
        Yf = Y.transpose(1, 0, 2).reshape(self.r, W * n)
        # jumps (q, q') that the homogeneous part takes up at each interval start (ne: the exit):
        # the particular solution sum_k a_k f^(k) / omega^(k+2) jumps with f^(k)
        Fj = (self.F_jump @ Yf).reshape(ne + 1, 4, W, n)
        jq = sum(a[k] * Fj[:, k] * inv ** (k + 2) for k in range(4))
        jv = sum(a[k] * Fj[:, k + 1] * inv ** (k + 2) for k in range(3))
        # homogeneous part Re(H e^{s delta}): q = Re H, q' = Re(s H), s = -zeta omega + i wd
        g = jq - 1j * (jv + zeta * omega * jq) / wd
        lam = np.exp((-zeta * omega + 1j * wd) * self.Dt)
        H = np.empty((ne + 2, W, n), dtype=complex)
        H[0] = g[0]
        for i in range(1, ne + 1):  # the exit is one element time after the last element's start
            H[i] = lam * H[i - 1] + g[i]
        H[ne + 1] = 0.0
        # particular part minus static: sum_{k>=1} a_k f^(k) / omega^(k+2), one product (T, W n)
        Yk = np.concatenate([Yf * (a[k] * inv ** (k + 2)).ravel()[None] for k in (1, 2, 3)])
        D = (self.R @ Yk).reshape(self.T, W, n)
        # homogeneous part: sum_j P_j Re(H_i e^{s (t - t_j - tau_i)}), tau_i = i Dt (i <= ne)
        ph = np.empty((ne + 2, W, n), dtype=complex)  # e^{-i wd tau_i}, by recurrence
        ph[0] = 1.0
        ph[1 : ne + 1] = np.exp(-1j * wd * self.Dt)[None]
        np.cumprod(ph[: ne + 1], axis=0, out=ph[: ne + 1])
        ph[ne + 1] = 0.0
        Hp = H * ph
        pj = np.exp(-1j * self.delays[:, None, None] * wd[None])  # (J, W, n)
        E = self._phase(wd)  # e^{i wd t}, (T, W, n)
        if zeta == 0.0:
            G = (Hp[None] * pj[:, None]).reshape(J * (ne + 2), W * n)
            acc = (self.S_hom @ G.view(float)).view(complex).reshape(self.T, W, n)
            D += E.real * acc.real - E.imag * acc.imag
            return D
        # damped: magnitudes e^{-zeta omega (t - t_j - tau_i)} split at block starts Tb
        decay = zeta * omega  # (W, n)
        span = float(self.t_u[-1] - self.t_u[0])
        nb = max(1, math.ceil(float(decay.max()) * (span + self.Dt) / _MAX_DECAY))
        edges = self.t_u[0] + span * np.arange(nb + 1) / nb
        blk = np.clip(np.searchsorted(edges, self.t_u, side="right") - 1, 0, nb - 1)
        tau_i = np.concatenate([np.arange(ne + 1) * self.Dt, [0.0]])
        for b in range(nb):
            sel = np.flatnonzero(blk == b)
            if sel.size == 0:
                continue
            Tb = edges[b]
            expo = -(Tb - self.delays[:, None] - tau_i[None, :])[..., None, None] * decay
            G = Hp[None] * pj[:, None] * np.exp(np.minimum(expo, 700.0))
            G = G.reshape(J * (ne + 2), W * n)
            acc = (self.S_hom[sel] @ G.view(float)).view(complex).reshape(sel.size, W, n)
            acc *= E[sel] * np.exp(-(self.t_u[sel] - Tb)[:, None, None] * decay)
            D[sel] += acc.real
        return D

    def predict(
        self,
        EI: np.ndarray,
        springs: np.ndarray | None = None,
        load_factor: np.ndarray | float | None = None,
    ) -> np.ndarray:
        """Observations for each parameter set.

        Parameters
        ----------
        EI : array (W, S) (or (S,)), segment flexural rigidities [N m^2].
        springs : array (W, 2) (or (2,)) of bearing springs [N m/rad] when `infer_springs`; None
            uses the template's.
        load_factor : array (W,) or float multiplying every axle load; None for 1.

        Returns
        -------
        array (W, P): a_u u + a_xx u_xx at the observation points.
        """
        EI, ks, lf = self._check_theta(EI, springs, load_factor)
        W = EI.shape[0]
        static = self.static_part(EI, ks)  # (W, P)
        omega, Y = self.modes(EI, ks)
        D = self.dynamic_part(omega, Y)  # (T, W, n)
        shape = np.matmul(self.CV[None], Y)  # (W, U, n)
        if self.U * self.T <= 8 * self.P:
            full = np.matmul(shape, D.transpose(1, 2, 0))  # (W, U, T)
            dyn = full.reshape(W, -1)[:, self.row_of * self.T + self.time_of]
        else:
            dyn = np.einsum("wpn,pwn->wp", shape[:, self.row_of], D[self.time_of], optimize=True)
        return lf[:, None] * (static + dyn)
