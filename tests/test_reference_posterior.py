"""Reference posterior: the emcee driver on an analytic target (with a negative control), the modal
posterior against exact quadrature, the Posterior type's I/O, and posterior coverage."""

import math

import numpy as np
import pytest
from scipy import stats

from bayespinn.config import preset
from bayespinn.data.synthetic import simulate
from bayespinn.methods import REFERENCE_KEY
from bayespinn.options import RunOptions
from bayespinn.physics.modal import ModalModel
from bayespinn.uq.coverage import binomial_acceptance, coverage_study, paired_with_reference
from bayespinn.uq.modal_mcmc import INTERP_NATS, ModalLikelihood, modal_posterior
from bayespinn.uq.posterior import Posterior
from bayespinn.uq.priors import NoisePrior
from bayespinn.uq.sampler import MCMCSettings, sample

#: with ESS >= ~1000 the Monte Carlo error of a posterior mean is <= 0.03 sd; of an sd, <= 3 %
MEAN_TOL_SD, SD_TOL_REL = 0.1, 0.08
#: the issue's acceptance for the modal run against exact quadrature
ISSUE_MEAN_TOL_SD, ISSUE_SD_TOL_REL = 0.15, 0.10


def _linear_gaussian(seed=0, n=40, noise=0.3):
    """y = A theta + e with a Gaussian prior: the posterior is Gaussian and known exactly."""
    r = np.random.default_rng(seed)
    A = np.column_stack([np.ones(n), np.linspace(-1, 1, n)])
    theta_true = np.array([0.7, -1.2])
    y = A @ theta_true + noise * r.standard_normal(n)
    prior_sd = 2.0
    prec = A.T @ A / noise**2 + np.eye(2) / prior_sd**2
    cov = np.linalg.inv(prec)
    mean = cov @ (A.T @ y / noise**2)
    return A, y, noise, prior_sd, mean, cov


def _logpost(A, y, noise, prior_sd):
    def f(theta):
        r = y[None, :] - theta @ A.T
        return -0.5 * np.sum(r**2, axis=1) / noise**2 - 0.5 * np.sum(theta**2, axis=1) / prior_sd**2

    return f


def _matches(draws, mean, cov):
    sd = np.sqrt(np.diag(cov))
    d = draws.reshape(-1, draws.shape[-1])
    return bool(
        np.all(np.abs(d.mean(0) - mean) < MEAN_TOL_SD * sd)
        and np.all(np.abs(d.std(0) / sd - 1) < SD_TOL_REL)
    )


def test_sampler_recovers_analytic_posterior():
    A, y, noise, psd, mean, cov = _linear_gaussian()
    ch = sample(
        _logpost(A, y, noise, psd), mean + 0.1, np.sqrt(np.diag(cov)), MCMCSettings(), seed=1
    )
    assert ch.steps >= 50 * ch.tau
    assert _matches(ch.draws, mean, cov)


def test_sampler_negative_control_wrong_likelihood_fails():
    """A likelihood with the noise sd misstated by 2x must not pass the same check."""
    A, y, noise, psd, mean, cov = _linear_gaussian()
    ch = sample(_logpost(A, y, 2 * noise, psd), mean, np.sqrt(np.diag(cov)), MCMCSettings(), seed=1)
    assert not _matches(ch.draws, mean, cov)


def test_sampler_is_a_function_of_the_seed():
    A, y, noise, psd, mean, cov = _linear_gaussian()
    s = MCMCSettings(min_steps=250, tau_factor=1.0)
    a = sample(_logpost(A, y, noise, psd), mean, np.sqrt(np.diag(cov)), s, seed=3).draws
    b = sample(_logpost(A, y, noise, psd), mean, np.sqrt(np.diag(cov)), s, seed=3).draws
    c = sample(_logpost(A, y, noise, psd), mean, np.sqrt(np.diag(cov)), s, seed=4).draws
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def _grid_posterior(cfg, data):
    """Exact marginal posterior of EI by quadrature (sigma integrated out under the log-uniform prior)."""
    m = ModalModel(cfg.beam, cfg.vehicle, data.x, data.t, *data.weights, n_modes=40)
    le = math.log(cfg.beam.EI) + np.linspace(-0.3, 0.3, 6001)
    rss = np.concatenate(
        [np.sum((data.value[None] - m.predict(np.exp(c))) ** 2, 1) for c in np.array_split(le, 30)]
    )
    logp = stats.norm.logpdf(
        le, math.log(cfg.prior.EI_median), cfg.prior.EI_log_sd
    ) - 0.5 * data.value.size * np.log(rss)
    w = np.exp(logp - logp.max())
    w /= w.sum()
    EI = np.exp(le)
    mean = float(np.sum(w * EI))
    return mean, float(np.sqrt(np.sum(w * (EI - mean) ** 2)))


@pytest.mark.parametrize("case,snr", [("deflection", 10.0), ("deflection", 30.0), ("strain", 20.0)])
def test_modal_posterior_matches_quadrature(case, snr, request):
    """Against exact quadrature of the exact modal likelihood (40 modes, no interpolant): the strain case is
    sampled through the Chebyshev interpolant of the likelihood (`ModalLikelihood.interpolate`)."""
    cfg = request.getfixturevalue("exeter" if case == "deflection" else "exeter_strain")
    data = simulate(cfg, snr, 5)
    p = modal_posterior(
        data, cfg, noise_prior=NoisePrior.build("vague", data.value), seed=5, method=REFERENCE_KEY
    )
    if case == "strain":
        assert p.diagnostics["interpolation"]["used"]
    mean, sd = _grid_posterior(cfg, data)
    assert abs(p.EI.mean() - mean) < ISSUE_MEAN_TOL_SD * sd
    assert abs(p.EI.std() / sd - 1) < ISSUE_SD_TOL_REL
    assert (
        p.diagnostics["converged"]
        and p.diagnostics["rhat"] <= 1.01
        and p.diagnostics["ess_bulk"] >= 400
    )


def test_snr_noise_prior_runs_2d(exeter):
    data = simulate(exeter, 20.0, 2)
    p = modal_posterior(
        data,
        exeter,
        noise_prior=NoisePrior.build("snr", data.value, 20.0),
        seed=2,
        settings=MCMCSettings.for_profile("smoke"),
        method=REFERENCE_KEY,
    )
    assert "log sigma" in p.diagnostics["scheme"]
    true_sigma = np.sqrt(np.mean(data.value_true**2) / 100.0)
    assert abs(p.sigma.mean() / true_sigma - 1) < 0.3


def test_posterior_netcdf_round_trip(tmp_path):
    r = np.random.default_rng(0)
    p = Posterior(
        "bpinn",
        1e9 + r.standard_normal((4, 50)),
        1e-4 + r.random((4, 50)) * 1e-5,
        diagnostics={"rhat": 1.001, "converged": True},
        runtime_s=3.5,
    )
    path = p.to_netcdf(tmp_path / "posterior_bpinn.nc")
    q = Posterior.from_netcdf(path)
    np.testing.assert_array_equal(q.EI, p.EI)
    np.testing.assert_array_equal(q.sigma, p.sigma)
    assert q.method == "bpinn" and q.diagnostics["rhat"] == 1.001 and q.runtime_s == 3.5


#: shift of the negative control's truth, in posterior sds. Scored against truth + k sd, a calibrated 90 %
#: interval holds it with p = Phi(k + 1.645) - Phi(k - 1.645): 0.36 at k = 2, which still reaches the
#: acceptance region's 8 of 12 with probability 3 % (it did, on one platform's draws); 0.088 at k = 3,
#: so the control fails to reject with probability 1.3e-6.
NEGATIVE_CONTROL_SHIFT_SD = 3.0


def test_coverage_negative_control_detects_a_wrong_truth():
    """The binomial acceptance region must reject a miscalibrated claim: intervals scored against a
    truth shifted by `NEGATIVE_CONTROL_SHIFT_SD` posterior sds cover far less than 90 %."""
    cfg = preset()
    res = coverage_study(
        "modal",
        cfg,
        10.0,
        replicates=12,
        level=0.9,
        seed=1,
        progress=False,
        opts=RunOptions(profile="smoke"),
    )
    lo, hi = binomial_acceptance(12, 0.9)
    assert lo <= res["hits"] <= hi
    k = NEGATIVE_CONTROL_SHIFT_SD
    shifted = [
        r
        for r in res["records"]
        if r["interval"][0] <= r["EI_true"] * (1 + k * r["sd_rel_pct"] / 100) <= r["interval"][1]
    ]
    assert len(shifted) < lo


def _study(seed=0, truth="fixed", shift_sd=0.0, sd_factor=1.0, n=8):
    """A coverage study dict with made-up records: replicate i has relative error e_i and sd s_i."""
    r = np.random.default_rng(3)
    e, s = r.normal(0, 3, n), r.uniform(2, 4, n)
    recs = [
        {
            "index": i,
            "rel_error_pct": float(e[i] + shift_sd * s[i]),
            "sd_rel_pct": float(sd_factor * s[i]),
            "hit": bool(abs(e[i] + shift_sd * s[i]) < 1.645 * sd_factor * s[i]),
        }
        for i in range(n)
    ]
    return {
        "method": "x",
        "seed": seed,
        "snr_db": 10.0,
        "case": "deflection",
        "truth": truth,
        "records": recs,
    }


def test_paired_comparison_with_the_reference():
    ref = _study()
    same = paired_with_reference(_study(), ref)
    assert same["datasets"] == 8 and same["mean_z"] == 0.0 and same["median_sd_ratio"] == 1.0
    assert same["sd_ratio_in_band"] == 1.0 and same["hits"] == same["reference_hits"]
    # negative control: a posterior 2 reference sds off and half as wide is caught on every dataset
    bad = paired_with_reference(_study(shift_sd=1.0, sd_factor=0.5), ref)
    assert bad["mean_z"] == pytest.approx(1.0) and bad["sd_z"] == pytest.approx(0.0, abs=1e-12)
    assert bad["median_sd_ratio"] == pytest.approx(0.5) and bad["sd_ratio_in_band"] == 0.0
    # other datasets (another seed) or a truth drawn per replicate: no pairing
    assert paired_with_reference(_study(seed=1), ref) is None
    assert paired_with_reference(_study(truth="prior"), _study(truth="prior")) is None


def test_coverage_replicates_share_datasets_across_runs():
    """Replicate i's dataset depends on (seed, SNR, i) only: two modal studies whose samplers differ
    pair up with z within Monte Carlo error; a study of another seed's datasets, forced into the pairing,
    does not (negative control)."""
    cfg, opts = preset(), RunOptions(profile="smoke")
    a = coverage_study("modal", cfg, 10.0, replicates=3, seed=2, progress=False, opts=opts)
    b = coverage_study(
        "modal",
        cfg,
        10.0,
        replicates=3,
        seed=2,
        progress=False,
        opts=RunOptions(profile="smoke", mcmc=MCMCSettings(n_walkers=24, n_groups=3)),
    )
    p = paired_with_reference(b, a)
    # measured: max |z| 0.024, sd ratios 1.017-1.034; the forced pairing below: max |z| 3.07
    assert p["datasets"] == 3 and p["max_abs_z"] < 0.15 and 0.85 < p["median_sd_ratio"] < 1.15
    c = coverage_study("modal", cfg, 10.0, replicates=3, seed=3, progress=False, opts=opts)
    forced = paired_with_reference(dict(c, seed=2), a)
    assert forced["max_abs_z"] > 0.5


@pytest.mark.slow
def test_modal_coverage_200_replicates():
    """Coverage of the 90 % interval over 200 datasets at 10 dB, within the 99 % binomial region."""
    res = coverage_study("modal", preset(), 10.0, replicates=200, level=0.9, seed=7, progress=False)
    lo, hi = binomial_acceptance(200, 0.9, false_failure=0.01)
    assert lo <= res["hits"] <= hi, res["hits"]
    assert res["rank_uniformity_p"] > 0.001


def _strain_likelihood(cfg):
    data = simulate(cfg, 20.0, 2)
    return cfg, data, ModalLikelihood(cfg, data, n_modes=6)


def test_interpolated_likelihood_is_within_its_stated_nats_and_exact_outside_its_window(
    exeter_strain,
):
    cfg, data, lik = _strain_likelihood(exeter_strain)
    c, hw = math.log(cfg.beam.EI), 0.01
    info = lik.interpolate(c, hw)
    assert info["used"] and info["max_loglik_error_nats"] <= INTERP_NATS
    le = c + hw * np.random.default_rng(0).uniform(-1, 1, 64)
    exact = ModalLikelihood(cfg, data, n_modes=6)
    n = data.value.size
    err = 0.5 * n * np.abs(np.log(lik.rss_log(le) / exact.rss_log(le)))
    assert err.max() <= 2 * INTERP_NATS  # random points, not only the midpoints it was checked at
    assert err.max() > 0  # the interpolant is in use
    out = c + np.array([-1.5, 1.5]) * hw
    np.testing.assert_array_equal(lik.rss_log(out), exact.rss_log(out))


def test_an_interpolant_that_cannot_reach_the_tolerance_is_not_used(exeter_strain, monkeypatch):
    """Negative control: with at most 16 nodes over a window of +-30 % in EI the check must refuse."""
    import bayespinn.uq.modal_mcmc as mm

    monkeypatch.setattr(mm, "INTERP_MAX_NODES", 16)
    cfg, data, lik = _strain_likelihood(exeter_strain)
    info = lik.interpolate(math.log(cfg.beam.EI), 0.3)
    assert not info["used"] and lik.cheb is None
    le = math.log(cfg.beam.EI) + np.array([-0.1, 0.0, 0.1])
    np.testing.assert_array_equal(lik.rss_log(le), ModalLikelihood(cfg, data, 6).rss_log(le))
