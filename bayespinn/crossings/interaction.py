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
#: Newmark steps whose matrices are built at once (memory: BLOCK x W x (N_DYN + axles)^2 x 2 floats)
BLOCK = 256


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
    Q, F = _newmark(L, mu, P, off, m, k, c, kn, omega, zeta, v, t0, T0, dt, n)
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


def _newmark(L, mu, P, off, m, k, c, kn, omega, zeta, v, t0, T0, dt, n):
    """The coupled system of the module docstring from rest at T0, n steps of dt, for W parameter sets:
    the interaction's modal response Q = q - q0 (n, W, Nd) and force Delta F (n, W, J).

    The rule is the average-acceleration Newmark one, A a_i = f_i - C_i v_p - K_i x_p with A = M + (dt/2)
    C_i + (dt^2/4) K_i. The matrices depend on time only through the axles' positions, not on the state,
    so they are built for `BLOCK` steps at once and the loop over steps is left with two small products:
    with A^-1 (dt/2 C + dt^2/4 K) = I - A^-1 M and C + dt K = (A - M) / (dt/2) + (dt/2) K,

        a_i = A^-1 f_i - A^-1 K (x + dt/2 v) - (I - A^-1 M) (v / (dt/2) + a),

    and A^-1 comes from its Schur complement on the modes (the bodies' block is diagonal). The whole step,
    with the constant-force modes' own rule beside it, is then one affine map of the state (x, x', x'',
    the constant-force modes' (q, q', q'')), built for the block at once, so that the loop over steps is a
    single small matrix-vector product (the loop's Python overhead was most of a likelihood's cost)."""
    W, Nd, J = omega.shape[0], kn.size, P.size
    D = Nd + J
    Mdiag = np.concatenate([np.ones(Nd), m])
    h2, h4 = dt / 2, dt * dt / 4
    damp0 = 2 * zeta[:, None] * omega  # (W, Nd)
    # the modes under the constant forces alone: a time-invariant map of (q, q', q'') per mode
    den = 1 + h2 * damp0 + h4 * omega**2
    ra = np.stack([-(omega**2), -damp0 - dt * omega**2, -h2 * damp0 - h4 * omega**2], -1)
    ra = ra / den[..., None]
    T0m = np.stack([np.array([1.0, dt, h4]) + h4 * ra, np.array([0.0, 1.0, h2]) + h2 * ra, ra], -2)
    g0c = np.array([h4, h2, 1.0])
    a22 = m + h2 * c + h4 * k  # (W, J): A's bodies block, diagonal
    modes, bodies = np.arange(Nd), np.arange(Nd, D)
    D3, NS = 3 * D, 3 * D + 3 * Nd
    # (x, x', x'') -> the same without the step's acceleration; the modes' constant-force map per mode
    lift = np.zeros((D3, D3))
    eye = np.eye(D)
    lift[:D, :D], lift[:D, D : 2 * D], lift[:D, 2 * D :] = eye, dt * eye, h4 * eye
    lift[D : 2 * D, D : 2 * D], lift[D : 2 * D, 2 * D :] = eye, h2 * eye
    T0blk = np.zeros((W, 3 * Nd, 3 * Nd))
    for j in range(Nd):
        T0blk[:, 3 * j : 3 * j + 3, 3 * j : 3 * j + 3] = T0m[:, j]
    Z = np.empty((n, W, NS))
    for b0 in range(0, n, BLOCK):
        idx = np.arange(b0, min(n, b0 + BLOCK))
        t = T0 + idx * dt
        xj = (
            v[None, :, None] * (t[:, None, None] - t0[None, :, None]) - off[None, None]
        )  # (b, W, J)
        on = (xj >= 0.0) & (xj <= L)
        Phi = np.sin(kn * xj[..., None]) * on[..., None]  # (b, W, J, Nd)
        dPhi = kn * np.cos(kn * xj[..., None]) * on[..., None]
        Bt = (2.0 / (mu * L)) * np.swapaxes(Phi, -1, -2)  # (b, W, Nd, J)
        cP = c[:, :, None] * Phi
        kP = k[:, :, None] * Phi + (c * v[:, None])[:, :, None] * dPhi
        C11, K11 = Bt @ cP, Bt @ kP
        C11[..., modes, modes] += damp0
        K11[..., modes, modes] += omega**2
        K12 = -Bt * k[:, None, :]
        A12d = -Bt * ((h2 * c + h4 * k) / a22)[:, None, :]  # A12 A22^-1
        A21 = -(h2 * cP + h4 * kP)
        S = h2 * C11 + h4 * K11 - A12d @ A21
        S[..., modes, modes] += 1.0
        Si = _inv_small(S)
        U = -Si @ A12d
        A21d = A21 / a22[:, :, None]
        Ainv = np.empty(idx.shape + (W, D, D))
        Ainv[..., :Nd, :Nd] = Si
        Ainv[..., :Nd, Nd:] = U
        Ainv[..., Nd:, :Nd] = -A21d @ Si
        Ainv[..., Nd:, Nd:] = -A21d @ U
        Ainv[..., bodies, bodies] += 1.0 / a22
        Km = np.zeros_like(Ainv)
        Km[..., :Nd, :Nd] = K11
        Km[..., :Nd, Nd:] = K12
        Km[..., Nd:, :Nd] = -kP
        Km[..., bodies, bodies] = k
        AK = np.einsum("...ij,...jk->...ik", Ainv, Km, optimize=True)
        IAM = -Ainv * Mdiag
        IAM[..., np.arange(D), np.arange(D)] += 1.0
        fN = np.einsum("bwnj,j->bwn", Bt, P)  # the constant forces' modal load (b, W, Nd)
        ga = np.einsum("bwin,bwn->bwi", Ainv[..., :Nd], fN)
        # one step as one affine map of the state z = (x, x', x'', s0): a = ga + Ra (x, x', x'')
        Ra = -np.concatenate([AK, h2 * AK + IAM / h2, IAM], axis=-1)  # (b, W, D, 3D)
        T = np.zeros(idx.shape + (W, NS, NS))
        T[..., :D, :D3] = h4 * Ra
        T[..., D : 2 * D, :D3] = h2 * Ra
        T[..., 2 * D : D3, :D3] = Ra
        T[..., :D3, :D3] += lift
        T[..., D3:, D3:] = T0blk
        off_v = np.concatenate(
            [h4 * ga, h2 * ga, ga, ((fN / den)[..., None] * g0c).reshape(*fN.shape[:2], -1)], -1
        )  # (b, W, NS)
        for ii, i in enumerate(idx):
            if i == 0:  # from rest: M a = f
                z = np.zeros((W, NS))
                z[:, 2 * D : 2 * D + Nd] = fN[ii]
                z[:, D3 + 2 :: 3] = fN[ii]
            else:
                z = np.matmul(T[ii], z[:, :, None])[:, :, 0] + off_v[ii]
            Z[i] = z
    t = T0 + np.arange(n) * dt
    xj = v[None, :, None] * (t[:, None, None] - t0[None, :, None]) - off[None, None]
    on = (xj >= 0.0) & (xj <= L)  # (n, W, J)
    Q = Z[..., :Nd] - Z[..., D3::3]
    F = -m * Z[..., 2 * D + Nd : D3] * on
    return Q, F


def _inv_small(S: np.ndarray) -> np.ndarray:
    """Inverses of a stack of 1 x 1 or 2 x 2 matrices in closed form (larger ones by LAPACK)."""
    if S.shape[-1] == 1:
        return 1.0 / S
    if S.shape[-1] == 2:
        a, b, c, d = S[..., 0, 0], S[..., 0, 1], S[..., 1, 0], S[..., 1, 1]
        det = a * d - b * c
        return np.stack([np.stack([d, -b], -1), np.stack([-c, a], -1)], -2) / det[..., None, None]
    return np.linalg.inv(S)
