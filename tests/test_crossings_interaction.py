"""The analysis model's sprung vehicle against the independent simulator, and the linearised
fluctuating-force posterior's algebra against dense linear algebra on the same small problem.

- The interaction (the response of a sprung vehicle minus that of its constant forces) is computed by two
  codes that share nothing: `bayespinn.vbi` (finite elements, generalized-alpha, the contact point in the
  element matrices) and `crossings.interaction` (modes, Newmark, mode-acceleration). They agree to a
  fraction of the interaction itself; a suspension 1.5x too stiff or 3x too damped does not.
- `linearised.Linearisation.log_evidence` (each crossing's block eliminated, then the shared one) equals the
  Gaussian marginal likelihood of the same linear model written densely, and its likelihood at the
  linearisation point equals the model's own (`linearised.exact_loglik`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import bayespinn as bp
from bayespinn import vbi
from bayespinn.config import Road
from bayespinn.crossings.forward import CrossingModel
from bayespinn.crossings.interaction import interaction_response
from bayespinn.crossings.likelihood import CrossingsLogPosterior
from bayespinn.crossings.linearised import Linearisation, exact_loglik
from bayespinn.crossings.peak import terms as _terms
from bayespinn.uq.priors import EIPrior, NoisePrior

#: the interaction's relative RMS error between the two codes: measured 0.05 on the Exeter girder at
#: 100 Hz (default simulator settings), where a wrong suspension gives 0.3 or more
AGREE, WRONG = 0.15, 0.3


@pytest.fixture(scope="module")
def crossing():
    cfg = bp.resolve("strain", {"data": {"sample_rate": 100.0}})
    veh = dataclasses.replace(
        cfg.vehicle, model="sprung", body_frequency=2.0, body_damping=0.08, entry_time=0.3
    )
    cfg = dataclasses.replace(
        cfg, vehicle=veh, beam=dataclasses.replace(cfg.beam, damping_ratio=0.015)
    )
    out = {}
    for model in ("forces", "sprung"):
        c = dataclasses.replace(
            cfg, vehicle=dataclasses.replace(veh, model=model), road=Road(roughness=0.0)
        )
        out[model] = vbi.simulate(c, None, 1)
    return cfg, out


def _interaction(cfg, data, fb, zb):
    a_u, a_xx = data.weights
    v = cfg.vehicle
    m = CrossingModel(
        cfg.beam.length, cfg.beam.mass_per_length, v.loads, v.offsets, data.x, data.t, a_u, a_xx,
        n_modes=24,
    )  # fmt: skip
    args = (cfg.beam.EI, cfg.beam.damping_ratio, v.speed, v.entry_time)
    return interaction_response(m, *args, fb, zb)[0]


def test_interaction_matches_the_independent_simulator(crossing):
    cfg, out = crossing
    truth = np.asarray(out["sprung"].value) - np.asarray(out["forces"].value)
    rms = float(np.sqrt(np.mean(truth**2)))
    assert rms > 0.003 * float(np.sqrt(np.mean(np.asarray(out["forces"].value) ** 2)))

    def err(fb, zb):
        d = _interaction(cfg, out["sprung"], fb, zb) - truth
        return float(np.sqrt(np.mean(d**2))) / rms

    assert err(2.0, 0.08) < AGREE
    # negative controls: the same codes with a wrong suspension
    assert err(3.0, 0.08) > WRONG
    assert err(2.0, 0.24) > WRONG


@pytest.fixture(scope="module")
def small_post(crossing):
    cfg, out = crossing
    data = out["sprung"]
    keep = np.arange(len(data)) % 4 == 0  # a small problem for the dense algebra
    data = data.select(keep)
    rng = np.random.default_rng(3)
    sigma = 0.05 * float(np.std(data.value))
    data = dataclasses.replace(
        data, value=np.asarray(data.value) + sigma * rng.standard_normal(len(data))
    )
    veh = dataclasses.replace(cfg.vehicle, speed_sd=0.01, entry_time_sd=0.05)
    cfg = dataclasses.replace(
        cfg, vehicle=veh, model=dataclasses.replace(cfg.model, axle_forces="fluctuating")
    )
    post = CrossingsLogPosterior(
        _terms(cfg, data, 8, True), EIPrior.from_spec(cfg.prior),
        NoisePrior.build("vague", np.asarray(data.value, float)), zeta_known=0.015,
        damping_prior=(0.01, 0.7), forces=True,
    )  # fmt: skip
    L = post.layout
    th = np.zeros(L.dim)
    th[0] = math.log(cfg.beam.EI)
    th[L.index["log_zeta"]] = math.log(0.015)
    th[L.index["log_s"]] = math.log(0.03)
    th[L.index["log_l"]] = math.log(0.3)
    th[L.index["log_sigma"]] = math.log(sigma)
    c = post.terms[0]
    th[L.index[f"log_v[{c.name}]"]] = math.log(veh.speed)
    th[L.index[f"t0[{c.name}]"]] = veh.entry_time
    th[L.index[f"log_fb[{c.name}]"]] = math.log(2.0)
    th[L.index[f"log_zb[{c.name}]"]] = math.log(0.08)
    th[L.index["log_q1"]], th[L.index["log_q2"]] = math.log(0.05), math.log(0.1)
    th[L.index["log_z2"]] = math.log(0.02)
    return post, th


def _dense_evidence(lin: Linearisation, post, h: np.ndarray) -> float:
    """log N(r; X mu, sigma^2 I + X P^-1 X') of the linear model, written out densely."""
    _, _, _, r, cov = _dense_model(lin, post, h)
    sign, logdet = np.linalg.slogdet(cov)
    assert sign > 0
    return float(-0.5 * (r.size * math.log(2 * math.pi) + logdet + r @ np.linalg.solve(cov, r)))


def _dense_model(lin: Linearisation, post, h: np.ndarray):
    """The linear model densely: design X (theta's columns, then the scaled basis), the prior's mean and
    variance of the coefficients, the data's residual from the prior mean r, and its covariance."""
    c, b = post.terms[0], lin.blocks[0]
    sig = math.exp(h[2])
    th = lin.theta
    L = post.layout
    cols = lin.shared + b.own
    steps = []
    pts = np.repeat(th[None], 1 + 2 * len(cols), 0)
    from bayespinn.crossings.linearised import _steps

    for j, k in enumerate(cols):
        hk = _steps(L.names[k])
        steps.append(hk)
        pts[1 + 2 * j, k] += hk
        pts[2 + 2 * j, k] -= hk
    p = post.unpack(pts)
    mu = c.predict({k: v for k, v in p.items()}, 0)
    J = (mu[1::2] - mu[2::2]) / (2 * np.array(steps)[:, None])
    mu0, R = c.responses(
        {k: [a[:1] for a in v] if isinstance(v, list) else v[:1] for k, v in p.items()}, 0
    )
    full = th.copy()
    full[lin.hyper] = h
    d = c.column_sds(post.unpack(full[None]), 0)[0]
    X = np.concatenate([J.T, R[0] * d[None]], axis=1)
    prior_mean = np.concatenate(
        [lin.shared_mean - th[lin.shared], b.own_mean - th[b.own], np.zeros(R.shape[2])]
    )
    prior_var = np.concatenate([lin.shared_sd**2, b.own_sd**2, np.ones(R.shape[2])])
    r = c.y - mu0[0] - X @ prior_mean
    cov = sig**2 * np.eye(r.size) + (X * prior_var[None]) @ X.T
    return X, prior_mean, prior_var, r, cov


def test_linearised_evidence_equals_the_dense_marginal(small_post):
    post, th = small_post
    lin = Linearisation(post, th)
    h = th[lin.hyper]
    dense = _dense_evidence(lin, post, h)
    assert lin.log_evidence(h[None])[0] == pytest.approx(dense, abs=1e-6 * abs(dense) + 1e-6)
    # negative control: another noise sd is another evidence
    h2 = h.copy()
    h2[2] += 0.1
    assert abs(lin.log_evidence(h2[None])[0] - dense) > 1.0


def test_linearised_conditional_mean_equals_the_dense_posterior_mean(small_post):
    """theta's conditional mean given the hyperparameters (each block eliminated by Cholesky factors and
    triangular solves) is the dense Gaussian posterior mean mu + P^-1 X' cov^-1 r; a noise sd 10 %
    larger moves it by more than the tolerance (negative control)."""
    post, th = small_post
    lin = Linearisation(post, th)
    h = th[lin.hyper]
    cols = lin.shared + lin.blocks[0].own
    X, m0, v0, r, cov = _dense_model(lin, post, h)
    dense = (m0 + v0 * (X.T @ np.linalg.solve(cov, r)))[: len(cols)]
    mine = lin.conditional(h[None])[0, cols] - th[cols]
    sd = np.sqrt(
        np.diag(np.linalg.inv(X[:, : len(cols)].T @ X[:, : len(cols)])) * math.exp(2 * h[2])
    )
    np.testing.assert_allclose(mine, dense, rtol=0, atol=1e-6 * sd.max())
    h2 = h.copy()
    h2[2] += math.log(1.1)
    X2, m2, v2, r2, cov2 = _dense_model(lin, post, h2)
    other = (m2 + v2 * (X2.T @ np.linalg.solve(cov2, r2)))[: len(cols)]
    assert np.abs(other - dense).max() > 1e-6 * sd.max()


def test_linearised_likelihood_is_exact_at_its_point_and_its_table_near_it(small_post):
    post, th = small_post
    lin = Linearisation(post, th)
    exact = exact_loglik(post, th[None])[0]
    assert lin.loglik(th[None])[0] == pytest.approx(exact, abs=1e-6 * abs(exact))
    tab = Linearisation(post, th, tabulate=True)
    t = tab.blocks[0].table
    K = t["nodes"]
    node = np.cos(np.pi * (np.array([2, K - 3]) + 0.5) / K)  # a node of the table, off its center
    off = th.copy()
    for j, k in enumerate(t["index"]):
        off[k] = t["center"][j] + t["half"][j] * node[j]
    ex_off = exact_loglik(post, off[None])[0]
    assert tab.loglik(off[None])[0] == pytest.approx(ex_off, abs=0.05)
    # negative control: the suspension's change matters to the likelihood there
    assert abs(tab.loglik(th[None])[0] - ex_off) > 1.0


def _dense_newmark(L, mu, P, off, m, k, c, kn, omega, zeta, v, t0, T0, dt, n):
    """The coupled system of `interaction`'s docstring for one parameter set, written directly: the full
    M, C, K assembled at every step and A a = f - C v_p - K x_p solved densely."""
    Nd, J = kn.size, P.size
    D = Nd + J
    M = np.diag(np.concatenate([np.ones(Nd), m]))
    x, xd = np.zeros(D), np.zeros(D)
    q0, q0d = np.zeros(Nd), np.zeros(Nd)
    Q, F = np.zeros((n, Nd)), np.zeros((n, J))
    for i in range(n):
        xj = v * (T0 + i * dt - t0) - off
        on = (xj >= 0) & (xj <= L)
        Phi = np.sin(np.outer(xj, kn)) * on[:, None]
        dPhi = kn * np.cos(np.outer(xj, kn)) * on[:, None]
        B = 2.0 / (mu * L) * Phi
        C, K = np.zeros((D, D)), np.zeros((D, D))
        C[:Nd, :Nd] = np.diag(2 * zeta * omega) + B.T @ (c[:, None] * Phi)
        K[:Nd, :Nd] = np.diag(omega**2) + B.T @ (k[:, None] * Phi + (c * v)[:, None] * dPhi)
        C[:Nd, Nd:], K[:Nd, Nd:] = -B.T * c, -B.T * k
        C[Nd:, :Nd], K[Nd:, :Nd] = -c[:, None] * Phi, -(k[:, None] * Phi + (c * v)[:, None] * dPhi)
        C[Nd:, Nd:], K[Nd:, Nd:] = np.diag(c), np.diag(k)
        f = np.concatenate([B.T @ P, np.zeros(J)])
        C0, K0 = np.diag(2 * zeta * omega), np.diag(omega**2)
        if i == 0:
            xa, q0a = np.linalg.solve(M, f), f[:Nd].copy()
        else:
            xp, vp = x + dt * xd + dt**2 / 4 * xa, xd + dt / 2 * xa
            xa = np.linalg.solve(M + dt / 2 * C + dt**2 / 4 * K, f - C @ vp - K @ xp)
            x, xd = xp + dt**2 / 4 * xa, vp + dt / 2 * xa
            qp, qv = q0 + dt * q0d + dt**2 / 4 * q0a, q0d + dt / 2 * q0a
            A0 = np.eye(Nd) + dt / 2 * C0 + dt**2 / 4 * K0
            q0a = np.linalg.solve(A0, f[:Nd] - C0 @ qv - K0 @ qp)
            q0, q0d = qp + dt**2 / 4 * q0a, qv + dt / 2 * q0a
        Q[i], F[i] = x[:Nd] - q0, -m * xa[Nd:] * on
    return Q, F


@pytest.mark.parametrize("block", [7, 256])
def test_blocked_newmark_equals_the_dense_rule(monkeypatch, block):
    """`interaction._newmark` (matrices built a block of steps at a time, A inverted through its Schur
    complement, the step written with A^-1 K and A^-1 M) is the average-acceleration rule itself: equal to
    the dense step-by-step solve for every parameter set of a batch, whatever the block length."""
    from bayespinn.crossings import interaction

    monkeypatch.setattr(interaction, "BLOCK", block)
    L, mu = 30.0, 5000.0
    P = np.array([40e3, 60e3, 60e3])
    off = np.array([0.0, 3.5, 4.8])
    m = P / interaction.G
    kn = np.arange(1, 3) * math.pi / L
    rng = np.random.default_rng(3)
    W = 3
    EI = 5e9 * np.exp(0.05 * rng.standard_normal(W))
    fb, zb = rng.uniform(1.5, 3.5, W), rng.uniform(0.05, 0.2, W)
    wb = 2 * math.pi * fb
    k, c = m[None] * wb[:, None] ** 2, 2 * zb[:, None] * m[None] * wb[:, None]
    omega = kn[None] ** 2 * np.sqrt(EI[:, None] / mu)
    zeta, v, t0 = rng.uniform(0.005, 0.02, W), rng.uniform(8, 12, W), rng.uniform(0.0, 0.2, W)
    dt, n = 0.25 / float(omega[:, -1].max()), 600
    T0 = float(t0.min())
    Q, F = interaction._newmark(L, mu, P, off, m, k, c, kn, omega, zeta, v, t0, T0, dt, n)
    for w in range(W):
        Qd, Fd = _dense_newmark(
            L, mu, P, off, m, k[w], c[w], kn, omega[w], zeta[w], v[w], t0[w], T0, dt, n
        )
        assert np.abs(F[:, w]).max() > 1e-3 * P.max()  # the bodies do bounce in this window
        np.testing.assert_allclose(Q[:, w], Qd, rtol=0, atol=1e-9 * np.abs(Qd).max())
        np.testing.assert_allclose(F[:, w], Fd, rtol=0, atol=1e-9 * np.abs(Fd).max())
    # negative control: the same rule with the bodies' damping left out differs by far more
    Qc, _ = _dense_newmark(
        L, mu, P, off, m, k[0], 0 * c[0], kn, omega[0], zeta[0], v[0], t0[0], T0, dt, n
    )
    assert np.abs(Qc - Q[:, 0]).max() > 1e-3 * np.abs(Qc).max()
