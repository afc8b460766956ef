"""The vehicle's suspension in the analysis model: each axle a sprung body on the moving girder.

A light girder under a heavy lorry is not loaded by forces that ignore it: each axle's body (mass m_j =
P_j / g) rides on a spring k_j = m_j (2 pi f_b)^2 and a damper c_j = 2 zeta_b m_j (2 pi f_b) whose foot
follows the girder, so the lorry adds stiffness, mass and (above all) damping to the girder's vibration.
On the Exeter girder (5 t of steel under a 17.6 t lorry) its dampers carry several times the girder's own
damping. The axle then presses on the girder with P_j - m_j z_j'' (z_j the body's downward displacement):
the constant force plus an interaction force that is a deterministic function of (EI, zeta, v, t0, f_b,
zeta_b), which this module computes and adds to `forward.CrossingModel`'s constant-force response.

The coupled system: the girder's first `N_DYN` modes q_n (phi_n = sin(k_n x), modal mass mu L / 2) and the
bodies z_j,

    q_n'' + 2 zeta omega_n q_n' + omega_n^2 q_n = (2 / (mu L)) sum_j F_j phi_n(x_j)
    m_j z_j'' + c_j (z_j' - w_j') + k_j (z_j - w_j) = 0,   w_j = sum_n phi_n(x_j) q_n,
    F_j = P_j + c_j (z_j' - w_j') + k_j (z_j - w_j) = P_j - m_j z_j''

(w_j' includes the convective v phi_n'(x_j) q_n), integrated by the average-acceleration Newmark rule at
a step of `STEP_FRACTION` / omega_N. The same rule integrates the modes under the constant forces alone,
and the difference of the two is the interaction's modal response, so the rule's own period error cancels
to first order. The interaction force's response at the sensors is then written in mode-acceleration form:
its exact static part (Delta F_j times the static influence line, divided by EI) plus the modal dynamic
corrections of the first N_DYN modes; higher modes respond quasi-statically to forces below the girder's
first frequency. The road's roughness is not here: it is the force fluctuation of `likelihood`.
"""

from __future__ import annotations

import math

import numpy as np

from ..physics.modal import static_unit_deflection, static_unit_moment
from .forward import CrossingModel

G = 9.81  # m/s^2: an axle load into its body's mass
#: the girder's modes coupled to the bodies; the Newmark step is STEP_FRACTION / omega_N_DYN
N_DYN, STEP_FRACTION = 2, 0.25


def interaction_response(base: CrossingModel, EI, zeta, v, t0, fb, zb) -> np.ndarray:
    """The interaction force's response (W, P) at base's observations, for parameter sets (W,): EI
    [N m^2], zeta, v [m/s], t0 [s], body frequency fb [Hz] and suspension damping ratio zb."""
    EI, zeta, v, t0, fb, zb = np.broadcast_arrays(
        *(np.atleast_1d(np.asarray(a, float)) for a in (EI, zeta, v, t0, fb, zb))
    )
    W, L, mu = EI.size, base.L, base.mu
    P, off = base.loads, base.offsets
    J, Nd = P.size, min(N_DYN, base.n_modes)
    m = P / G
    wb = 2 * math.pi * fb
    k = m[None] * wb[:, None] ** 2  # (W, J)
    c = 2 * zb[:, None] * m[None] * wb[:, None]
    kn = np.arange(1, Nd + 1) * math.pi / L
    omega = kn[None] ** 2 * np.sqrt(EI[:, None] / mu)  # (W, Nd)
    dt = STEP_FRACTION / float(omega[:, -1].max())
    T0 = float(t0.min())
    T1 = float(base.times.max())
    if T1 <= T0:
        return np.zeros((W, base.x.size))
    n = int(math.ceil((T1 - T0) / dt)) + 1
    D = Nd + J
    Mdiag = np.concatenate([np.ones(Nd), m])
    x = np.zeros((W, D))
    xd = np.zeros((W, D))
    xa = np.zeros((W, D))
    q0, q0d, q0a = np.zeros((W, Nd)), np.zeros((W, Nd)), np.zeros((W, Nd))
    Q = np.empty((n, W, Nd))  # the interaction's modal response q - q0
    F = np.empty((n, W, J))  # its force Delta F_j = -m_j z_j''
    h2, h4 = dt / 2, dt * dt / 4
    damp0 = 2 * zeta[:, None] * omega
    eye = np.arange(D)
    for i in range(n):
        t = T0 + i * dt
        xj = v[:, None] * (t - t0[:, None]) - off[None]  # (W, J)
        on = (xj >= 0.0) & (xj <= L)
        Phi = np.sin(kn[None, None] * xj[:, :, None]) * on[:, :, None]  # (W, J, Nd)
        dPhi = kn[None, None] * np.cos(kn[None, None] * xj[:, :, None]) * on[:, :, None]
        B = (2.0 / (mu * L)) * Phi
        Cm = np.zeros((W, D, D))
        Km = np.zeros((W, D, D))
        Cm[:, :Nd, :Nd] = np.einsum("wjn,wj,wjm->wnm", B, c, Phi)
        Km[:, :Nd, :Nd] = np.einsum("wjn,wj,wjm->wnm", B, k, Phi) + np.einsum(
            "wjn,wj,wjm->wnm", B, c * v[:, None], dPhi
        )
        Cm[:, eye[:Nd], eye[:Nd]] += damp0
        Km[:, eye[:Nd], eye[:Nd]] += omega**2
        Cm[:, :Nd, Nd:] = -np.swapaxes(B, 1, 2) * c[:, None, :]
        Km[:, :Nd, Nd:] = -np.swapaxes(B, 1, 2) * k[:, None, :]
        Cm[:, Nd:, :Nd] = -Phi * c[:, :, None]
        Km[:, Nd:, :Nd] = -(Phi * k[:, :, None] + dPhi * (c * v[:, None])[:, :, None])
        Cm[:, eye[Nd:], eye[Nd:]] = c
        Km[:, eye[Nd:], eye[Nd:]] = k
        f = np.zeros((W, D))
        f[:, :Nd] = np.einsum("wjn,j->wn", B, P)
        if i == 0:  # from rest: M a = f
            xa = f / Mdiag[None]
            q0a = f[:, :Nd].copy()
        else:
            xp = x + dt * xd + h4 * xa
            vp = xd + h2 * xa
            A = np.diag(Mdiag)[None] + h2 * Cm + h4 * Km
            rhs = f - np.einsum("wij,wj->wi", Cm, vp) - np.einsum("wij,wj->wi", Km, xp)
            xa = np.linalg.solve(A, rhs[:, :, None])[:, :, 0]
            x = xp + h4 * xa
            xd = vp + h2 * xa
            # the modes under the constant forces alone, by the same rule (diagonal)
            qp = q0 + dt * q0d + h4 * q0a
            qv = q0d + h2 * q0a
            q0a = (f[:, :Nd] - damp0 * qv - omega**2 * qp) / (1 + h2 * damp0 + h4 * omega**2)
            q0 = qp + h4 * q0a
            q0d = qv + h2 * q0a
        Q[i] = x[:, :Nd] - q0
        F[i] = -m[None] * xa[:, Nd:] * on
    # to the observation times (linear interpolation on the step grid)
    s = (base.t - T0) / dt
    i0 = np.clip(np.floor(s).astype(int), 0, n - 2)
    fr = np.clip(s - i0, 0.0, 1.0)[None, :]
    Qo = Q[i0] * (1 - fr.T)[:, :, None] + Q[i0 + 1] * fr.T[:, :, None]  # (P, W, Nd)
    Fo = F[i0] * (1 - fr.T)[:, :, None] + F[i0 + 1] * fr.T[:, :, None]  # (P, W, J)
    Qo, Fo = np.transpose(Qo, (1, 0, 2)), np.transpose(Fo, (1, 0, 2))  # (W, P, .)
    shape = np.sin(kn[None] * base.x[:, None]) * (
        base.a_u[:, None] - base.a_xx[:, None] * kn[None] ** 2
    )  # (P, Nd)
    out = np.zeros((W, base.x.size))
    modal_force = np.zeros((W, base.x.size, Nd))
    for j in range(J):
        xj = v[:, None] * (base.t[None] - t0[:, None]) - off[j]  # (W, P)
        on = (xj >= 0.0) & (xj <= L)
        pos = np.clip(xj, 0.0, L)
        st = np.zeros_like(pos)
        if base.any_u:
            st += base.a_u * static_unit_deflection(base.x[None], pos, L)
        if base.any_xx:
            st -= base.a_xx * static_unit_moment(base.x[None], pos, L)
        out += np.where(on, st, 0.0) * Fo[:, :, j] / EI[:, None]
        modal_force += (
            (2.0 / (mu * L)) * Fo[:, :, j, None] * np.sin(kn[None, None] * pos[:, :, None])
            * on[:, :, None]
        )  # fmt: skip
    dyn = Qo - modal_force / omega[:, None, :] ** 2
    return out + np.einsum("wpn,pn->wp", dyn, shape)
