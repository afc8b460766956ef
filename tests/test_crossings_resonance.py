"""The crossing reference's resonant terms (`bayespinn.crossings.resonance`): the coupled first mode against
two limits with closed forms (massless bodies leave the bare girder's mode; rigid suspensions add each body's
mass at its axle's mode-shape value), the weights' sds against their stated normalisation (the modal
coordinate's mean square over the window is (rho A)^2) and their spectrum's peak at the oscillator's
frequency, and the term's place in the fluctuating-force likelihood: a resonant first-mode response in the
data is explained by it, and without it the same data are far less likely."""

from __future__ import annotations

import math

import numpy as np
import pytest
from gauges import three_gauges

from bayespinn.crossings.forward import CrossingModel
from bayespinn.crossings.resonance import Resonance, coupled_mode

L, MU, EI = 20.0, 4000.0, 5e9
W1 = (math.pi / L) ** 2 * math.sqrt(EI / MU)
OFFSETS = np.array([0.0, 4.0])


def test_massless_bodies_leave_the_bare_girder_mode():
    w, z = coupled_mode(L, MU, [1e-6, 1e-6], OFFSETS, EI, 0.01, 2.5, 0.1)
    assert w[0] == pytest.approx(W1, rel=1e-9) and z[0] == pytest.approx(0.01, rel=1e-6)


def test_rigid_suspensions_add_the_bodies_mass():
    loads = np.array([60e3, 90e3])
    w, _ = coupled_mode(L, MU, loads, OFFSETS, EI, 0.01, 2000.0, 1e-4)
    phi = np.sin(math.pi * (L / 2 + 2.0 - OFFSETS) / L)
    M1 = MU * L / 2
    expect = W1 * math.sqrt(M1 / (M1 + np.sum(loads / 9.81 * phi**2)))
    assert w[0] == pytest.approx(expect, rel=1e-3)
    # the negative control: the bare girder's frequency is far outside that tolerance
    assert abs(W1 / expect - 1) > 0.05


def test_coupled_mode_is_vectorised_row_by_row():
    EIs, fbs = np.array([4e9, 5e9, 6e9]), np.array([1.5, 2.5, 3.5])
    w, z = coupled_mode(L, MU, [60e3, 90e3], OFFSETS, EIs, 0.01, fbs, 0.1)
    for i in range(3):
        wi, zi = coupled_mode(L, MU, [60e3, 90e3], OFFSETS, EIs[i], 0.01, fbs[i], 0.1)
        assert (w[i], z[i]) == pytest.approx((wi[0], zi[0]), rel=1e-12)


@pytest.fixture(scope="module")
def gauges():
    """Two strain gauges and a deflection point read at 200 Hz for 4 s, the lorry entering at 0.5 s."""
    loads = np.array([60e3, 90e3])
    model = CrossingModel(L, MU, loads, OFFSETS, *three_gauges(4.0, 200), n_modes=8)
    return model, Resonance.build(model, 10.0, 0.5, EI)


def test_sds_give_the_stated_mean_square(gauges):
    model, res = gauges
    q1, q2 = 0.07, 0.2
    d = res.sds(np.array([EI]), 0.015, np.array([q1]), np.array([q2]), np.array([0.03]))[0]
    n1 = res.freqs[0].size
    A1 = 2 * 150e3 / (MU * L * W1**2)
    A2 = A1 / 16
    tau = np.linspace(0, res.window, 20001)
    for a, dd, target in ((res.freqs[0], d[:n1], q1 * A1), (res.freqs[1], d[n1:], q2 * A2)):
        ms = np.sum(dd**2 * np.mean(np.sin(np.outer(tau, a)) ** 2, axis=0))
        assert math.sqrt(ms) == pytest.approx(target, rel=0.02)
    # the spectrum's peak: the bare first mode without bodies, the coupled one with them
    bare = res.freqs[0][np.argmax(d[:n1])]
    assert bare == pytest.approx(W1, abs=res.freqs[0][1] - res.freqs[0][0])
    body = (np.array([2.0]), np.array([0.1]))
    dc = res.sds(np.array([EI]), 0.015, np.array([q1]), np.array([q2]), np.array([0.03]), body)[0]
    wc, _ = coupled_mode(L, MU, model.loads, OFFSETS, EI, 0.015, 2.0, 0.1)
    peak = res.freqs[0][np.argmax(dc[:n1])]
    assert peak == pytest.approx(wc[0], abs=res.freqs[0][1] - res.freqs[0][0])
    assert abs(wc[0] / W1 - 1) > 0.02  # the negative control: coupling moves the mode


def test_columns_vanish_before_the_entry_and_follow_the_mode_shape(gauges):
    model, res = gauges
    R = res.columns(model, np.array([0.5, 0.8]))  # (2, P, K)
    assert R.shape == (2, model.t.size, res.n_columns)
    assert np.all(R[0][model.t < 0.5] == 0) and np.all(R[1][model.t < 0.8] == 0)
    assert np.any(R[0][(model.t >= 0.5) & (model.t < 0.8)] != 0)
    n1 = res.freqs[0].size
    k1 = math.pi / L
    # the first mode's columns at the 6 m strain gauge: -a_xx k^2 sin(k x) sin(a (t - t0))
    sel = (model.x == 6.0) & (model.t > 1.0)
    expect = 0.4 * k1**2 * math.sin(k1 * 6.0) * np.sin(np.outer(model.t[sel] - 0.5, res.freqs[0]))
    assert np.allclose(R[0][sel][:, :n1], expect, rtol=1e-12, atol=0)


def test_a_resonant_response_is_what_the_term_explains(gauges):
    """Data: noise plus a first-mode free vibration from the entry on. The evidence with the resonant
    term beats the evidence without it by far (the negative control), and the term's conditional mean
    recovers the vibration to well under the noise."""
    from bayespinn.crossings.likelihood import woodbury_loglik

    model, res = gauges
    rng = np.random.default_rng(5)
    tau = model.t - 0.5
    k1 = math.pi / L
    shape = np.sin(k1 * model.x) * (model.a_u - model.a_xx * k1**2)
    wd = W1 * math.sqrt(1 - 0.02**2)
    q = 2e-3 * np.exp(-0.02 * W1 * tau) * np.sin(wd * tau) * (tau >= 0)
    truth = shape * q
    sig = 0.1 * float(np.std(truth))
    y = truth + sig * rng.standard_normal(truth.size)
    A1 = 2 * 150e3 / (MU * L * W1**2)
    d = res.sds(np.array([EI]), 0.02, np.array([2e-3 / A1]), np.array([0.01]), np.array([0.02]))
    B = res.columns(model, np.array([0.5])) * d[:, None, :]
    with_term = woodbury_loglik(y[None], B, np.array([sig**2]))[0]
    without = -0.5 * float(y @ y) / sig**2
    assert with_term - without > 1000
    w = np.linalg.solve(B[0].T @ B[0] + sig**2 * np.eye(B.shape[2]), B[0].T @ y)
    assert float(np.std(B[0] @ w - truth)) < 0.3 * sig


def test_an_undamped_mode_takes_the_limit_of_light_damping(gauges):
    _, res = gauges
    one = np.ones(1)

    def sds(z):
        return res.sds(one * EI, z, one * 0.05, one * 0.05, one * z)[0]

    d0 = sds(0.0)
    assert np.all(np.isfinite(d0)) and np.all(d0 > 0)
    assert np.allclose(d0, sds(1e-5), rtol=1e-3)
    assert not np.allclose(d0, sds(0.05), rtol=0.1)  # the negative control: real damping widens it
