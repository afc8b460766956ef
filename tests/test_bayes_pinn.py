"""Ensemble and B-PINN machinery: the last-layer marginal likelihood is exact, NUTS recovers a known
posterior (and a wrong one fails), both methods run end to end and say when EI is not identified."""

import math

import numpy as np
import pytest
import torch

from bayespinn import methods
from bayespinn.config import preset
from bayespinn.data.synthetic import simulate
from bayespinn.options import RunOptions
from bayespinn.pinn import TrainSettings, fit
from bayespinn.uq.bpinn import nuts
from bayespinn.uq.lastlayer import LastLayer
from bayespinn.uq.nuts import NUTSSettings, nuts_health

#: float64 Cholesky vs dense log-determinant on ~100-row systems
EXACT_TOL = 1e-6
#: NUTS with 4 x 300 draws: Monte Carlo error of the mean ~0.05 sd, of the sd ~4 %
NUTS_MEAN_TOL_SD, NUTS_SD_TOL = 0.2, 0.12


def _brute_force(ll: LastLayer, D, P4, P2, f, Bm, Cm, y, lt, ls):
    """log N of all observations with the stiffness-scaled output weights gamma = theta beta integrated out,
    in observation space (the `lastlayer` docstring's model: data rows D / theta, PDE rows P4 + P2 / theta)."""
    th, s = math.exp(lt), math.exp(ls)
    Z = torch.cat([D / th, P4 + P2 / th, Bm, Cm])
    t = torch.cat([y, f, torch.zeros(Bm.shape[0] + Cm.shape[0], dtype=torch.float64)])
    noise = torch.cat(
        [
            torch.full((D.shape[0],), s**2),
            torch.full((P4.shape[0],), ll.s_f**2),
            torch.full((Bm.shape[0],), ll.s_b**2),
            torch.full((Cm.shape[0],), ll.s_i**2),
        ]
    ).double()
    S = ll.s_w**2 * Z @ Z.T + torch.diag(noise)
    return float(torch.distributions.MultivariateNormal(torch.zeros_like(t), S).log_prob(t))


def test_last_layer_marginal_is_exact(smoke_fit):
    cfg, data, problem, res = smoke_fit
    model = res.model()
    ll = LastLayer(
        model,
        0,
        problem,
        data,
        np.random.default_rng(0),
        n_pde=40,
        n_bc=10,
        n_ic=10,
        vary_first_mode=True,
    )
    held = LastLayer(
        model,
        0,
        problem,
        data,
        np.random.default_rng(0),
        n_pde=40,
        n_bc=10,
        n_ic=10,
        vary_first_mode=False,
    )
    # rebuild the same design matrices through the public pieces of the module, the first mode's free
    # vibrations at each theta, the higher modes without PDE rows (`LastLayer` docstring)
    from bayespinn.pinn.losses import moving_load
    from bayespinn.uq.lastlayer import feature_jet

    sc, pt = ll.sc, ll.pt
    fv = model.free_vibration
    assert fv is not None and fv.modes > 1  # the smoke profile has the fast profile's basis
    low = fv.lowest()
    T = lambda a: torch.as_tensor(np.asarray(a, float), dtype=torch.float64)  # noqa: E731
    r = np.random.default_rng(0)
    xi_f, tau_f = T(r.uniform(0, 1, 40)), T(r.uniform(0, 1, 40))
    tb = T(r.uniform(0, 1, 10))
    xi_i = T(r.uniform(0, 1, 10))
    xi_d, tau_d = T(data.x / sc.L), T(data.t / sc.T)

    def with_low(jet, xi, tau, kx, kt, lt, comp):
        """comp(jet) with its trailing columns replaced by the first mode's at theta = exp(lt)."""
        jl = low.jet(xi[None], tau[None], kx, kt, torch.tensor([lt], dtype=torch.float64))
        jl = jl.map(lambda c: c[0])
        a = comp(jet).clone()
        a[:, -low.n_features :] = comp(jl)
        return a

    f = moving_load(xi_f[None], tau_f[None], pt)[0]
    y = T(data.value)

    def brute_held(lt, ls):
        """every free-vibration mode at the fitted EI, none with PDE rows"""
        j = feature_jet(model, 0, xi_d, tau_d, 2, 0)
        jf = feature_jet(model, 0, xi_f, tau_f, 4, 2)
        P4, P2 = pt.stiffness * jf.dx(4), pt.inertia * jf.dt(2)
        k = P4.shape[1]
        P4[:, k - fv.n_features :] = 0.0
        P2[:, k - fv.n_features :] = 0.0
        rows = []
        for end in (0.0, 1.0):
            jb = feature_jet(model, 0, torch.full_like(tb, end), tb, 2, 0)
            rows += [jb.value, jb.dx(2)]
        ji = feature_jet(model, 0, xi_i, torch.zeros_like(xi_i), 0, 1)
        return _brute_force(
            held,
            sc.U * j.value,
            P4,
            P2,
            f,
            torch.cat(rows),
            torch.cat([ji.value, ji.dt(1)]),
            y,
            lt,
            ls,
        )

    def brute(lt, ls):
        j = feature_jet(model, 0, xi_d, tau_d, 2, 0)
        D = sc.U * with_low(j, xi_d, tau_d, 2, 0, lt, lambda q: q.value)
        jf = feature_jet(model, 0, xi_f, tau_f, 4, 2)
        P4 = pt.stiffness * with_low(jf, xi_f, tau_f, 4, 2, lt, lambda q: q.dx(4))
        P2 = pt.inertia * with_low(jf, xi_f, tau_f, 4, 2, lt, lambda q: q.dt(2))
        k = P4.shape[1]
        P4[:, k - fv.n_features : k - low.n_features] = 0.0
        P2[:, k - fv.n_features : k - low.n_features] = 0.0
        rows = []
        for end in (0.0, 1.0):
            e = torch.full_like(tb, end)
            jb = feature_jet(model, 0, e, tb, 2, 0)
            rows += [
                with_low(jb, e, tb, 2, 0, lt, lambda q: q.value),
                with_low(jb, e, tb, 2, 0, lt, lambda q: q.dx(2)),
            ]
        z0 = torch.zeros_like(xi_i)
        ji = feature_jet(model, 0, xi_i, z0, 0, 1)
        Cm = torch.cat(
            [
                with_low(ji, xi_i, z0, 0, 1, lt, lambda q: q.value),
                with_low(ji, xi_i, z0, 0, 1, lt, lambda q: q.dt(1)),
            ]
        )
        return _brute_force(ll, D, P4, P2, f, torch.cat(rows), Cm, y, lt, ls)

    pts = [(0.0, -7.0), (0.1, -7.5), (-0.2, -6.5)]
    ours = [
        float(
            ll.log_marginal(
                torch.tensor(a, dtype=torch.float64), torch.tensor(b, dtype=torch.float64)
            )
        )
        for a, b in pts
    ]
    got = [brute(a, b) for a, b in pts]
    # equal up to one additive constant
    d = np.array(ours) - np.array(got)
    assert np.ptp(d) < EXACT_TOL * max(1.0, abs(got[0]))
    # the same with the first mode held at the fitted EI
    ours_h = [
        float(
            held.log_marginal(
                torch.tensor(a, dtype=torch.float64), torch.tensor(b, dtype=torch.float64)
            )
        )
        for a, b in pts
    ]
    d_h = np.array(ours_h) - np.array([brute_held(a, b) for a, b in pts])
    assert np.ptp(d_h) < EXACT_TOL * max(1.0, abs(got[0]))
    # negative control: the free vibrations held at the fitted EI give a different likelihood
    frozen = []
    for a, b in pts:
        j = feature_jet(model, 0, xi_d, tau_d, 2, 0)
        jf = feature_jet(model, 0, xi_f, tau_f, 4, 2)
        rows = []
        for end in (0.0, 1.0):
            jb = feature_jet(model, 0, torch.full_like(tb, end), tb, 2, 0)
            rows += [jb.value, jb.dx(2)]
        ji = feature_jet(model, 0, xi_i, torch.zeros_like(xi_i), 0, 1)
        frozen.append(
            _brute_force(
                ll,
                sc.U * j.value,
                pt.stiffness * jf.dx(4),
                pt.inertia * jf.dt(2),
                f,
                torch.cat(rows),
                torch.cat([ji.value, ji.dt(1)]),
                y,
                a,
                b,
            )
        )
    assert np.ptp(np.array(ours) - np.array(frozen)) > 100 * EXACT_TOL * max(1.0, abs(got[0]))


def test_first_mode_follows_ei_only_where_the_data_resolve_its_vibration(smoke_fit):
    """The vibration test (`lastlayer` docstring) for free amplitudes: at 20 dB the first-mode vibration stands
    well above the noise and its frequency follows EI; the same features explaining far noisier data (noise
    30x) hold it at the fitted EI. With tied amplitudes (the profiles' default) the amplitude is the loads',
    not fitted noise, and the first mode follows EI at both noise levels."""
    cfg, data, problem, tied_res = smoke_fit
    sd = float(np.std(data.value - data.value_true))
    noisy = data.with_values(
        data.value + 30 * sd * np.random.default_rng(5).standard_normal(len(data))
    )
    s = TrainSettings.for_profile("smoke", optimizer="adam", free_modes=3, tie_vibration=False)
    free_res = fit(problem, s, seed=0, quiet=True)

    def last_layer(res, d):
        return LastLayer(
            res.model(), 0, problem, d, np.random.default_rng(0), n_pde=40, n_bc=10, n_ic=10
        )

    ll = last_layer(free_res, data)
    assert ll.first_mode_varies and ll.vibration_z2 > ll.vibration_threshold and ll.nv > 0
    hid = last_layer(free_res, noisy)
    assert not hid.first_mode_varies and hid.vibration_z2 < hid.vibration_threshold and hid.nv == 0
    assert hid.kf == hid.k
    for d in (data, noisy):
        tied = last_layer(tied_res, d)
        assert tied.first_mode_varies and tied.nv == 1


def test_full_weight_model_is_the_last_layer_one_with_free_hidden_weights(smoke_fit):
    """`bpinn_full`: at the fitted hidden weights its log marginal is the last-layer model's (bit for bit), at
    other hidden weights it is that of a network carrying them (the flat vector maps onto the right weights),
    and it is differentiable in every hidden weight."""
    from bayespinn.uq.bpinn_full import FullWeight
    from bayespinn.uq.lastlayer import feature_jet

    cfg, data, problem, res = smoke_fit
    model = res.model()
    ll = LastLayer(
        model,
        0,
        problem,
        data,
        np.random.default_rng(0),
        n_pde=40,
        n_bc=10,
        n_ic=10,
        vary_first_mode=False,
    )
    fw = FullWeight(ll, model.member(0))
    n_hidden = sum(
        w.numel() + b.numel()
        for w, b in zip(list(model.weights)[:-1], list(model.biases)[:-1], strict=True)
    )
    assert fw.dim == n_hidden
    z = [(math.log(ll.theta_fit), -8.0), (0.1, -7.5)]
    T = lambda v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
    for lt, ls in z:
        assert float(fw.log_marginal(fw.h_fit, T(lt), T(ls))) == float(
            ll.log_marginal(T(lt), T(ls))
        )
    h = fw.h_fit + 0.01 * torch.randn(
        fw.dim, generator=torch.Generator().manual_seed(1), dtype=torch.float64
    )
    net = model.member(0).double()
    with torch.no_grad():
        flat = iter(
            torch.split(h, [p.numel() for p in list(net.weights)[:-1] + list(net.biases)[:-1]])
        )
        for p in list(net.weights)[:-1]:
            p.copy_(next(flat).view(p.shape))
        for p in list(net.biases)[:-1]:
            p.copy_(next(flat).view(p.shape))
    ref = ll.with_rows(*ll.rows(lambda xi, tau, kx, kt: feature_jet(net, 0, xi, tau, kx, kt)))
    got = float(fw.log_marginal(h, T(0.05), T(-7.8)))
    assert abs(got - float(ref.log_marginal(T(0.05), T(-7.8)))) < EXACT_TOL * abs(got)
    # negative control: the hidden weights matter far beyond that tolerance
    assert abs(got - float(fw.log_marginal(fw.h_fit, T(0.05), T(-7.8)))) > 100 * EXACT_TOL * abs(
        got
    )
    hh = h.clone().requires_grad_(True)
    fw.log_marginal(hh, T(0.05), T(-7.8)).backward()
    assert torch.isfinite(hh.grad).all() and (hh.grad != 0).float().mean() > 0.9


@pytest.mark.slow
def test_full_weight_nuts_reduces_to_the_last_layer_posterior(smoke_fit):
    """The full-weight sampler end to end (whitening, chains, draws of log EI) with the hidden weights' prior
    held tightly at the fit: its posterior of (log theta, log sigma) must be the last-layer one; a reference
    off by a factor 2 in the sd of log theta must fail the same check."""
    from bayespinn.uq.bpinn_core import LastLayerPotential
    from bayespinn.uq.bpinn_full import FullHMCSettings, FullWeight, _FullPotential, full_nuts
    from bayespinn.uq.nuts import laplace_factor, map_estimate
    from bayespinn.uq.priors import EIPrior, NoisePrior

    cfg, data, problem, res = smoke_fit
    ll = LastLayer(
        res.model(),
        0,
        problem,
        data,
        np.random.default_rng(0),
        n_pde=40,
        n_bc=10,
        n_ic=10,
        vary_first_mode=False,
    )
    pot = LastLayerPotential(
        ll, EIPrior.from_spec(cfg.prior), NoisePrior.build("vague", data.value, None), 0.0
    )
    z_map = map_estimate(
        pot, np.array([math.log(ll.theta_fit), math.log(math.sqrt(ll.fit_rss / ll.n))])
    )
    L = laplace_factor(pot, z_map)
    ref = nuts(pot, z_map, L, NUTSSettings(4, 200, 500), seed=0, progress=False)[0].reshape(-1, 2)
    mean, sd = ref.mean(0), ref.std(0)
    fw = FullWeight(ll, res.model().member(0))
    held = _FullPotential(fw, pot, z_map, L, prior_mean=fw.h_fit, prior_sd=1e-6)
    z, h, hz, runs = full_nuts(held, FullHMCSettings(4, 150, 300, 5), seed=1, progress=False)
    assert z.shape == (4, 300, 2) and h.shape[1] == fw.dim and len(hz) == len(h)
    assert len(runs) == 4 and all(r.tree_depth.shape == (300,) for r in runs)
    assert float((h - fw.h_fit).abs().max()) < 1e-4
    assert _ok(z, mean, sd)
    assert not _ok(z, mean, [2 * sd[0], sd[1]])


def test_bpinn_variant_choice():
    from bayespinn.uq.bpinn_core import resolve_variant

    # the full sampler is never the default: hours at the fast profile on a GPU too, and never converged
    for profile in ("smoke", "fast", "paper"):
        assert resolve_variant("auto", profile) == "last-layer"
    assert resolve_variant("last-layer", "paper") == "last-layer"
    assert resolve_variant("full", "smoke") == "full"
    with pytest.raises(ValueError, match="variant"):
        resolve_variant("fulll", "fast")


class _Gauss:
    def __init__(self, mean, sd):
        self.mean, self.sd = (
            torch.tensor(mean, dtype=torch.float64),
            torch.tensor(sd, dtype=torch.float64),
        )

    def __call__(self, params):
        return 0.5 * (((params["z"] - self.mean) / self.sd) ** 2).sum()


def _ok(draws, mean, sd):
    d = draws.reshape(-1, 2)
    return bool(
        np.all(np.abs(d.mean(0) - mean) < NUTS_MEAN_TOL_SD * np.array(sd))
        and np.all(np.abs(d.std(0) / np.array(sd) - 1) < NUTS_SD_TOL)
    )


def test_nuts_recovers_gaussian_and_negative_control():
    mean, sd = [0.3, -6.0], [0.02, 0.07]
    s = NUTSSettings(4, 200, 300)
    draws, runs = nuts(_Gauss(mean, sd), np.array(mean), np.diag(sd), s, seed=0, progress=False)
    assert draws.shape == (4, 300, 2) and _ok(draws, mean, sd)
    health = nuts_health(runs)
    assert (
        health["divergences"] == 0
        and health["tree_depth_saturated"] == 0
        and not health["sampler_warnings"]
    )
    # whitened with a factor 5 off in one direction and a shifted centre: the adaptation still finds it
    off, _ = nuts(
        _Gauss(mean, sd),
        np.array(mean) + [0.02, 0.0],
        np.diag([5 * sd[0], sd[1]]),
        s,
        seed=0,
        progress=False,
    )
    assert _ok(off, mean, sd)
    wrong, _ = nuts(
        _Gauss(mean, [0.04, 0.07]), np.array(mean), np.diag(sd), s, seed=0, progress=False
    )
    assert not _ok(wrong, mean, sd)


@pytest.mark.parametrize("method", ["bpinn", "bpinn-full", "ensemble"])
def test_methods_end_to_end_smoke(method, tmp_path):
    from bayespinn.uq.bpinn import VARIANT
    from bayespinn.uq.bpinn_full import FULL_VARIANT

    cfg = preset()
    data = simulate(cfg, 20.0, 2)
    method, _, full = method.partition("-")
    opts = RunOptions(
        profile="smoke", members=3, snr_db=20.0, bpinn_variant="full" if full else "auto"
    )
    p = methods.build(method, opts).infer(data, cfg, seed=2)
    s = p.summary({"EI": cfg.beam.EI})
    assert np.isfinite(s["EI"]["mean"]) and s["EI"]["ci90"][0] < s["EI"]["ci90"][1]
    assert np.isfinite(s["sigma"]["mean"]) and s["sigma"]["mean"] > 0
    if method == "ensemble":
        assert s["members"] == 3 and len(s["member_EI"]) == 3
    else:
        assert s["diagnostics"]["chains"] >= 4 and s["variant"] == (
            FULL_VARIANT if full else VARIANT
        )
    band = p.predictor(np.array([4.0, 8.0]), np.array([0.8, 1.2]), "deflection", 12)
    assert band.shape[1] == 2 and np.all(np.isfinite(band))
    moment = p.predictor(np.array([4.0, 8.0]), np.array([0.8, 1.2]), "moment", 12)
    assert moment.shape == band.shape and np.all(np.isfinite(moment))
    from arviz_check import check_inference_data

    path = p.to_netcdf(tmp_path / "posterior.nc", data=data, seed=2)
    check_inference_data(path, data, "nuts" if method == "bpinn" else None)
    if not full:  # the same seed gives the same numbers
        q = methods.build(method, opts).infer(data, cfg, seed=2)
        np.testing.assert_allclose(q.EI, p.EI)


def test_ensemble_without_data_is_not_identified():
    cfg = preset("strain")
    data = simulate(cfg, 30.0, 0)
    empty = data.select(np.zeros(len(data), bool))
    p = methods.build("ensemble", RunOptions(profile="smoke", members=3)).infer(empty, cfg, seed=0)
    s = p.summary()
    assert s["identified"] is False and "not identified" in s["note"]


def _gaussian_marginal(mean, sd, points=801, half=8.0):
    from bayespinn.uq.ensemble import MemberMarginal

    g = mean + np.linspace(-half * sd, half * sd, points)
    p = np.exp(-0.5 * ((g - mean) / sd) ** 2)
    return MemberMarginal(g, p / p.sum())


def test_ensemble_pools_its_members_posteriors_as_a_mixture():
    from bayespinn.uq.ensemble import pool_log_ei

    # members' posterior means 0, +-0.02, +-0.01 around log(1.03e9): variance of the means 2e-4 (ddof 0);
    # every member's width 0.01 -> 1e-4; the mixture's variance 1e-4 + 2e-4 = 3e-4
    c = np.log(1.03e9)
    means = np.array([0.0, 0.02, -0.02, 0.01, -0.01]) + c
    marg = [_gaussian_marginal(m, 0.01) for m in means]
    fits = means + np.array([0.3, -0.1, 0.2, 0.0, 0.1])  # the trained EIs: not the centre
    mu, between, lap_var, n_ok, pooled = pool_log_ei(fits, marg, 0.5)
    np.testing.assert_allclose(
        [mu, between, lap_var, n_ok, pooled], [c, 2e-4, 1e-4, 5, 3e-4], rtol=1e-6
    )
    # member 4 without a marginal: the mixture of the other four
    mu4, b4, lv4, n4, pooled4 = pool_log_ei(fits, [*marg[:4], None], 0.5)
    rest = means[:4]
    np.testing.assert_allclose(
        [mu4, b4, lv4, n4, pooled4],
        [rest.mean(), rest.var(), 1e-4, 4, 1e-4 + rest.var()],
        rtol=1e-6,
    )
    # no marginal at all: the trained EIs' spread stands for the posterior, plus their mean's error
    mu0, _, _, n0, pooled0 = pool_log_ei(fits, [None] * 5, 0.5)
    assert n0 == 0 and mu0 == pytest.approx(fits.mean())
    assert pooled0 == pytest.approx(np.var(fits, ddof=1) * 1.2)
    # one member without a marginal: the prior
    assert pool_log_ei(fits[:1], [None], 0.5)[4] == 0.25


class _GaussianLastLayer:
    """A stand-in last-layer model whose marginal of log theta is N(c, s^2) and whose trained theta sits
    `off` widths away from c (as a member's trained EI can)."""

    def __init__(self, c, s, off):
        self.c, self.s, self.theta_fit = c, s, float(np.exp(c + off * s))

    def log_marginal(self, log_theta, log_sigma, z=None):
        return -0.5 * ((log_theta - self.c) / self.s) ** 2


def test_a_members_marginal_follows_its_peak_away_from_the_trained_value():
    """The grid starts at the trained EI, seven widths from the marginal's peak, and has to find it: the
    member's posterior is then centred where its marginal is (shifted to EI units, the prior's pull
    negligible), with its width. The control, a grid that may not move, never sees the peak's far side."""
    from bayespinn.uq import ensemble as E
    from bayespinn.uq import ensemble_marginal as EM
    from bayespinn.uq.priors import EIPrior

    c, s, shift = -0.1, 0.003, np.log(2.0e9)
    ll = _GaussianLastLayer(c, s, off=7.0)
    grid = E.SigmaGrid(np.array([-3.0, -2.0]), np.array([0.5, 0.5]))
    prior = EIPrior(median=2.0e9, log_sd=0.5)
    m = E.member_marginal(ll, grid, prior, shift, sd=s)
    assert m is not None
    assert m.mean == pytest.approx(c + shift, abs=0.02 * s)
    assert np.sqrt(m.var) == pytest.approx(s, rel=0.02)
    assert E.member_marginal(ll, grid, prior, shift, sd=float("nan")) is None
    tries = EM.MARGINAL_TRIES
    try:
        EM.MARGINAL_TRIES = 1
        m1 = E.member_marginal(ll, grid, prior, shift, sd=s / 4)
    finally:
        EM.MARGINAL_TRIES = tries
    assert m1 is None


def test_ensemble_mixture_is_calibrated_when_members_hold_the_posterior():
    """The property the mixture rests on: members whose marginals are the posterior N(m, s^2) (up to a
    small scatter between networks) and a truth drawn from that posterior: the mixture's 90 % interval
    holds the truth inside the binomial 99.9 % region over 4000 trials. The negative control, the old
    centre (five randomise-then-optimise draws around m, the local width plus their mean's Monte Carlo
    error) is calibrated too when the draws are exact, so the control here is what broke on the family:
    trained EIs that miss the posterior by a bias of one local width; centred on them, the interval falls
    outside the region, while the mixture of the same members' marginals does not care."""
    from scipy import stats

    from bayespinn.uq.ensemble import pool_log_ei

    rng = np.random.default_rng(11)
    n, s, M = 4000, 0.01, 5
    lo, hi = stats.binom.ppf([0.0005, 0.9995], n, 0.9)
    hits, hits_ctrl = 0, 0
    for _ in range(n):
        truth = s * rng.standard_normal()  # the truth around the posterior mean 0
        centres = (
            0.1 * s * rng.standard_normal(M)
        )  # each network's posterior mean, scattered a little
        marg = [_gaussian_marginal(m, s, points=161) for m in centres]
        fits = s + s * rng.standard_normal(M)  # trained EIs: biased by one width
        mu, _, _, _, var = pool_log_ei(fits, marg, 0.5)
        hits += abs(truth - mu) <= 1.645 * np.sqrt(var)
        old_var = s**2 + np.var(fits, ddof=1) / M
        hits_ctrl += abs(truth - fits.mean()) <= 1.645 * np.sqrt(old_var)
    assert lo <= hits <= hi, (hits, lo, hi)
    assert not lo <= hits_ctrl <= hi, (hits_ctrl, lo, hi)


#: the shared and the own fit of one seed agree to this relative tolerance, their NUTS draws to SAME_DRAWS
SAME_FIT, SAME_DRAWS = 1e-10, 1e-4


def test_bpinn_shares_the_ensembles_fit_and_is_the_same_function_of_the_seed():
    """Run after the ensemble on the same data, the B-PINN takes the ensemble's member 0 fit instead of
    training its own (issue 25); alone, it computes that very fit itself: the posterior is the same up to
    the last bits of torch's arithmetic in another process, and only the time it spent training differs. A different seed gives a different fit (the control)."""
    import bayespinn as bp
    from bayespinn.uq import shared_fit

    cfg = preset()
    data = simulate(cfg, 20.0, 3)
    shared_fit.clear()
    alone = bp.analyse(data, cfg, methods="bpinn", seed=5, profile="smoke").posteriors["bpinn"]
    shared_fit.clear()
    both = bp.analyse(data, cfg, methods="ensemble,bpinn", seed=5, profile="smoke")
    after = both.posteriors["bpinn"]
    assert alone.diagnostics["warm_start"].startswith("own fit")
    assert after.diagnostics["warm_start"].startswith("shared")
    # the same fit computed in a pool worker and in this process: torch's CPU kernels are not bit-reproducible
    # across processes (measured here: fit EI 1.4e-14 apart, relative), and NUTS carries that to ~1e-6
    # in the draws; SAME_FIT and SAME_DRAWS sit far below a posterior sd (about 1e-2 relative)
    fa, fb = alone.diagnostics["fit_EI"], after.diagnostics["fit_EI"]
    assert abs(fa / fb - 1) < SAME_FIT
    assert np.allclose(alone.EI, after.EI, rtol=SAME_DRAWS, atol=0)
    assert np.allclose(alone.sigma, after.sigma, rtol=SAME_DRAWS, atol=0)
    assert after.diagnostics["fit_runtime_s"] == 0.0 < alone.diagnostics["fit_runtime_s"]
    assert both.manifest["time_breakdown_s"]["bpinn"]["training"] == 0.0
    shared_fit.clear()
    other = bp.analyse(data, cfg, methods="bpinn", seed=6, profile="smoke").posteriors["bpinn"]
    assert abs(other.diagnostics["fit_EI"] / fa - 1) > 100 * SAME_FIT


@pytest.mark.parametrize("noise_factor", [1.0, 30.0])
def test_local_width_is_the_marginals_sd_on_a_grid(smoke_fit, noise_factor):
    """`LastLayer.local_sd_log_theta` (the ensemble members' own width) is the sd of log theta under the
    last-layer marginal (sigma held) times the prior's curvature: checked against a brute-force grid of
    12001 points over +-3 in log theta, at the smoke fit's noise and 30x it."""
    cfg, data, problem, res = smoke_fit
    sd = float(np.std(data.value - data.value_true))
    d = data.with_values(
        data.value + (noise_factor - 1) * sd * np.random.default_rng(5).standard_normal(len(data))
    )
    ll = LastLayer(res.model(), 0, problem, d, np.random.default_rng(0), n_pde=40, n_bc=10, n_ic=10)
    lt = math.log(ll.theta_fit)
    ls = math.log(ll.noise_mode(lt))
    prior_sd = 0.5
    got = ll.local_sd_log_theta(lt, ls, prior_sd)
    g = lt + np.linspace(-3.0, 3.0, 12001)
    with torch.no_grad():
        lp = np.array(
            [
                float(ll.log_marginal(torch.tensor(v, dtype=torch.float64), torch.tensor(ls)))
                for v in g
            ]
        )
    lp -= 0.5 * ((g - lt) / prior_sd) ** 2
    p = np.exp(lp - lp.max())
    p /= p.sum()
    m = (p * g).sum()
    want = math.sqrt((p * (g - m) ** 2).sum())
    assert p[0] < 1e-6 and p[-1] < 1e-6  # the brute-force grid holds the whole density
    assert got == pytest.approx(want, rel=0.01)


@pytest.mark.parametrize("offset_sd, converged", [(0.0, True), (5.0, False)])
def test_a_posterior_far_from_the_fit_it_linearises_is_not_converged(offset_sd, converged):
    """The last-layer B-PINN linearises around its fit: draws that mix well but sit 5 of their sds from the
    fit's EI are not a trustworthy interval, and the verdict says so (the control: the same draws centred
    on the fit converge). Draws are synthetic, 4 chains of 2000 independent normals."""
    import warnings
    from types import SimpleNamespace

    from bayespinn.uq.bpinn_core import MAX_MOVE_SD, assemble
    from bayespinn.uq.priors import EIPrior

    rng = np.random.default_rng(3)
    sd, shift = 0.002, math.log(1.0e9)
    draws = np.stack(
        [sd * rng.standard_normal((4, 2000)), -7.0 + 0.01 * rng.standard_normal((4, 2000))], -1
    )
    res = SimpleNamespace(
        EI=np.array([math.exp(shift - offset_sd * sd)]), runtime_s=1.0, beta_factor=1.0
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        post = assemble(
            draws, {}, None, {}, res=res, shift=shift, ei_prior=EIPrior(1.0e9, 0.5),
            variant="last-layer", name="last-layer", t0=0.0,
        )  # fmt: skip
    assert post.diagnostics["converged"] is converged
    assert (post.diagnostics["moved_from_fit_sd"] > MAX_MOVE_SD) is (not converged)
    if not converged:
        assert any("from the fit it linearises" in p for p in post.diagnostics["problems"])
        assert "not trustworthy" in post.info["warnings"][0]
