"""Coupled vehicle-bridge time integration: generalized-alpha, monolithic, one banded solve a step.

Unknowns: the girder's nodal dofs w (`beam.SimBeam`) and, for sprung axles, each axle's body
displacement z_j from its static position (positive down). Axle j of static load P_j = m_j g rides on
a massless contact point at x_j(t) = v (t - t_entry) - offset_j that follows u_c = w(x_j) - r(x_j) (r the
road elevation, up; w = 0 off the span); its body sits on a spring k_j = m_j (2 pi f_b)^2 and a
damper c_j = 2 zeta_b m_j (2 pi f_b). With the suspension force
    s_j = k_j (z_j - u_c) + c_j (dz_j/dt - du_c/dt),   du_c/dt = N_j dw/dt + v N'_j w - v r'(x_j),
the equations are  m_j z_j'' + s_j = 0  and  M w'' + C w' + K w = sum_j N_j^T (P_j + s_j)  (axles on the
span), N_j the deflection interpolation at x_j. The contact force on the girder is P_j - m_j z_j''. With
`model = "forces"` there are no body dofs and each axle is the constant force P_j.

Time integration is the generalized-alpha method (Chung & Hulbert 1993, J. Appl. Mech. 60: 371) with
spectral radius rho_inf at infinite frequency (0.8 by default: it damps the spurious high-mode ringing a
point load excites as it crosses element boundaries, while staying second-order accurate). For this
time-varying system the balance is imposed in its interpolated form,
    (1 - am) M a_{n+1} + am M a_n + (1 - af) g(t_{n+1}, d_{n+1}, v_{n+1}) + af g(t_n, d_n, v_n) = 0,
g = C(t) v + K(t) d - F(t) the (linear) internal-minus-external force, solved for a_{n+1} monolithically:
the body unknowns are eliminated exactly, which leaves a 4 x 4 correction on the girder's band at each
contact element, so every step is one banded solve (no iteration; the coupling is linear).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from ..config import Vehicle
from .beam import BW, SimBeam, hermite, to_banded
from .road import RoadProfile

G = 9.81  # m/s^2, only to turn an axle load into its body mass


def alpha_parameters(rho_inf: float) -> tuple[float, float, float, float]:
    """(alpha_m, alpha_f, gamma, beta) of generalized-alpha for a spectral radius rho_inf in [0, 1]."""
    am = (2 * rho_inf - 1) / (rho_inf + 1)
    af = rho_inf / (rho_inf + 1)
    gamma = 0.5 - am + af
    return am, af, gamma, 0.25 * (1 - am + af) ** 2


@dataclass
class Axles:
    """The vehicle as the solver sees it: loads, offsets, body masses, springs, dampers."""

    P: np.ndarray
    offset: np.ndarray
    mass: np.ndarray
    k: np.ndarray
    c: np.ndarray
    speed: float
    sprung: bool

    @classmethod
    def of(cls, vehicle: Vehicle) -> Axles:
        P = vehicle.loads
        m = P / G
        w = 2 * math.pi * vehicle.body_frequency
        return cls(
            P, vehicle.offsets, m, m * w * w, 2 * vehicle.body_damping * m * w, vehicle.speed,
            vehicle.model == "sprung",
        )  # fmt: skip


@dataclass
class Crossing:
    """The solved crossing: girder dofs on its own time grid from the entry, and axle histories.

    t0, dt : the girder grid t_k = t0 + k dt (t0 = the entry time; the girder is at rest before)
    U, V : (n + 1, ndof) nodal displacements and velocities
    t_axle : times of the axle histories (from the start on the approach) [s]
    force : (n_t, J) contact force of each axle on what it rides on (girder or road) [N]
    body : (n_t, J) body displacement from its static position [m] (zeros for forces)
    """

    beam: SimBeam
    t0: float
    dt: float
    U: np.ndarray
    V: np.ndarray
    t_axle: np.ndarray
    force: np.ndarray
    body: np.ndarray

    def sample(self, x, t, a_u=1.0, a_xx=0.0) -> np.ndarray:
        """a_u w + a_xx w_xx at points (x [m], t [s]) on the data's clock: zero before the entry, cubic
        Hermite interpolation of (U, V) in time, the element basis in space."""
        x = np.asarray(x, float).ravel()
        t = np.asarray(t, float).ravel()
        a_u = np.broadcast_to(np.asarray(a_u, float), x.shape)
        a_xx = np.broadcast_to(np.asarray(a_xx, float), x.shape)
        n = self.U.shape[0] - 1
        s = np.clip((t - self.t0) / self.dt, 0.0, n)
        k = np.minimum(s.astype(int), n - 1)
        r = s - k
        h00, h10 = 2 * r**3 - 3 * r**2 + 1, (r**3 - 2 * r**2 + r) * self.dt
        h01, h11 = -2 * r**3 + 3 * r**2, (r**3 - r**2) * self.dt
        dofs, N, B = self.beam.rows(x)
        kk = k[:, None]
        Ue = (
            h00[:, None] * self.U[kk, dofs]
            + h10[:, None] * self.V[kk, dofs]
            + h01[:, None] * self.U[kk + 1, dofs]
            + h11[:, None] * self.V[kk + 1, dofs]
        )
        out = a_u * np.sum(N * Ue, axis=1) + a_xx * np.sum(B * Ue, axis=1)
        return np.where(t < self.t0, 0.0, out)


def _gbsv(ab: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve the banded system (LAPACK dgbsv, partial pivoting; the matrix is not symmetric)."""
    _, _, x, info = sla.lapack.dgbsv(BW, BW, ab, b, overwrite_ab=1)
    if info != 0:
        raise FloatingPointError(f"singular coupled step matrix (dgbsv info {info})")
    return x


def solve(
    beam: SimBeam,
    vehicle: Vehicle,
    road: RoadProfile,
    t_entry: float,
    t_end: float,
    n_steps: int,
    approach: float = 0.0,
    rho_inf: float = 0.8,
) -> Crossing:
    """Integrate a crossing whose first axle enters at t_entry [s], to t_end [s], with n_steps steps
    over [t_entry, t_end]; a sprung vehicle starts with its first axle `approach` m before the span (the
    others further back), its bodies at rest on their springs' static length, so that on a rough road
    they arrive bouncing."""
    ax = Axles.of(vehicle)
    dt = (t_end - t_entry) / n_steps
    J = ax.P.size
    m_pre = math.ceil(approach / (ax.speed * dt) - 1e-9) if ax.sprung else 0
    am, af, gm, bt = alpha_parameters(rho_inf)
    cg, cb = (1 - af) * gm * dt, (1 - af) * bt * dt * dt
    nd = beam.ndof
    # LAPACK gbsv layout: BW extra rows on top for the factorisation's fill-in
    S0 = np.zeros((3 * BW + 1, nd))
    S0[BW:] = to_banded((1 - am) * beam.M + cg * beam.C + cb * beam.K)
    S0[2 * BW, beam.fixed] = 1.0
    Kband, Cband, Mband = (to_banded(A) for A in (beam.K, beam.C, beam.M))
    gbmv = sla.blas.dgbmv
    ii, jj = np.meshgrid(np.arange(4), np.arange(4), indexing="ij")
    band_rows = 2 * BW + ii - jj
    L, v = beam.length, ax.speed
    n_t = m_pre + n_steps + 1
    t_axle = t_entry + dt * np.arange(-m_pre, n_steps + 1)
    # every axle's position, contact element and basis, and road, at every step, at once
    xs = v * (t_axle[:, None] - t_entry) - ax.offset[None, :]
    live = (xs >= 0.0) & (xs <= L)
    el, xi = beam.locate(xs.ravel())
    d0s = (2 * el).reshape(xs.shape)
    mask = beam.free[d0s[..., None] + np.arange(4)]
    Ns = hermite(xi, beam.h, 0).T.reshape(xs.shape + (4,)) * mask
    Nxs = hermite(xi, beam.h, 1).T.reshape(xs.shape + (4,)) * mask
    rs = road.elevation(xs.ravel()).reshape(xs.shape)
    rps = road.slope(xs.ravel()).reshape(xs.shape)
    on_list = [np.flatnonzero(row) for row in live]
    four = np.arange(4)
    mass, kk, cc = ax.mass, ax.k, ax.c
    szz = (1 - am) * mass + cg * cc + cb * kk

    def g_of(i, d, vel, z, zd):
        """Internal-minus-external force at step i: girder part, and the suspension forces."""
        on = on_list[i]
        gb = gbmv(nd, nd, BW, BW, 1.0, Cband, vel) + gbmv(nd, nd, BW, BW, 1.0, Kband, d)
        uc, ucd = -rs[i], -v * rps[i]
        if on.size:
            idx = d0s[i, on, None] + four
            N, Nx = Ns[i, on], Nxs[i, on]
            we = d[idx]
            uc, ucd = uc.copy(), ucd.copy()
            uc[on] += np.sum(N * we, axis=1)
            ucd[on] += np.sum(N * vel[idx] + v * Nx * we, axis=1)
        s = kk * (z - uc) + cc * (zd - ucd) if ax.sprung else np.zeros(J)
        if on.size:
            np.add.at(gb, idx, -N * (ax.P[on] + s[on])[:, None])
        return gb, s

    force = np.tile(ax.P, (n_t, 1))
    body = np.zeros((n_t, J))
    # phase 1, up to the entry: the girder at rest, each body on the road alone
    z = -rs[0] if ax.sprung else np.zeros(J)
    zd = -v * rps[0] if ax.sprung else np.zeros(J)
    zdd = np.zeros(J)
    gz = kk * (z + rs[0]) + cc * (zd + v * rps[0])
    body[0] = z
    for i in range(1, m_pre + 1):
        zp = z + dt * zd + dt * dt * (0.5 - bt) * zdd
        zdp = zd + dt * (1 - gm) * zdd
        gz1 = kk * (zp + rs[i]) + cc * (zdp + v * rps[i])
        zdd_new = (-(1 - af) * gz1 - af * gz - am * mass * zdd) / szz
        z = zp + bt * dt * dt * zdd_new
        zd = zdp + gm * dt * zdd_new
        zdd = zdd_new
        gz = kk * (z + rs[i]) + cc * (zd + v * rps[i])
        force[i] = ax.P - mass * zdd
        body[i] = z
    # phase 2, from the entry: the coupled system
    U = np.zeros((n_steps + 1, nd))
    V = np.zeros((n_steps + 1, nd))
    d, vel, acc = np.zeros(nd), np.zeros(nd), np.zeros(nd)
    gb, gz = g_of(m_pre, d, vel, z, zd)
    for k in range(1, n_steps + 1):
        i = m_pre + k
        dp = d + dt * vel + dt * dt * (0.5 - bt) * acc
        vp = vel + dt * (1 - gm) * acc
        zp = z + dt * zd + dt * dt * (0.5 - bt) * zdd
        zdp = zd + dt * (1 - gm) * zdd
        gb1, gz1 = g_of(i, dp, vp, zp, zdp)
        Rb = -(1 - af) * gb1 - af * gb - am * gbmv(nd, nd, BW, BW, 1.0, Mband, acc)
        Rz = -(1 - af) * gz1 - af * gz - am * mass * zdd
        Sb = S0.copy()
        rows = {}
        for j in on_list[i] if ax.sprung else ():
            d0, N, Nx = d0s[i, j], Ns[i, j], Nxs[i, j]
            row = -(cg * cc[j]) * N - cb * (kk[j] * N + cc[j] * v * Nx)
            rows[j] = (d0, row)
            Sb[band_rows, d0 + jj] -= np.outer(N, row) * ((1 - am) * mass[j] / szz[j])
            Rb[d0 : d0 + 4] += N * ((cg * cc[j] + cb * kk[j]) * Rz[j] / szz[j])
        Rb[beam.fixed] = 0.0
        acc = _gbsv(Sb, Rb)
        d = dp + bt * dt * dt * acc
        vel = vp + gm * dt * acc
        if ax.sprung:
            zdd = Rz / szz
            for j, (d0, row) in rows.items():
                zdd[j] = (Rz[j] - row @ acc[d0 : d0 + 4]) / szz[j]
            z = zp + bt * dt * dt * zdd
            zd = zdp + gm * dt * zdd
            force[i] = ax.P - mass * zdd
            body[i] = z
        gb, gz = g_of(i, d, vel, z, zd)
        U[k], V[k] = d, vel
    return Crossing(beam, t_entry, dt, U, V, t_axle, force, body)
