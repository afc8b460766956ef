"""Real girders: the segment/spring FE model against closed forms, and the reduced modal surrogate
against time integration of the full FE model."""

import dataclasses
import math

import numpy as np
import pytest

from bayespinn.config import Axle, Beam, Vehicle, preset
from bayespinn.errors import InputError
from bayespinn.physics.fe_modal import GirderModalModel
from bayespinn.physics.fem import FEBeam, FESettings
from bayespinn.physics.girder import Girder, GirderFE, hermite
from bayespinn.physics.modal import ModalModel

L, EI, MU, DEPTH = 17.28, 1.03361e9, 289.0, 0.9266
PIN, CLAMP = (0.0, 0.0), (math.inf, math.inf)
PROPPED = (math.inf, 0.0)  # clamped at x = 0, pinned at x = L
#: damaged Exeter girder: segment 4 of 5 at 70 %
DAMAGED = (EI, EI, EI, 0.7 * EI, EI)
BEARINGS = (2 * EI / L, 2 * EI / L)
#: fe_modal against Newmark on the full FE model (issue "Real girders I": 0.1 % RMS)
SURROGATE_TOL = 1e-3
#: beta L of the first three modes
BETA_L = {
    PIN: (math.pi, 2 * math.pi, 3 * math.pi),
    CLAMP: (4.730040745, 7.853204624, 10.99560784),
    PROPPED: (3.926602312, 7.068582745, 10.21017612),
}


def _rel_rms(a, b):
    return float(np.sqrt(np.mean((a - b) ** 2)) / np.sqrt(np.mean(b**2)))


def _order(errors, ratio):
    e = np.asarray(errors, float)
    return np.log(e[:-1] / e[1:]) / np.log(ratio)


def _girder(ks=PIN, EI_=(EI,), zeta=0.0):
    return Girder(L, EI_, MU, DEPTH, damping_ratio=zeta, rotational_stiffness=ks)


def _deflect(fe, F, x):
    return float((fe.rows([x]) @ fe.static(F))[0])


def _udl_vector(fe, q):
    """Consistent load vector of a uniform load q [N/m] (3-point Gauss per element: exact for cubics)."""
    g, w = np.polynomial.legendre.leggauss(3)
    xs = ((np.arange(fe.n_elements)[:, None] + 0.5 * (g[None, :] + 1)) * fe.h).ravel()
    ws = np.tile(0.5 * fe.h * w, fe.n_elements)
    return q * np.asarray(fe.rows(xs).T @ ws).ravel()


def _udl_exact(ks, x, q):
    if ks == PIN:
        return q * x * (L**3 - 2 * L * x**2 + x**3) / (24 * EI)
    if ks == CLAMP:
        return q * x**2 * (L - x) ** 2 / (24 * EI)
    return q * x**2 * (3 * L**2 - 5 * L * x + 2 * x**2) / (48 * EI)  # clamped at 0, pinned at L


# ---- Girder -------------------------------------------------------------------------------------


def test_girder_validation_names_the_field():
    with pytest.raises(InputError, match=r"beam\.EI\[3\]"):
        Girder(L, (EI, EI, EI, 0.0, EI), MU, DEPTH)
    with pytest.raises(InputError, match=r"beam\.EI\[1\]"):
        Girder(L, (EI, "x"), MU, DEPTH)
    with pytest.raises(InputError, match=r"beam\.EI"):
        Girder(L, (), MU, DEPTH)
    with pytest.raises(InputError, match=r"beam\.rotational_stiffness\[0\]"):
        _girder((-1.0, 0.0))
    with pytest.raises(InputError, match=r"beam\.rotational_stiffness\[1\]"):
        _girder((0.0, "stiff"))
    with pytest.raises(InputError, match=r"beam\.rotational_stiffness\[1\]"):
        _girder((0.0, math.nan))
    with pytest.raises(InputError, match=r"beam\.rotational_stiffness"):
        _girder((0.0,))
    with pytest.raises(InputError, match=r"beam\.length"):
        Girder(-1.0, (EI,), MU, DEPTH)
    with pytest.raises(InputError, match=r"beam\.damping_ratio"):
        _girder(zeta=1.0)
    with pytest.raises(InputError, match=r"fe\.n_elements"):
        GirderFE(_girder(), 1)


def test_girder_helpers():
    g = _girder(CLAMP, DAMAGED)
    assert g.n_segments == 5 and g.clamped == (True, True)
    np.testing.assert_allclose(g.segment_edges(), np.linspace(0, L, 6))
    assert g.ei_at(0.7 * L) == pytest.approx(0.7 * EI)  # edge 0.6 L..0.8 L: segment 4
    assert g.ei_at(0.6 * L + 1e-9) == pytest.approx(0.7 * EI)
    assert g.ei_at(L) == pytest.approx(EI)
    assert Girder(L, EI, MU, DEPTH).EI == (EI,)  # a bare number is one segment
    b = Beam(damping_ratio=0.03)
    gb = Girder.from_beam(b, rotational_stiffness=BEARINGS)
    assert gb.EI == (b.EI,) and gb.damping_ratio == 0.03 and gb.rotational_stiffness == BEARINGS
    assert Girder.from_beam(b, EI=DAMAGED).n_segments == 5
    # elements rounded up to a multiple of the segment count: edges on nodes
    fe = GirderFE(g, 96)
    assert fe.n_elements == 100
    assert fe.ndof == 2 * 101 - 4  # w at both supports and both clamped rotations removed


# ---- FE against closed forms ----------------------------------------------------------------------


@pytest.mark.parametrize(
    "ks,coef", [(PIN, 1 / 48), (CLAMP, 1 / 192), (PROPPED, 7 / 768)], ids=["pin", "clamp", "prop"]
)
def test_point_load_at_node_exact(ks, coef):
    """Hermite elements are nodally exact: midspan deflection under a midspan point load."""
    P = 1.0e4
    for ne in (2, 6, 96):
        fe = GirderFE(_girder(ks), ne)
        u = _deflect(fe, fe.point_load(L / 2, P), L / 2)
        assert u == pytest.approx(coef * P * L**3 / EI, rel=1e-9)


@pytest.mark.parametrize("ks", [PIN, CLAMP, PROPPED], ids=["pin", "clamp", "prop"])
def test_static_between_nodes_converges(ks):
    """Between nodes the FE field is the cubic interpolant of exact nodal values: a uniform load's
    deflection at element midpoints is off by q h^4 / (384 EI) (order 4); under a point load between
    nodes by P xi^3 (1 - xi)^3 h^3 / (3 EI) (order 3)."""
    q, P = 5.0e3, 1.0e4
    errs = []
    for ne in (4, 8, 16, 32):
        fe = GirderFE(_girder(ks), ne)
        xm = (np.arange(ne) + 0.5) * fe.h
        u = fe.rows(xm) @ fe.static(_udl_vector(fe, q))
        err = np.max(np.abs(u - _udl_exact(ks, xm, q)))
        assert err == pytest.approx(q * fe.h**4 / (384 * EI), rel=1e-6)
        errs.append(err)
    assert np.all(np.abs(_order(errs, 2.0) - 4.0) < 0.05), errs
    errs = []
    for ne in (4, 16, 64):  # a = L / 3 sits at xi = 1/3 of its element on all three meshes
        fe = GirderFE(_girder(ks), ne)
        a = L / 3
        exact = _deflect(GirderFE(_girder(ks), 3), GirderFE(_girder(ks), 3).point_load(a, P), a)
        err = exact - _deflect(fe, fe.point_load(a, P), a)
        assert err == pytest.approx(P * (1 / 3) ** 3 * (2 / 3) ** 3 * fe.h**3 / (3 * EI), rel=1e-6)
        errs.append(err)
    assert np.all(np.abs(_order(errs, 4.0) - 3.0) < 0.05), errs


def test_stepped_girder_static():
    """Pinned, left half EI1 and right half EI2, midspan load: delta = P L^3 / 96 (1/EI1 + 1/EI2)
    (virtual work); a stiffer segment deflects less, a weaker one more."""
    P = 1.0e4
    fe = GirderFE(_girder(PIN, (EI, 2.5 * EI)), 10)
    u = _deflect(fe, fe.point_load(L / 2, P), L / 2)
    assert u == pytest.approx(P * L**3 / 96 * (1 / EI + 1 / (2.5 * EI)), rel=1e-9)
    mid = []
    for EI_ in ((EI,) * 5, (EI, EI, 2 * EI, EI, EI), (EI, EI, 0.5 * EI, EI, EI)):
        fe = GirderFE(_girder(BEARINGS, EI_))
        mid.append(_deflect(fe, fe.point_load(0.45 * L, P), 0.5 * L))
    assert mid[1] < mid[0] < mid[2]


def test_equal_segments_equal_uniform():
    for ks in (PIN, BEARINGS, CLAMP):
        one, five = GirderFE(_girder(ks), 100), GirderFE(_girder(ks, (EI,) * 5), 100)
        np.testing.assert_allclose(five.K, one.K, rtol=0, atol=1e-12 * np.abs(one.K).max())
        np.testing.assert_array_equal(five.M, one.M)
        w1, p1 = one.eigen(4)
        w5, p5 = five.eigen(4)
        np.testing.assert_allclose(w5, w1, rtol=1e-10)
        np.testing.assert_allclose(np.abs(p5), np.abs(p1), atol=1e-8 * np.abs(p1).max())


@pytest.mark.parametrize("ks", [PIN, CLAMP, PROPPED], ids=["pin", "clamp", "prop"])
def test_frequencies_converge_at_order_four(ks):
    """omega_n = (beta_n L)^2 / L^2 sqrt(EI / mu); consistent-mass Hermite elements: error ~ h^4."""
    exact = np.array(BETA_L[ks]) ** 2 / L**2 * math.sqrt(EI / MU)
    errs = [GirderFE(_girder(ks), ne).eigen(3)[0] / exact - 1 for ne in (6, 12, 24)]
    assert np.all(np.array(errs) > 0)  # Rayleigh-Ritz: from above
    order = np.log(np.array(errs[:-1]) / np.array(errs[1:])) / np.log(2.0)
    assert np.all((order > 3.5) & (order < 4.5)), order
    w, phi = GirderFE(_girder(ks)).eigen(3)  # default mesh
    assert np.max(np.abs(w / exact - 1)) < 1e-6
    fe = GirderFE(_girder(ks))
    np.testing.assert_allclose(phi.T @ fe.M @ phi, np.eye(3), atol=1e-10)


def test_springs_limits():
    """k -> 0 reproduces the pinned girder, k -> large the clamped one (difference ~ EI / (k L))."""
    P = 1.0e4
    fe_pin, fe_cl = GirderFE(_girder(PIN)), GirderFE(_girder(CLAMP))
    u_pin = _deflect(fe_pin, fe_pin.point_load(0.4 * L, P), L / 2)
    u_cl = _deflect(fe_cl, fe_cl.point_load(0.4 * L, P), L / 2)
    diffs = []
    for r in (1e-4, 1e-6, 1e-8):
        soft = GirderFE(_girder((r * EI / L,) * 2))
        diffs.append(1 - _deflect(soft, soft.point_load(0.4 * L, P), L / 2) / u_pin)
    assert diffs[2] < 1e-8 and np.all(np.diff(np.log10(diffs)) < -1.9), diffs
    diffs = []
    for r in (1e4, 1e6, 1e8):
        stiff = GirderFE(_girder((r * EI / L,) * 2))
        diffs.append(_deflect(stiff, stiff.point_load(0.4 * L, P), L / 2) / u_cl - 1)
    assert diffs[2] < 1e-6 and np.all(np.diff(np.log10(diffs)) < -1.9), diffs
    w_pin, w_cl = fe_pin.eigen(3)[0], fe_cl.eigen(3)[0]
    np.testing.assert_allclose(
        GirderFE(_girder((1e-6 * EI / L,) * 2)).eigen(3)[0], w_pin, rtol=1e-6
    )
    np.testing.assert_allclose(GirderFE(_girder((1e6 * EI / L,) * 2)).eigen(3)[0], w_cl, rtol=3e-5)


def test_hermite_derivatives_consistent():
    xi = np.linspace(0, 1, 7)
    h, d = 0.3, 1e-6
    for k in range(3):
        num = (hermite(xi + d, h, k) - hermite(xi - d, h, k)) / (2 * d * h)
        np.testing.assert_allclose(num, hermite(xi, h, k + 1), rtol=1e-6, atol=1e-6)


def test_uniform_pinned_moving_load_matches_fem_and_modal(exeter):
    beam, veh = exeter.beam, exeter.vehicle
    rng = np.random.default_rng(3)
    x, t = rng.uniform(0, beam.length, 100), rng.uniform(0, exeter.duration, 100)
    T = exeter.duration
    got = GirderFE(Girder.from_beam(beam), 96).solve(veh, T, 12000).sample(x, t)
    fem = FEBeam(beam, FESettings(96, 12000)).solve(veh, T).sample(x, t)
    assert _rel_rms(got, fem) < 1e-8  # the same discretisation
    ref = ModalModel(beam, veh, x, t, n_modes=40).predict(beam.EI)
    assert _rel_rms(got, ref) < 1.5e-4  # measured 8.3e-5: Newmark's time error


# ---- the reduced modal surrogate -------------------------------------------------------------------


def _observations(case, T, rng):
    """100 random (x, t) deflections, or strain at 4 gauges (0.3, 0.45, 0.55, 0.7 L) at 200 Hz."""
    if case == "deflection":
        return rng.uniform(0, L, 100), rng.uniform(0, T, 100), 1.0, 0.0
    tt = np.arange(0.0, T, 1 / 200)
    xs = np.array([0.3, 0.45, 0.55, 0.7]) * L
    return np.repeat(xs, tt.size), np.tile(tt, 4), 0.0, -DEPTH / 2


def _three_axles(girder):
    """A three-axle vehicle with alpha = v / (2 f1 L) = 0.1 on this girder."""
    f1 = GirderFE(girder).eigen(1)[0][0] / (2 * math.pi)
    return Vehicle(0.2 * f1 * L, (Axle(60e3, 0.0), Axle(80e3, 3.0), Axle(80e3, 4.3)))


@pytest.mark.parametrize("ks", [BEARINGS, CLAMP], ids=["bearings", "clamped"])
@pytest.mark.parametrize(
    "case,vehicle",
    [("deflection", "preset"), ("strain", "preset"), ("deflection", "3axle"), ("strain", "3axle")],
)
def test_surrogate_matches_newmark_damaged_exeter(ks, case, vehicle):
    """Damaged Exeter girder: fe_modal against 20 000 Newmark steps of the full FE model.

    Measured: bearings 5.1e-5 / 4.1e-4 (preset deflection / strain), 6.5e-6 / 3.3e-4 (3 axles);
    clamped 1.9e-6 / 9.2e-6, 5.3e-7 / 1.4e-5. The differences are Newmark's: for the bearings'
    strain it falls to 1.5e-4 at 80 000 steps."""
    g = _girder(ks, DAMAGED)
    veh = preset(case).vehicle if vehicle == "preset" else _three_axles(g)
    T = veh.duration(L)
    x, t, a_u, a_xx = _observations(case, T, np.random.default_rng(5))
    ref = GirderFE(g).solve(veh, T, 20000).sample(x, t, a_u, a_xx)
    got = GirderModalModel(g, veh, x, t, a_u, a_xx).predict(np.array(DAMAGED))[0]
    assert _rel_rms(got, ref) < SURROGATE_TOL
    if ks == BEARINGS:  # the same girder with the springs as parameters
        m = GirderModalModel(g, veh, x, t, a_u, a_xx, infer_springs=True)
        assert _rel_rms(m.predict(np.array(DAMAGED), np.array(BEARINGS))[0], ref) < SURROGATE_TOL


def test_surrogate_damped_free_vibration_matches_newmark():
    """zeta = 0.02 and times up to 1.5 T (free vibration after the axle left)."""
    g = _girder(BEARINGS, DAMAGED, zeta=0.02)
    veh = preset("deflection").vehicle
    T = 1.5 * veh.duration(L)
    x, t, _, _ = _observations("deflection", T, np.random.default_rng(6))
    ref = GirderFE(g).solve(veh, T, 30000).sample(x, t)
    assert _rel_rms(GirderModalModel(g, veh, x, t).predict(np.array(DAMAGED))[0], ref) < 2e-4


@pytest.mark.parametrize("zeta", [0.0, 0.02])
def test_surrogate_uniform_pinned_matches_closed_form(exeter, exeter_strain, zeta):
    """Against the closed-form `ModalModel`, to 1.3 T. Deflection: 2.5e-7 (zeta 0), 2.4e-8 (0.02).
    Strain: 4.4e-4 at 96 elements, 1.7e-4 at 192: the FE curvature is linear in each element, so it
    is off while an axle is in a gauge's element (the same FE error as `fem.py`'s 0.07 %)."""
    beam = dataclasses.replace(exeter.beam, damping_ratio=zeta)
    g = Girder.from_beam(beam)
    rng = np.random.default_rng(3)
    T = 1.3 * exeter.duration
    x, t = rng.uniform(0, L, 100), rng.uniform(0, T, 100)
    ref = ModalModel(beam, exeter.vehicle, x, t, n_modes=60).predict(beam.EI)
    got = GirderModalModel(g, exeter.vehicle, x, t).predict([beam.EI])[0]
    assert _rel_rms(got, ref) < 2e-6
    veh = exeter_strain.vehicle
    tt = np.arange(0.0, 1.3 * exeter_strain.duration, 1 / 200)
    s = exeter_strain.sensors
    x = np.repeat([q.x for q in s], tt.size)
    t = np.tile(tt, len(s))
    a_xx = np.repeat([-q.y for q in s], tt.size)
    ref = ModalModel(beam, veh, x, t, 0.0, a_xx, n_modes=60).predict(beam.EI)
    errs = [
        _rel_rms(
            GirderModalModel(g, veh, x, t, 0.0, a_xx, n_elements=ne).predict([beam.EI])[0], ref
        )
        for ne in (96, 192)
    ]
    assert errs[0] < 1e-3 and errs[1] < 0.5 * errs[0], errs


@pytest.mark.parametrize("case", ["deflection", "strain"])
def test_ritz_basis_matches_exact_fe_modes(case):
    """Over a wide spread of parameters (EI_s x e^(0.5 N(0,1)), springs x e^(1.5 N(0,1))), the reduced
    basis reproduces the surrogate built on every FE dof (exact FE modes); measured <= 1.7e-5."""
    rng = np.random.default_rng(7)
    g = _girder(BEARINGS, DAMAGED)
    veh = preset(case).vehicle
    x, t, a_u, a_xx = _observations(case, veh.duration(L), rng)
    W = 16
    EIw = np.array(DAMAGED) * np.exp(0.5 * rng.standard_normal((W, 5)))
    ksw = np.array(BEARINGS) * np.exp(1.5 * rng.standard_normal((W, 2)))
    full = GirderModalModel(g, veh, x, t, a_u, a_xx, infer_springs=True, basis="full")
    ritz = GirderModalModel(g, veh, x, t, a_u, a_xx, infer_springs=True)
    assert ritz.r < 40
    a, b = ritz.predict(EIw, ksw), full.predict(EIw, ksw)
    err = np.sqrt(np.mean((a - b) ** 2, axis=1) / np.mean(b**2, axis=1))
    assert err.max() < 1e-4, err


def test_static_part_is_the_fe_static_solution():
    """The flexibility form equals K(theta)^-1 F of the assembled FE model, springs pinned to clamped."""
    rng = np.random.default_rng(8)
    veh = preset("strain").vehicle
    x, t = rng.uniform(0, L, 12), rng.uniform(0, veh.duration(L), 12)
    for ks in (PIN, BEARINGS, CLAMP, (math.inf, 3e7)):
        g = _girder(ks, DAMAGED)
        m = GirderModalModel(g, veh, x, t, 1.0, 0.3, n_modes=2)
        EIw = np.array(DAMAGED) * np.exp(0.4 * rng.standard_normal((2, 5)))
        got = m.static_part(EIw, np.broadcast_to(np.array(ks), (2, 2)))
        for w in range(2):
            fe = GirderFE(dataclasses.replace(g, EI=tuple(EIw[w])))
            ref = [
                (fe.rows([x[p]], 1.0, 0.3) @ fe.static(fe.load_vector(veh, t[p])))[0]
                for p in range(x.size)
            ]
            np.testing.assert_allclose(got[w], ref, rtol=0, atol=1e-7 * np.max(np.abs(ref)))


def test_predict_batching_load_factor_and_springs():
    rng = np.random.default_rng(9)
    g = _girder(BEARINGS, DAMAGED)
    veh = preset("strain").vehicle
    x, t, a_u, a_xx = _observations("strain", veh.duration(L), rng)
    m = GirderModalModel(g, veh, x, t, a_u, a_xx, infer_springs=True)
    EIw = np.array(DAMAGED) * np.exp(0.2 * rng.standard_normal((3, 5)))
    ksw = np.array(BEARINGS) * np.exp(0.5 * rng.standard_normal((3, 2)))
    lf = np.array([0.9, 1.0, 1.2])
    batch = m.predict(EIw, ksw, lf)
    for w in range(3):
        one = m.predict(EIw[w], ksw[w], lf[w])[0]
        np.testing.assert_allclose(batch[w], one, rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(one, lf[w] * m.predict(EIw[w], ksw[w])[0], rtol=1e-12)
    fixed = GirderModalModel(g, veh, x, t, a_u, a_xx)  # springs fixed at the template's
    assert _rel_rms(m.predict(DAMAGED, BEARINGS)[0], fixed.predict(DAMAGED)[0]) < 1e-6
    # a very stiff inferred spring approaches the clamped girder
    cl = GirderModalModel(_girder(CLAMP, DAMAGED), veh, x, t, a_u, a_xx).predict(DAMAGED)[0]
    assert _rel_rms(m.predict(DAMAGED, (1e6 * EI / L,) * 2)[0], cl) < 1e-4
    # more modes change little (mode acceleration: the static part is exact)
    m20 = GirderModalModel(g, veh, x, t, a_u, a_xx, n_modes=20)
    assert _rel_rms(fixed.predict(DAMAGED)[0], m20.predict(DAMAGED)[0]) < 1e-4


def test_surrogate_validation():
    g = _girder(BEARINGS, DAMAGED)
    veh = preset("deflection").vehicle
    x, t = np.array([1.0, 2.0]), np.array([0.1, 0.2])
    with pytest.raises(InputError, match="x"):
        GirderModalModel(g, veh, [1.0, L + 1], t)
    with pytest.raises(InputError, match="t"):
        GirderModalModel(g, veh, x, [-0.1, 0.2])
    with pytest.raises(InputError, match="n_modes"):
        GirderModalModel(g, veh, x, t, n_modes=0)
    with pytest.raises(InputError, match="basis"):
        GirderModalModel(g, veh, x, t, basis="exact")
    with pytest.raises(InputError, match="vehicle"):
        GirderModalModel(g, "truck", x, t)
    m = GirderModalModel(g, veh, x, t)
    with pytest.raises(InputError, match="EI"):
        m.predict(np.ones((2, 4)))
    with pytest.raises(InputError, match="EI"):
        m.predict(np.array([DAMAGED[:4] + (-1.0,)]))
    with pytest.raises(InputError, match="springs"):
        m.predict(DAMAGED, BEARINGS)  # not inferred
    mi = GirderModalModel(g, veh, x, t, infer_springs=True)
    with pytest.raises(InputError, match="springs"):
        mi.predict(DAMAGED, (-1.0, 0.0))
    with pytest.raises(InputError, match="springs"):
        mi.predict(DAMAGED, (math.inf, 0.0))
    with pytest.raises(InputError, match="load_factor"):
        mi.predict(DAMAGED, BEARINGS, math.nan)
    clamped = GirderModalModel(_girder(CLAMP, DAMAGED), veh, x, t, infer_springs=True)
    with pytest.raises(InputError, match="springs"):
        clamped.predict(DAMAGED)  # the template's infinite springs cannot be inferred values
    assert np.all(np.isfinite(clamped.predict(DAMAGED, (1e3 * EI / L,) * 2)))
