"""The independent vehicle-bridge simulator (bayespinn.vbi): its limits and exactly solvable cases.

- the constant-force limit against today's FE truth (physics.fem through data.synthetic), Exeter preset
- the moving-force closed form of Fryba (undamped simply supported beam) at a high speed
- a sprung axle on a harmonic road: the quarter-car transmissibility, exact
- a sprung axle on the girder against an independent modal (Galerkin) solution integrated by an adaptive
  Runge-Kutta method, the formulation of Biggs (1964, section 8.5) carried to many modes
- entry_time shifts the response exactly; nothing before the entry
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import bayespinn as bp
from bayespinn.config import Axle, Beam, Vehicle, replace
from bayespinn.data.synthetic import simulate as fe_simulate
from bayespinn.vbi import VBISettings, simulate
from bayespinn.vbi.beam import SimBeam
from bayespinn.vbi.crossings import _sub, simulate_crossing
from bayespinn.vbi.road import flat_road, from_components
from bayespinn.vbi.solver import solve


def rel_rms(a, b) -> float:
    return float(np.sqrt(np.mean((np.asarray(a) - b) ** 2)) / np.sqrt(np.mean(np.asarray(b) ** 2)))


@pytest.mark.parametrize("case", ["deflection", "strain"])
def test_constant_force_limit_is_todays_fe_truth(case):
    """model = "forces" on a smooth road: within 0.1 % RMS of the FE truth; 0.5 % off in EI is not."""
    cfg = bp.resolve(case)
    assert not cfg.realistic  # the preset still takes today's FE path
    truth = fe_simulate(cfg, None, seed=3)
    ours = simulate(cfg, None, seed=3)
    assert np.array_equal(ours.x, truth.x) and np.array_equal(ours.t, truth.t)
    assert rel_rms(ours.value_true, truth.value_true) < 1e-3
    # negative control: a girder 0.5 % softer is told apart at this tolerance
    soft = replace(cfg, beam=replace(cfg.beam, EI=cfg.beam.EI * 0.995))
    assert rel_rms(simulate(soft, None, seed=3).value_true, truth.value_true) > 2e-3


def fryba_midspan(beam: Beam, P: float, v: float, t: np.ndarray, n_modes: int = 200) -> np.ndarray:
    """Fryba's closed form of a constant force P crossing an undamped simply supported beam at speed v,
    while it is on the span: w(x, t) = w0 sum_n sin(n pi x / L) [sin(n W t) - (alpha / n) sin(w_n t)]
    / (n^2 (n^2 - alpha^2)), w0 = 2 P L^3 / (pi^4 EI), W = pi v / L, alpha = W / w_1."""
    L, EI = beam.length, beam.EI
    w1 = (math.pi / L) ** 2 * math.sqrt(EI / beam.mass_per_length)
    W = math.pi * v / L
    alpha = W / w1
    n = np.arange(1, n_modes + 1)[:, None]
    terms = (
        np.sin(n * math.pi / 2)
        * (np.sin(n * W * t) - (alpha / n) * np.sin(n**2 * w1 * t))
        / (n**2 * (n**2 - alpha**2))
    )
    return 2 * P * L**3 / (math.pi**4 * EI) * terms.sum(axis=0)


@pytest.mark.parametrize("alpha", [0.1, 0.5])
def test_moving_force_matches_frybas_closed_form(alpha):
    beam = Beam()
    w1 = beam.natural_frequency(1)
    v = alpha * w1 * beam.length / math.pi
    veh = Vehicle(speed=v, axles=(Axle(37e3, 0.0),))
    T = beam.length / v
    cr = solve(SimBeam(beam, 96), veh, flat_road(), 0.0, T, 4000)
    t = np.linspace(0.0, T, 401)
    ours = cr.sample(np.full(t.size, beam.length / 2), t)
    exact = fryba_midspan(beam, 37e3, v, t)
    assert rel_rms(ours, exact) < 1e-3
    # the dynamic part is resolved, not only the static one: the quasi-static curve is far off at 0.5
    static = 37e3 * (v * t) * (beam.length**2 * 3 - 4 * (v * t) ** 2) / (48 * beam.EI)
    static = np.where(v * t <= beam.length / 2, static, static[::-1])
    assert rel_rms(static, exact) > (0.005 if alpha == 0.1 else 0.1)


def test_sprung_axle_on_harmonic_road_has_quarter_car_transmissibility():
    """Body amplitude / road amplitude = sqrt((1 + (2 z r)^2) / ((1 - r^2)^2 + (2 z r)^2)), r = f / f_b,
    f = v n the road's frequency as driven; the contact force swings by m (2 pi f)^2 |z|."""
    f_b, zeta = 2.5, 0.1
    for ratio in (0.6, 1.0, 1.7):
        v = 10.0
        n = ratio * f_b / v  # cycles/m
        veh = Vehicle(
            speed=v, axles=(Axle(40e3, 0.0),), model="sprung", body_frequency=f_b, body_damping=zeta
        )
        approach = 120.0
        # a cosine of amplitude 5 mm whose wavelength is a whole fraction of the profile period
        period = 409.6
        index = max(1, round(n * period))
        n = index / period
        road = from_components(-approach - 1.0, approach + 30.0, [index], [5e-3], [0.3])
        cr = solve(SimBeam(Beam(), 24), veh, road, 0.0, 17.28 / v, 2000, approach)
        late = cr.t_axle < -2.0
        late &= (
            cr.t_axle > cr.t_axle[late].max() - 3.0
        )  # steady state: the last 3 s of the approach
        r = v * n / f_b
        H = math.sqrt((1 + (2 * zeta * r) ** 2) / ((1 - r**2) ** 2 + (2 * zeta * r) ** 2))
        amp = 0.5 * (cr.body[late, 0].max() - cr.body[late, 0].min())
        assert amp == pytest.approx(5e-3 * H, rel=5e-3)
        swing = 0.5 * (cr.force[late, 0].max() - cr.force[late, 0].min())
        m = 40e3 / 9.81
        assert swing == pytest.approx(m * (2 * math.pi * v * n) ** 2 * 5e-3 * H, rel=5e-3)


def modal_sprung_reference(beam: Beam, P, v, f_b, zeta_b, t_eval, n_modes=8):
    """An independent solution of one sprung axle crossing a uniform pinned undamped beam: Galerkin on
    sin(n pi x / L) (the formulation of Biggs 1964, section 8.5, with n_modes modes), the body and the
    modes integrated together by scipy's DOP853 at rtol 1e-10. Returns (midspan deflection, body)."""
    L, mu, EI = beam.length, beam.mass_per_length, beam.EI
    kn = np.arange(1, n_modes + 1) * math.pi / L
    wn2 = kn**4 * EI / mu
    m = P / 9.81
    k = m * (2 * math.pi * f_b) ** 2
    c = 2 * zeta_b * m * (2 * math.pi * f_b)

    def rhs(t, y):
        q, qd, z, zd = y[:n_modes], y[n_modes : 2 * n_modes], y[-2], y[-1]
        x = v * t
        phi, dphi = np.sin(kn * x), kn * np.cos(kn * x)
        uc, ucd = phi @ q, phi @ qd + v * (dphi @ q)
        s = k * (z - uc) + c * (zd - ucd)
        qdd = -wn2 * q + (2 / (mu * L)) * phi * (P + s)
        return np.concatenate([qd, qdd, [zd, -s / m]])

    sol = solve_ivp(rhs, (0, L / v), np.zeros(2 * n_modes + 2), "DOP853", t_eval, rtol=1e-8,
                    atol=1e-12)  # fmt: skip
    mid = np.sin(kn * L / 2) @ sol.y[:n_modes]
    return mid, sol.y[-2]


@pytest.mark.parametrize("f_b", [2.5, 10.0])
def test_sprung_axle_on_girder_matches_independent_modal_solution(f_b):
    """A heavy sprung axle (a sixth of the girder's mass), its bounce below and at the girder's first
    frequency (about 10 Hz), at 20 m/s: midspan deflection and body motion agree within 0.3 %."""
    beam = Beam()
    P, v = 0.17 * beam.mass_per_length * beam.length * 9.81, 20.0
    veh = Vehicle(speed=v, axles=(Axle(P, 0.0),), model="sprung", body_frequency=f_b,
                  body_damping=0.05)  # fmt: skip
    T = beam.length / v
    cr = solve(SimBeam(beam, 48), veh, flat_road(), 0.0, T, 2000)
    t = np.linspace(0.0, T, 301)
    mid_ref, z_ref = modal_sprung_reference(beam, P, v, f_b, 0.05, t)
    mid = cr.sample(np.full(t.size, beam.length / 2), t)
    assert rel_rms(mid, mid_ref) < 3e-3
    body = np.interp(t, cr.t_axle, cr.body[:, 0])
    assert rel_rms(body, z_ref) < 3e-3
    # negative control: the same axle as a constant force is told apart (the interaction matters)
    force = solve(SimBeam(beam, 48), replace(veh, model="forces"), flat_road(), 0.0, T, 1000)
    assert rel_rms(force.sample(np.full(t.size, beam.length / 2), t), mid_ref) > 5e-3


def test_entry_time_shifts_the_response_exactly():
    cfg = bp.resolve(
        "strain",
        {
            "vehicle": {"model": "sprung"},
            "road": {"roughness": "B"},
            "beam": {"damping_ratio": 0.01},
        },
    )
    s = VBISettings(n_elements=48, n_steps=2000)
    tau = 0.65
    a = simulate_crossing(cfg, cfg.vehicle, _sub(0, "road", 0), s)
    b = simulate_crossing(cfg, replace(cfg.vehicle, entry_time=tau), _sub(0, "road", 0), s)
    x = np.repeat([cfg.beam.length / 3, cfg.beam.length / 2], 200)
    t = np.tile(np.linspace(0.0, cfg.duration, 200), 2)
    ua, ub = a.sample(x, t, 0.0, -0.46), b.sample(x, t + tau, 0.0, -0.46)
    assert np.max(np.abs(ua)) > 1e-5
    assert np.allclose(ub, ua, rtol=1e-9, atol=1e-12 * np.max(np.abs(ua)))
    assert np.all(b.sample(x, t * tau / cfg.duration * 0.999, 0.0, -0.46) == 0.0)
    assert np.allclose(b.force, a.force, rtol=1e-9) and np.allclose(b.t_axle - tau, a.t_axle)


def test_forces_model_is_constant_forces_whatever_the_road():
    cfg = bp.resolve("strain", {"road": {"roughness": "C"}})
    s = VBISettings(n_elements=48, n_steps=1000)
    cr = simulate_crossing(cfg, cfg.vehicle, _sub(0, "road", 0), s)
    assert np.all(cr.force == cfg.vehicle.loads) and np.all(cr.body == 0.0)
    smooth = simulate_crossing(
        replace(cfg, road=replace(cfg.road, roughness=0.0)), cfg.vehicle, 0, s
    )
    assert np.array_equal(cr.U, smooth.U)
    sprung = simulate_crossing(cfg, replace(cfg.vehicle, model="sprung"), _sub(0, "road", 0), s)
    # the sprung axles on a class C road: dynamic forces of several percent, mean still the static
    dyn = sprung.force / cfg.vehicle.loads - 1.0
    assert 0.01 < np.std(dyn) < 0.5 and abs(np.mean(dyn)) < 0.02


@pytest.mark.slow
def test_real_girder_matches_the_analysis_girder_fe():
    """Segment EI (a 30 % softer fourth fifth) and bearing springs (5e8 N m/rad left, clamped right),
    constant forces: within 0.1 % RMS (deflection) and 0.3 % (strain) of the analysis' own girder FE
    (physics.girder via data.synthetic); the same girder without its springs is far off."""
    doc = {
        "beam": {
            "EI": [1.03361e9, 1.03361e9, 1.03361e9, 7.2353e8, 1.03361e9],
            "rotational_stiffness": [5e8, "fixed"],
        }
    }
    s = VBISettings(n_elements=100, n_steps=8000)
    for case, tol in (("deflection", 1e-3), ("strain", 3e-3)):
        cfg = bp.resolve(case, doc)
        truth = fe_simulate(cfg, None, seed=1).value_true
        assert rel_rms(simulate(cfg, None, seed=1, settings=s).value_true, truth) < tol
        pinned = replace(cfg, beam=replace(cfg.beam, rotational_stiffness=(0.0, 0.0)))
        assert rel_rms(simulate(pinned, None, seed=1, settings=s).value_true, truth) > 10 * tol


def test_beam_frequencies_and_rayleigh_damping():
    beam = Beam(damping_ratio=0.02)
    sb = SimBeam(beam, 48)
    assert sb.omega[0] == pytest.approx(beam.natural_frequency(1), rel=1e-6)
    assert sb.omega[1] == pytest.approx(beam.natural_frequency(2), rel=1e-5)
    a, b = sb.rayleigh
    for w in sb.omega:
        assert a / (2 * w) + b * w / 2 == pytest.approx(0.02, rel=1e-12)
    # clamping both ends raises the first frequency by (4.730 / pi)^2
    clamped = SimBeam(replace(beam, rotational_stiffness=(math.inf, math.inf)), 48)
    assert clamped.omega[0] / sb.omega[0] == pytest.approx((4.730041 / math.pi) ** 2, rel=1e-5)
