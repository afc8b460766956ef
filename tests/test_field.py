"""The smooth EI field (`[model] EI_field = "smooth"`): the modal reference's EI(x) against the truth of
data it does not contain exactly.

Data: the finite-element simulator (Newmark time integration, 96 segments of their own EI) on the Exeter
girder with a smooth loss 30 % deep and 1.5 m wide (full width at half depth) centred at 6.1 m, which is
on no edge of the analysis' pieces; the reference's surrogate is modal with 48 pieces whose EI is the
loss's compliance average. Deflection, 400 points at 30 dB, seeds fixed. Measured here (2 cores): about
15 s per posterior; on seeds 1-3 the 90 % band held the true EI(x) over 0.95-1.0 of the span and the
posterior mean's deepest point lay 0.05-0.47 m from the truth's.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.special import ndtri

import bayespinn as bp
from bayespinn.errors import InputError
from bayespinn.methods import get
from bayespinn.pipeline import true_values_of
from bayespinn.threads import one_blas_thread
from bayespinn.uq import field_search, girder_field
from bayespinn.uq.girder_field import field_grid, field_posterior

EI0 = 1.03361e9
DEPTH, CENTRE, FWHM = 0.3, 6.1, 1.5
#: the gauge dataset of the search test (one BLAS thread; on seeds 1-7 of data from the surrogate the
#: grid reached the truth's mode on 6, 7 nats short on seed 5; starts along the span alone on 2)
SEARCH_SEED = 2


def loss_profile(length: float, centre: float = CENTRE, n: int = 96) -> list[float]:
    """EI of n equal segments: the smooth loss evaluated at each segment's centre."""
    c = (np.arange(n) + 0.5) * length / n
    s = FWHM / (2.0 * np.sqrt(2.0 * np.log(2.0)))
    return (EI0 * (1.0 - DEPTH * np.exp(-0.5 * ((c - centre) / s) ** 2))).tolist()


def config(centre: float = CENTRE, **model):
    length = bp.resolve("deflection").beam.length
    return bp.resolve(
        "deflection",
        {
            "beam": {"EI": loss_profile(length, centre)},
            "model": {"EI_field": "smooth", "EI_nominal": EI0, **model},
            "data": {"n_points": 400},
        },
    )


def true_EI_x(cfg) -> np.ndarray:
    prof = np.asarray(cfg.beam.EI_profile)
    x = field_grid(cfg.beam.length)
    return prof[np.clip((x / cfg.beam.length * prof.size).astype(int), 0, prof.size - 1)]


@pytest.fixture(scope="module")
def dip():
    cfg = config()
    data = bp.simulate(cfg, snr_db=30, seed=1)
    return cfg, data, field_posterior(data, cfg, seed=1)


def test_band_holds_the_loss_and_finds_its_deepest_point(dip):
    cfg, _, post = dip
    assert post.diagnostics["converged"]
    ex = post.EI_x(true_EI_x(cfg))
    assert ex["coverage"] >= 0.9
    x, mean = np.asarray(ex["x"]), np.asarray(ex["mean"])
    assert abs(x[np.argmin(mean)] - CENTRE) <= 1.0
    # the span-averaged flexibility's equivalent holds its truth, and the loss is seen as a loss
    truth = true_values_of(cfg, 1)["EI"]
    lo, hi = np.quantile(post.EI, [0.05, 0.95])
    assert lo <= truth <= hi
    i = int(np.argmin(np.abs(x - CENTRE)))
    assert ex["p_damaged"][i] > 0.95 and max(ex["p_damaged"][:10]) < 0.05


def test_the_checks_fail_for_a_loss_elsewhere_and_for_a_uniform_model(dip):
    """Negative controls: the same band judged against the loss moved by 3 m misses it (coverage and
    deepest point), and the uniform reference on the same data, whose EI(x) is one value along the span,
    holds the true EI(x) over well under 90 % of it."""
    cfg, data, post = dip
    moved = true_EI_x(config(CENTRE + 3.0))
    ex = post.EI_x(moved)
    assert ex["coverage"] < 0.9
    assert abs(np.asarray(ex["x"])[np.argmin(ex["mean"])] - (CENTRE + 3.0)) > 1.0
    uniform = bp.analyse(data, bp.resolve("deflection"), methods="modal", seed=1, profile="smoke")
    lo, hi = next(iter(uniform.posteriors.values())).interval(0.9)
    t = true_EI_x(cfg)
    assert np.mean((t >= lo) & (t <= hi)) < 0.9


def test_run_writes_the_field_and_the_pinn_methods_take_it(dip, tmp_path):
    cfg, data, _ = dip
    truth = true_values_of(cfg, 1)
    res = bp.analyse(data, cfg, methods="modal", seed=1, profile="smoke", snr_db=30, truth=truth)
    entry = next(iter(res.summary["methods"].values()))
    ex = entry["EI_x"]
    assert len(ex["x"]) >= 50 and len(ex["mean"]) == len(ex["x"]) == len(ex["ci90"])
    assert all(lo <= m <= hi for m, (lo, hi) in zip(ex["mean"], ex["ci90"], strict=True))
    assert 0.0 < ex["coverage"] <= 1.0  # the truth is known for simulated data
    assert set(entry["local_loss"]) == {"depth", "position", "width"}
    lo, hi = entry["local_loss"]["position"]["ci90"]
    assert lo - 0.5 <= CENTRE <= hi + 0.5
    run = bp.write_run(res, tmp_path / "run")
    assert (run / "fig_ei_span.png").exists()
    assert "local loss" in (run / "report.md").read_text()
    # the PINN methods take the field (what its reference does not describe, they refuse alike)
    ar1 = config(noise="ar1")
    for name in ("ensemble", "bpinn"):
        get(name)(profile="smoke").check(data, cfg)
        with pytest.raises(InputError) as e:
            get(name)(profile="smoke").check(data, ar1)
        assert str(e.value).startswith("model.noise") and "\n" not in str(e.value)


def test_the_pinn_reads_the_field_as_the_reference_does():
    """The girder PINN's field (torch, differentiable) is the reference's map from theta to each piece's
    EI, and its enrichment the reference's surrogate; its problem starts at the reference's MAP search."""
    import torch

    from bayespinn.uq.field_pinn import FieldGirderProblem

    cfg = strain_config()
    data = bp.simulate(cfg, snr_db=30, seed=SEARCH_SEED)
    pr = FieldGirderProblem(data, cfg)
    th = np.random.default_rng(0).standard_normal((5, 4))
    assert np.allclose(pr.ei_pieces(torch.as_tensor(th)).numpy(), pr.loss.EI_pieces(th), rtol=1e-12)
    theta, left, right, lam = pr.coefficients(torch.as_tensor(th))
    assert theta.shape == (5, girder_field.PIECES) and torch.all(lam == 1)
    assert np.allclose(pr.enrichment(th), pr.field.predict(th))
    # the start is the reference's MAP: from it, Levenberg-Marquardt climbs no further
    top = pr.field.residuals(pr.phi0[None])[1][0]
    assert field_search._lm_map(pr.field.residuals, pr.field.n, pr.phi0)[1] <= top + 1e-3
    assert pr.inside(pr.phi0) and not pr.inside(np.array([0.0, 0.0, 9.0, 0.0]))
    assert np.isclose(float(pr.log_prior(torch.as_tensor(th[0]))), -0.5 * np.sum(th[0] ** 2))


@pytest.mark.parametrize(
    "model, key",
    [
        ({"EI_segments": 4}, "model.EI_segments"),
        ({"supports": "springs"}, "model.supports"),
        ({"noise": "ar1"}, "model.noise"),
    ],
)
def test_what_the_field_does_not_describe_is_refused(model, key):
    cfg = config(**model)
    data = bp.simulate(bp.resolve("deflection"), 30, seed=0)
    with pytest.raises(InputError) as e:
        get("modal")(profile="smoke").check(data, cfg)
    assert str(e.value).startswith(key) and "\n" not in str(e.value)


def test_a_crossing_to_infer_is_refused_with_the_field():
    length = bp.resolve("deflection").beam.length
    cfg = bp.resolve(
        "deflection",
        {
            "beam": {"EI": loss_profile(length)},
            "model": {"EI_field": "smooth"},
            "vehicle": {"speed_sd": 0.01},
        },
    )
    data = bp.simulate(bp.resolve("deflection"), 30, seed=0)
    with pytest.raises(InputError) as e:
        get("modal")(profile="smoke").check(data, cfg)
    assert str(e.value).startswith("model.EI_field")


def strain_config(**vehicle):
    length = bp.resolve("strain").beam.length
    return bp.resolve(
        "strain",
        {
            "beam": {"EI": loss_profile(length)},
            "model": {"EI_field": "smooth", "EI_nominal": EI0},
            "vehicle": vehicle,
        },
    )


def true_theta(loss) -> np.ndarray:
    """theta of the loss the test girders carry (level EI0, DEPTH, CENTRE, FWHM)."""
    lo, hi = loss.width_range
    width = FWHM / (2.0 * np.sqrt(2.0 * np.log(2.0)))
    u = [DEPTH, CENTRE / loss.length, np.log(width / lo) / np.log(hi / lo)]
    return np.array([(np.log(EI0) - loss.m) / loss.sd, *ndtri(u)])


def test_a_gauge_reads_the_moment_over_the_local_EI():
    """Quasi-static crossing (1 m/s): at every gauge the surrogate's curvature times the field's EI at the
    gauge is the statically determined bending moment (pinned supports) to 0.2 %. Negative control: the
    surrogate's own curvature (its piece's averaged EI) misses it by over 2 % at the gauge on the loss's
    flank (5.76 m)."""
    cfg = strain_config(speed=1.0)
    data = bp.simulate(cfg, snr_db=30, seed=3)
    prob = girder_field._problem(data, cfg)
    th = true_theta(prob.loss)[None]
    curvature = prob.predict(th)[0] / np.asarray(data.weights[1])
    x, t, L = np.asarray(data.x), np.asarray(data.t), cfg.beam.length
    moment = np.zeros_like(x)
    for axle in cfg.vehicle.axles:
        a = cfg.vehicle.speed * t - axle.offset
        on = (a >= 0) & (a <= L)
        moment += axle.load * np.where(on, np.where(a <= x, a * (L - x), x * (L - a)) / L, 0.0)
    ei_x = prob.loss.EI_at(th, x)[0]
    piece = np.minimum((x / L * girder_field.PIECES).astype(int), girder_field.PIECES - 1)
    factor = prob.loss.curvature_factor(th, prob.loss.EI_pieces(th), x, piece)[0]
    for g in np.unique(x):
        s = (x == g) & (moment > 0.3 * moment[x == g].max())
        assert abs(np.median(np.abs(curvature[s]) * ei_x[s] / moment[s]) - 1.0) < 2e-3
        if abs(g - 5.76) < 1e-6:
            own = np.abs(curvature[s] / factor[s]) * ei_x[s] / moment[s]
            assert abs(np.median(own) - 1.0) > 0.02


@one_blas_thread  # as the reference runs it: the climbs' last bits then do not depend on the machine
def test_the_global_search_reaches_the_best_mode_on_gauge_data():
    """Strain data made by the surrogate itself at the true loss (30 dB): the global search's starts
    climb to the mode the truth climbs to. Negative control: sixteen starts along the span at one depth
    and width (the search before the grid) end far below it on the same data."""
    cfg = strain_config()
    data = bp.simulate(cfg, snr_db=30, seed=SEARCH_SEED)
    prob = girder_field._problem(data, cfg)
    th = true_theta(prob.loss)
    clean = prob.predict(th[None])[0]
    noise = np.random.default_rng(SEARCH_SEED).standard_normal(clean.size)
    y = clean + noise * np.std(clean) * 10 ** (-30 / 20)
    own = girder_field._problem(dataclasses.replace(data, value=y), cfg)

    def best(starts):
        return max(field_search._lm_map(own.residuals, own.n, s)[1] for s in starts)

    top = field_search._lm_map(own.residuals, own.n, th)[1]
    starts, _ = field_search._grid_starts(
        own.residuals, own.y, own.a0, own.loss.sd, girder_field.PIECES
    )
    assert best(starts) >= top - 1.0
    along = [np.array([own.a0, -1.0, u, 0.0]) for u in ndtri((np.arange(16) + 0.5) / 16)]
    assert best(along) < top - 50.0


@pytest.mark.slow
def test_the_pinn_methods_find_the_loss_beside_the_reference(dip):
    """The deep ensemble (smoke profile, two members) on the deflection dataset: the 90 % band of EI(x)
    holds the true EI(x) over at least 90 % of the span, the deepest point of the posterior mean lies
    within 1 m of the truth's, and the span-equivalent EI sits within one reference sd of the reference's.
    Negative control: the same band judged against the loss moved by 3 m misses it. (The B-PINN runs the
    same problem; its NUTS chains take about 20 minutes at the fast profile, so it is measured by the
    study command in docs/methods.md, not here.)"""
    cfg, data, _ = dip
    truth = true_EI_x(cfg)
    moved = true_EI_x(config(CENTRE + 3.0))
    ref = bp.analyse(data, cfg, methods="modal", seed=1, profile="smoke").posteriors
    ref = next(iter(ref.values()))
    for method in (get("ensemble")(profile="smoke", members=2),):
        post = next(iter(bp.analyse(data, cfg, methods=[method], seed=1).posteriors.values()))
        ex = post.field.EI_x(truth)
        x, mean = np.asarray(ex["x"]), np.asarray(ex["mean"])
        assert ex["coverage"] >= 0.9, (method.name, ex["coverage"])
        assert abs(x[np.argmin(mean)] - CENTRE) <= 1.0
        assert abs(np.mean(post.EI) - np.mean(ref.EI)) <= np.std(ref.EI)
        assert post.field.EI_x(moved)["coverage"] < 0.9
