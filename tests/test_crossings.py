"""The crossing reference (`bayespinn.crossings`): its forward model against today's modal model and an
independent finite-element solve with time-varying axle forces, its Woodbury likelihood against the dense
Gaussian, the refusals, and that nothing declared leaves today's path untouched. The posteriors' recovery
tests are in test_crossings_posterior.py."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.stats import multivariate_normal

import bayespinn as bp
from bayespinn.crossings import check_crossings, crossings_reference, needs_crossings
from bayespinn.crossings.forward import CrossingModel, basis_functions
from bayespinn.crossings.likelihood import cho_solve, tri_solve, woodbury_loglik
from bayespinn.data.synthetic import sample_layout
from bayespinn.errors import InputError
from bayespinn.methods import REFERENCE_KEY
from bayespinn.physics.fem import FEBeam, FESettings
from bayespinn.physics.modal import ModalModel
from bayespinn.uq.sampler import MCMCSettings

pytestmark = pytest.mark.filterwarnings("ignore:.*did not meet R-hat:RuntimeWarning")
SMOKE = MCMCSettings(n_walkers=16, n_groups=2, min_steps=250, tau_factor=10.0)


def _model(cfg, data, **kw):
    a_u, a_xx = data.weights
    v = cfg.vehicle
    return CrossingModel(
        cfg.beam.length,
        cfg.beam.mass_per_length,
        v.loads,
        v.offsets,
        data.x,
        data.t,
        a_u,
        a_xx,
        **kw,
    )


@pytest.mark.parametrize("case", ["deflection", "strain"])
def test_constant_forces_equal_modal_model(case):
    """Constant forces, the stated speed and t0 = 0: today's closed-form modal model to rounding, damped or
    not; a clock shifted by t0 with entry time t0 gives the same numbers."""
    cfg = bp.resolve(case)
    beam = dataclasses.replace(cfg.beam, damping_ratio=0.02)
    data = sample_layout(cfg, 1)  # where and when: the values play no part
    a_u, a_xx = data.weights
    ref = ModalModel(beam, cfg.vehicle, data.x, data.t, a_u, a_xx, n_modes=12).predict(
        np.array([0.9e9, 1.1e9])
    )
    mine = _model(cfg, data, n_modes=12).predict([0.9e9, 1.1e9], 0.02, cfg.vehicle.speed, 0.0)
    assert np.max(np.abs(mine - ref)) <= 1e-12 * np.max(np.abs(ref))
    shifted = dataclasses.replace(data, t=data.t + 0.7)
    later = _model(cfg, shifted, n_modes=12).predict([0.9e9, 1.1e9], 0.02, cfg.vehicle.speed, 0.7)
    assert np.max(np.abs(later - ref)) <= 1e-12 * np.max(np.abs(ref))


def _fe_fluctuating(beam, loads, offsets, v, t0, w, M, t_end, n_el=96, n_steps=6000):
    """An independent solve: Hermite beam elements and Newmark time stepping (`physics.fem`) under point
    forces P_j (1 + sum_m w_jm phi_m(tau_j)), the forces spread to the nodes by the cubic shape functions."""
    fe = FEBeam(beam, FESettings(n_el, n_steps))
    h, L = fe.h, beam.length
    Te = L / v

    def force(t):
        F = np.zeros(fe.ndof)
        for j, (P, o) in enumerate(zip(loads, offsets, strict=True)):
            tau = t - t0 - o / v
            a = v * tau
            if 0.0 <= a <= L:
                phi = basis_functions(np.array([[tau]]), np.array([Te]), M)[0, :, 0]
                e = min(int(a / h), n_el - 1)
                xi = (a - e * h) / h
                N = [1 - 3 * xi**2 + 2 * xi**3, h * (xi - 2 * xi**2 + xi**3), 3 * xi**2 - 2 * xi**3]
                N.append(h * (xi**3 - xi**2))
                F[2 * e : 2 * e + 4] += P * (1.0 + phi @ w[j]) * np.array(N)
        return F[fe.free]

    return fe.solve_forced(force, t_end, n_steps)


def test_force_basis_responses_match_finite_elements():
    """The responses to the force basis, weighted, equal a finite-element solve with those time-varying
    forces (strain gauges, damped girder, a recording that starts before the entry)."""
    cfg = bp.resolve("strain")
    beam = dataclasses.replace(cfg.beam, damping_ratio=0.015)
    veh = cfg.vehicle
    v, t0, M = 7.0, 0.4, 6
    w = np.random.default_rng(0).standard_normal((veh.loads.size, M)) * 0.05
    T = t0 + (beam.length + veh.offsets.max()) / v + 0.3
    resp = _fe_fluctuating(beam, veh.loads, veh.offsets, v, t0, w, M, T)
    tt = np.arange(0.0, T, 1 / 100.0)
    S = cfg.sensors
    x = np.concatenate([np.full(tt.size, s.x) for s in S])
    t = np.tile(tt, len(S))
    y = np.concatenate([np.full(tt.size, s.y) for s in S])
    fe = resp.sample(x, t, 0.0, -y)
    cm = CrossingModel(
        beam.length,
        beam.mass_per_length,
        veh.loads,
        veh.offsets,
        x,
        t,
        0.0,
        -y,
        n_modes=24,
        n_basis=M,
    )
    mu, R = cm.responses(beam.EI, 0.015, v, t0, basis=True)
    fluct = R[0] @ w.ravel()
    rms = np.sqrt(np.mean(fe**2))
    assert np.sqrt(np.mean((mu[0] + fluct - fe) ** 2)) < 2e-3 * rms  # FE converged to ~0.1 %
    assert np.sqrt(np.mean(fluct**2)) > 5 * np.sqrt(np.mean((mu[0] + fluct - fe) ** 2))
    # negative control: without the fluctuation the constant-force response misses the FE solve
    assert np.sqrt(np.mean((mu[0] - fe) ** 2)) > 5 * np.sqrt(np.mean((mu[0] + fluct - fe) ** 2))


def test_woodbury_equals_dense_gaussian():
    rng = np.random.default_rng(2)
    n, M, W = 40, 7, 3
    B = rng.standard_normal((W, n, M))
    r = rng.standard_normal((W, n))
    s2 = np.array([0.3, 1.0, 2.5])
    mine = woodbury_loglik(r, B, s2) - 0.5 * n * np.log(2 * np.pi * s2)
    dense = [
        multivariate_normal(np.zeros(n), s2[i] * np.eye(n) + B[i] @ B[i].T).logpdf(r[i])
        for i in range(W)
    ]
    np.testing.assert_allclose(mine, dense, rtol=1e-10)


def test_triangular_solves_equal_general_ones():
    """`tri_solve` (C^-1 B and C'^-1 B) and `cho_solve` ((C C')^-1 B) on a batch, against numpy's general
    solver; the transposed solve is not the plain one (negative control)."""
    rng = np.random.default_rng(4)
    W, K, m = 3, 30, 4
    X = rng.standard_normal((W, K, K))
    A = X @ np.swapaxes(X, 1, 2) + K * np.eye(K)
    C = np.linalg.cholesky(A)
    B = rng.standard_normal((W, K, m))
    np.testing.assert_allclose(tri_solve(C, B), np.linalg.solve(C, B), rtol=1e-10, atol=1e-12)
    up = np.linalg.solve(np.swapaxes(C, 1, 2), B)
    np.testing.assert_allclose(tri_solve(C, B, transposed=True), up, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(cho_solve(C, B), np.linalg.solve(A, B), rtol=1e-10, atol=1e-12)
    assert np.abs(tri_solve(C, B) - up).max() > 1e-3


def test_nothing_declared_is_todays_reference():
    """No nuisance declared: the modal method takes today's path (the same posterior as modal_posterior)."""
    from bayespinn.methods.modal import ModalMCMC
    from bayespinn.uq.modal_mcmc import modal_posterior
    from bayespinn.uq.priors import NoisePrior

    for case in ("deflection", "strain"):
        assert not needs_crossings(bp.resolve(case))
    cfg = bp.resolve("deflection")
    data = bp.simulate(cfg, 20, seed=4)
    method = ModalMCMC(profile="smoke", mcmc=SMOKE)
    got = method.infer(data, cfg, seed=5)
    from bayespinn import seeding

    want = modal_posterior(
        data, cfg, noise_prior=NoisePrior.build("vague", data.value),
        seed=seeding.stream(5, "emcee"), settings=SMOKE,
        method=REFERENCE_KEY,
    )  # fmt: skip
    assert type(got).__name__ == "Posterior"
    np.testing.assert_array_equal(got.EI, want.EI)


@pytest.mark.parametrize(
    "toml",
    [
        {"vehicle": {"speed_sd": 0.01}},
        {"vehicle": {"entry_time_sd": 0.05}},
        {"vehicle": {"entry_time": 0.3}},
        {"model": {"damping": "inferred"}},
        {"model": {"axle_forces": "fluctuating"}},
        {"crossing": [{"name": "a", "speed": 7.0}]},
    ],
)
def test_declared_nuisances_pick_the_crossing_reference(toml):
    assert needs_crossings(bp.resolve("strain", toml))


@pytest.mark.parametrize(
    "toml, key",
    [
        ({"model": {"EI_segments": 2}}, "model.EI_segments"),
        ({"model": {"supports": "springs"}}, "model.supports"),
        ({"model": {"noise": "ar1"}}, "model.noise"),
        ({"model": {"EI_field": "smooth"}}, "model.EI_field"),
        ({"vehicle": {"load_rel_sd": 0.05}}, "vehicle.load_rel_sd"),
    ],
)
def test_unsupported_combinations_are_refused(toml, key):
    cfg = bp.resolve(
        "deflection", {**toml, "vehicle": {**toml.get("vehicle", {}), "speed_sd": 0.01}}
    )
    data = bp.simulate(bp.resolve("deflection"), 20, seed=0)
    with pytest.raises(InputError) as e:
        check_crossings(cfg, data)
    assert e.value.args[0].startswith(key) or key in str(e.value)
    assert "\n" not in str(e.value)


def test_new_model_keys_are_validated():
    for toml, key in (
        ({"model": {"damping": "guessed"}}, "model.damping"),
        ({"model": {"axle_forces": "random"}}, "model.axle_forces"),
        ({"model": {"EI_field": "wavy"}}, "model.EI_field"),
        ({"prior": {"damping_median": 1.5}}, "prior.damping_median"),
        ({"prior": {"damping_log_sd": 0.0}}, "prior.damping_log_sd"),
    ):
        with pytest.raises(InputError) as e:
            bp.resolve("deflection", toml)
        assert key in str(e.value)
    cfg = bp.resolve("deflection", {"model": {"damping": "inferred"}})
    assert cfg.prior.damping_median == 0.01 and cfg.prior.damping_log_sd == 0.7
    assert (
        "damping" not in bp.resolve("deflection", {"model": {"EI_segments": 2}}).identity()["model"]
    )


def test_smoke_posterior_has_the_contract_keys():
    """A short run on a deflection file: every inferred nuisance in the summary with the fields of EI."""
    truth = bp.resolve("deflection")
    data = bp.simulate(truth, 20, seed=3)
    cfg = bp.resolve(
        "deflection",
        {"vehicle": {"speed_sd": 0.02, "entry_time_sd": 0.05}, "model": {"damping": "inferred"}},
    )
    ref = crossings_reference(data, cfg, seed=0, settings=SMOKE, method=REFERENCE_KEY)
    s = ref.summary({"EI": truth.beam.EI, "speed": truth.vehicle.speed, "entry_time": 0.0})
    for key in ("EI", "speed", "entry_time", "damping_ratio"):
        assert {"mean", "sd", "median", "ci90", "ci95"} <= set(s[key]), key
    assert "rel_error_pct" in s["speed"] and "error" in s["entry_time"]
    assert s["diagnostics"]["parameters"] == [
        "log_EI",
        "log_zeta",
        "log_v[crossing]",
        "t0[crossing]",
    ]
    assert abs(s["speed"]["mean"] / truth.vehicle.speed - 1) < 0.03
    post = ref.to_inference_data(data).posterior
    assert {"EI", "sigma", "speed", "entry_time", "damping_ratio"} <= set(post.data_vars)
    assert post["speed"].shape == post["EI"].shape


@pytest.mark.parametrize("name", ["ensemble", "bpinn"])
@pytest.mark.parametrize(
    "toml, key",
    [
        ({"vehicle": {"speed_sd": 0.01}}, "vehicle.speed_sd"),
        ({"vehicle": {"entry_time_sd": 0.05}}, "vehicle.entry_time_sd"),
        ({"model": {"damping": "inferred"}}, "model.damping"),
        ({"model": {"axle_forces": "fluctuating"}}, "model.axle_forces"),
        ({"crossing": [{"name": "a"}, {"name": "b", "speed": 7.0}]}, "[[crossing]]"),
    ],
)
def test_pinn_methods_refuse_what_they_would_ignore(name, toml, key):
    """The PINN methods take the crossing as stated: a declared nuisance is refused in one line naming its
    key, before anything runs, instead of being silently ignored."""
    from bayespinn.methods import get

    cfg = bp.resolve("deflection", toml)
    data = sample_layout(bp.resolve("deflection"), 0)
    method = get(name)(profile="smoke")
    with pytest.raises(InputError) as e:
        method.check(data, cfg)
    assert str(e.value).startswith(key) and "\n" not in str(e.value)


def test_a_pinn_reads_a_recording_that_starts_before_the_entry():
    """A recording that starts before the vehicle arrives (`[vehicle] entry_time = 0.5`, stated exactly;
    the independent simulator, constant forces, 30 dB): the deep ensemble (smoke) reads it on the crossing's
    clock and lands within 1 reference sd of the modal reference on the same data (measured +0.32 % against
    +0.28 %, sds 0.23 % and 0.22 %), with its fit check passing; its predictions on the data's clock are
    zero before the entry, and cover every row. Negative control: the same data read as if the first axle
    entered at t = 0 miss by more than 5 reference sds (measured +23 %)."""
    from bayespinn.methods import get
    from bayespinn.methods.clock import ShiftedPredictor

    cfg = bp.resolve("deflection", {"vehicle": {"entry_time": 0.5}})
    data = bp.simulate(cfg, 30.0, 3)
    assert data.t.min() < 0.5  # rows before the entry
    r = bp.analyse(data, cfg, methods=["modal", "ensemble"], seed=3, profile="smoke")
    ref, ens = (r.summary["methods"][k] for k in ("modal_mcmc", "ensemble"))
    z = (ens["EI"]["mean"] - ref["EI"]["mean"]) / ref["EI"]["sd"]
    assert abs(z) < 1.0, z
    assert ens["fit_check"]["verdict"] == "fits" and ens["entry_time_s"] == 0.5
    post = r.posteriors["ensemble"]
    assert isinstance(post.predictor, ShiftedPredictor)
    before = post.predictor(np.full(3, 10.0), np.array([0.1, 0.3, 0.49]), "deflection", 20)
    assert before.shape[1] == 3 and np.all(before == 0.0)
    assert post.predictive_draws(data, 20).shape == (20, len(data))
    # negative control: the raw clock, the entry taken as t = 0
    at0 = dataclasses.replace(cfg, vehicle=dataclasses.replace(cfg.vehicle, entry_time=0.0))
    miss = get("ensemble")(profile="smoke").infer(data, at0, seed=3)
    z0 = (float(np.mean(miss.EI)) - ref["EI"]["mean"]) / ref["EI"]["sd"]
    assert abs(z0) > 5.0, z0
