"""AR(1) noise: the likelihood's algebra against a dense Gaussian, the reference posterior with AR(1) noise,
and the fit check's verdicts with and without it (issue 23)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

import bayespinn as bp
from bayespinn.data.measurements import Measurements
from bayespinn.uq.ar1 import AR1Noise, noise_series


def _layout(rng, sensors=("S1", "S2", "S3"), n=40):
    """Three gauges' interleaved, shuffled series."""
    t = np.tile(np.arange(n) * 0.005, len(sensors))
    sensor = np.repeat(np.array(sensors), n)
    p = rng.permutation(t.size)
    z = np.zeros(t.size)
    return Measurements(z, t[p], z, np.full(t.size, "strain"), z + 0.4, sensor[p], z)


def test_the_ar1_likelihood_is_the_dense_gaussian_with_ar1_covariance():
    """-(n/2) log(2 pi s^2) + log_jacobian - Q / (2 s^2) equals the multivariate normal log density with
    covariance s^2 rho^|i-j| within each series (and 0 across series), for several rho; at rho = 0 Q is the
    plain sum of squares."""
    rng = np.random.default_rng(0)
    data = _layout(rng)
    noise = AR1Noise.of(data)
    r = rng.standard_normal(len(data))
    s = 0.7
    for rho in (-0.5, 0.0, 0.3, 0.9):
        z = np.array([math.atanh(rho)])
        q = noise.quad(r[None], z)[0]
        ll = (
            -0.5 * len(data) * math.log(2 * math.pi * s * s)
            + noise.log_jacobian(z)[0]
            - q / (2 * s * s)
        )
        cov = np.zeros((len(data), len(data)))
        for rows in noise_series(data):
            i = np.arange(rows.size)
            cov[np.ix_(rows, rows)] = s * s * rho ** np.abs(i[:, None] - i[None, :])
        dense = stats.multivariate_normal(np.zeros(len(data)), cov).logpdf(r)
        assert ll == pytest.approx(dense, rel=1e-10, abs=1e-8)
    assert noise.quad(r[None], np.zeros(1))[0] == pytest.approx(np.sum(r * r), rel=1e-12)
    # whitening gives the innovations: their sum of squares is Q
    u = noise.whiten(r, 0.6)
    assert np.sum(u * u) == pytest.approx(noise.quad(r[None], np.array([math.atanh(0.6)]))[0])


def test_series_cover_every_point_once_in_time_order():
    data = _layout(np.random.default_rng(1))
    series = noise_series(data)
    assert len(series) == 3 and sorted(np.concatenate(series).tolist()) == list(range(len(data)))
    for rows in series:
        assert np.all(np.diff(data.t[rows]) > 0) and len(set(data.sensor[rows])) == 1


def _strain(noise_ar1, model_noise, seed):
    cfg = bp.resolve(
        "strain",
        {"data": {"noise_ar1": noise_ar1, "sample_rate": 100.0}, "model": {"noise": model_noise}},
    )
    data = bp.simulate(cfg, 20.0, seed)
    return bp.analyse(data, cfg, methods=["modal"], seed=seed).summary["methods"]["modal_mcmc"]


def test_the_ar1_reference_recovers_the_coefficient_and_its_check_fits():
    """AR(1) strain noise (0.8): the AR(1) model's 90 % interval of the coefficient holds 0.8, its sampler
    converges and its fit check (on the whitened residuals) says `fits`; the white-noise model on the same
    data says `misfit` (the negative control) and its EI sd is smaller than the AR(1) model's."""
    m = _strain(0.8, "ar1", 3)
    lo, hi = m["noise_ar1"]["ci90"]
    assert lo <= 0.8 <= hi, m["noise_ar1"]
    assert m["diagnostics"]["converged"]
    assert m["fit_check"]["verdict"] == "fits" and m["fit_check"]["whitened"]
    w = _strain(0.8, "iid", 3)
    assert w["fit_check"]["verdict"] == "misfit"
    assert "noise_ar1" not in w
    assert w["EI"]["sd"] < m["EI"]["sd"]


def test_the_ar1_model_on_white_noise_finds_a_coefficient_near_zero():
    """White noise analysed with the AR(1) model: the coefficient's interval holds 0 and is narrow (about
    +-1.64 / sqrt(n) for n samples), and the check fits."""
    m = _strain(0.0, "ar1", 4)
    lo, hi = m["noise_ar1"]["ci90"]
    assert lo <= 0.0 <= hi and hi - lo < 0.2, m["noise_ar1"]
    assert m["fit_check"]["verdict"] == "fits"


def test_run_with_the_ar1_model_reports_the_coefficient(tmp_path):
    """`bayespinn run` with [model] noise = "ar1": summary.json has noise_ar1 (schema-valid: the run
    validates it), the report has its table."""
    import json
    import subprocess
    import sys

    cfg = tmp_path / "ar1.toml"
    cfg.write_text('[data]\nsample_rate = 100.0\nnoise_ar1 = 0.6\n[model]\nnoise = "ar1"\n')
    out = tmp_path / "out"
    r = subprocess.run(
        [sys.executable, "-m", "bayespinn", "run", "--snr", "20", "--case", "strain", "--method",
         "modal", "--config", str(cfg), "--out", str(out), "--quiet"],
        capture_output=True, text=True,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    m = json.loads((out / "summary.json").read_text())["methods"]["modal_mcmc"]
    assert set(m["noise_ar1"]) >= {"mean", "sd", "ci90"}
    assert m["model"]["noise"] == "ar1"
    md = (out / "report.md").read_text()
    assert "Noise correlation" in md and "AR(1) coefficient" in md


def _dense_last_layer(ll, D, P4, P2, Bm, Cm, lt, ls, rho):
    """log N of every observation of a last-layer model with its output weights integrated out, in observation
    space, the data noise AR(1) along the model's series (covariance sigma^2 rho^|i-j| within a series)."""
    import torch

    th, s = math.exp(lt), math.exp(ls)
    Z = torch.cat([D / th, P4 + P2 / th, Bm, Cm]).numpy()
    t = np.concatenate([ll.y.numpy(), ll.f.numpy(), np.zeros(Bm.shape[0] + Cm.shape[0])])
    n = D.shape[0]
    R = np.zeros((n, n))
    for rows in ll.ar1.series:
        i = np.arange(rows.size)
        R[np.ix_(rows, rows)] = rho ** np.abs(i[:, None] - i[None, :])
    S = ll.s_w**2 * Z @ Z.T
    S[:n, :n] += s * s * R
    k = P4.shape[0]
    S[n : n + k, n : n + k] += ll.s_f**2 * np.eye(k)
    j = Bm.shape[0]
    S[n + k : n + k + j, n + k : n + k + j] += ll.s_b**2 * np.eye(j)
    S[n + k + j :, n + k + j :] += ll.s_i**2 * np.eye(Cm.shape[0])
    St, tt = torch.as_tensor(S), torch.as_tensor(t)
    return float(torch.distributions.MultivariateNormal(torch.zeros_like(tt), St).log_prob(tt))


@pytest.mark.parametrize("vary", [False, True])
def test_the_last_layer_marginal_with_ar1_noise_is_the_dense_gaussian(smoke_fit, vary):
    """The PINN methods' likelihood (`LastLayer` with `noise`): at several (theta, sigma, rho) it equals the dense
    Gaussian of all observations with AR(1) data covariance, up to one constant, with the first mode held
    and with it following theta; rho = 0 is the white-noise model exactly, and the white-noise model is
    not the AR(1) one (negative control)."""
    import torch

    from bayespinn.uq.lastlayer import LastLayer, feature_jet

    cfg, data, problem, res = smoke_fit
    model = res.model()
    kw = dict(n_pde=40, n_bc=10, n_ic=10, vary_first_mode=vary)
    noise = AR1Noise.of(data)
    ll = LastLayer(model, 0, problem, data, np.random.default_rng(0), noise=noise, **kw)
    white = LastLayer(model, 0, problem, data, np.random.default_rng(0), **kw)
    assert ll.first_mode_varies == vary and ll.pde_v is None
    D0, P40, P20, B0, C0 = ll.rows(lambda xi, tau, kx, kt: feature_jet(model, 0, xi, tau, kx, kt))
    T = lambda v: torch.tensor(v, dtype=torch.float64)  # noqa: E731

    def dense(lt, ls, rho):
        D, P4, P2, Bm, Cm = D0.clone(), P40.clone(), P20.clone(), B0, C0.clone()
        if vary:  # the first mode's columns at theta: no PDE rows (exact), zero at the supports
            Dv, Cv = ll._varying(T(lt))
            D[:, ll.kf :], Cm[:, ll.kf :] = Dv, Cv
            P4[:, ll.kf :], P2[:, ll.kf :] = 0.0, 0.0
        return _dense_last_layer(ll, D, P4, P2, Bm, Cm, lt, ls, rho)

    pts = [(0.0, -7.0, 0.0), (0.1, -7.5, 0.5), (-0.2, -6.5, -0.3), (0.05, -7.2, 0.9)]
    ours = np.array([float(ll.log_marginal(T(a), T(b), T(math.atanh(r)))) for a, b, r in pts])
    got = np.array([dense(*p) for p in pts])
    assert np.ptp(ours - got) < 1e-6 * abs(got[0])
    # rho = 0 is the white-noise model (the default z of an AR(1) model is 0 too)
    for a, b, _ in pts:
        w = float(white.log_marginal(T(a), T(b)))
        assert float(ll.log_marginal(T(a), T(b))) == pytest.approx(w, rel=1e-12)
    # negative control: the white model's likelihood differs from the AR(1) one's by far more than the tolerance
    whites = np.array([float(white.log_marginal(T(a), T(b))) for a, b, _ in pts])
    assert np.ptp(whites - got) > 1e3 * 1e-6 * abs(got[0])


def test_the_pinn_training_objective_whitens_the_data_rows(smoke_fit):
    """With `Problem.noise_ar1` the training's data term is the whitened residuals' sum of squares (the AR(1)
    quadratic form Q(rho) of the scaled residuals), so randomise-then-optimise members are fitted under the
    same likelihood the last layer uses; noise_ar1 = 0 is the white objective, which is not the AR(1) one."""
    import dataclasses

    import torch

    from bayespinn.pinn.losses import data_residual

    cfg, data, problem, res = smoke_fit
    model = res.model().double()
    pt = problem.tensors(1, dtype=torch.float64)
    r = data_residual(model, pt)[0].detach().numpy()
    noise = AR1Noise.of(data)
    for rho in (0.6, -0.3):
        pw = dataclasses.replace(problem, noise_ar1=rho).tensors(1, dtype=torch.float64)
        rw = data_residual(model, pw)[0].detach().numpy()
        q = noise.quad(r[None], np.array([math.atanh(rho)]))[0]
        assert np.sum(rw * rw) == pytest.approx(q, rel=1e-10)
        assert abs(np.sum(rw * rw) - np.sum(r * r)) > 1e-3 * np.sum(r * r)  # negative control
    p0 = dataclasses.replace(problem, noise_ar1=0.0).tensors(1, dtype=torch.float64)
    assert np.array_equal(data_residual(model, p0)[0].detach().numpy(), r)
    with pytest.raises(ValueError, match="noise_ar1"):
        dataclasses.replace(problem, noise_ar1=1.0)


def test_the_pinn_methods_infer_ar1_noise_beside_the_reference():
    """Strain records with AR(1) noise (0.8, 200 Hz, 20 dB), smoke profile: the deep ensemble and the B-PINN
    with `[model] noise = "ar1"` give EI and the coefficient within 1.5 reference sds of the reference's mean
    on the same data, sds within [0.67, 1.5] of its, and the fit check's `fits` on the whitened residuals;
    the B-PINN with white noise on the same data says `misfit` (the negative control)."""
    over = {"data": {"noise_ar1": 0.8, "sample_rate": 200.0}}
    cfg = bp.resolve("strain", {**over, "model": {"noise": "ar1"}})
    data = bp.simulate(cfg, 20.0, 0)
    got = bp.analyse(
        data, cfg, methods=["modal", "ensemble", "bpinn"], seed=0, profile="smoke", snr_db=20.0
    ).summary["methods"]
    ref = got["modal_mcmc"]
    for key in ("ensemble", "bpinn"):
        m = got[key]
        for var in ("EI", "noise_ar1"):
            z = (m[var]["mean"] - ref[var]["mean"]) / ref[var]["sd"]
            ratio = m[var]["sd"] / ref[var]["sd"]
            assert abs(z) < 1.5 and 0.67 <= ratio <= 1.5, (key, var, z, ratio)
        assert m["fit_check"]["verdict"] == "fits" and m["fit_check"]["whitened"], key
    white = bp.resolve("strain", {**over, "model": {"noise": "iid"}})
    w = bp.analyse(data, white, methods=["bpinn"], seed=0, profile="smoke", snr_db=20.0)
    assert w.summary["methods"]["bpinn"]["fit_check"]["verdict"] == "misfit"
    assert "noise_ar1" not in w.summary["methods"]["bpinn"]


def test_a_coverage_study_scores_the_coefficient_and_a_wrong_truth_misses():
    """A coverage study of the AR(1) model (modal reference, 100 Hz, 20 dB) scores the coefficient's 90 %
    interval against the simulated 0.8 beside EI's and sums the hits with their acceptance region; the
    same posterior scored against a coefficient of 0.6 misses (the negative control: the score looks at
    the truth), and a white-noise analysis has no coefficient to score."""
    import dataclasses

    from bayespinn.options import RunOptions
    from bayespinn.pipeline import analyse
    from bayespinn.uq import coverage as cov
    from bayespinn.uq.sampler import MCMCSettings

    cfg = bp.resolve(
        "strain",
        {"data": {"noise_ar1": 0.8, "sample_rate": 100.0}, "model": {"noise": "ar1"}},
    )
    opts = RunOptions(
        profile="smoke", mcmc=MCMCSettings(n_walkers=16, n_groups=2, min_steps=500, tau_factor=20.0)
    )
    res = cov.coverage_study("modal", cfg, 20.0, replicates=1, seed=5, opts=opts, progress=False)
    (rec,) = res["records"]
    lo, hi = rec["noise_ar1"]["interval"]
    assert 0.6 < lo < 0.8 < hi < 0.95 and rec["noise_ar1"]["hit"]
    assert res["noise_ar1"]["hits"] == 1 and res["noise_ar1"]["true"] == 0.8
    assert res["noise_ar1"]["acceptance_99"] == list(cov.binomial_acceptance(1, 0.9))
    # the same replicate by hand: the same posterior, scored against the truth and against a wrong one
    task = cov.Replicate(
        0, "modal", cfg, 20.0, 5, 0.9, "fixed", cov.study_options("modal", 20.0, opts)
    )
    cfg_t, data, seq = cov._dataset(task)
    post = analyse(data, cfg_t, methods=["modal"], seed=seq, snr_db=20.0, opts=task.opts, argv=[])
    post = post.posteriors["modal_mcmc"]
    assert cov._score(task, cfg_t, post)["noise_ar1"] == rec["noise_ar1"]  # a function of the seed
    wrong = dataclasses.replace(cfg_t, data=dataclasses.replace(cfg_t.data, noise_ar1=0.6))
    missed = cov._score(task, wrong, post)
    assert missed["noise_ar1"]["true"] == 0.6 and not missed["noise_ar1"]["hit"]
    assert cov.parameter_coverage([missed], "noise_ar1", 0.9)["hits"] == 0
    white = dataclasses.replace(cfg, model=dataclasses.replace(cfg.model, noise="iid"))
    assert cov.ar1_draws(post, white) is None
    assert "noise_ar1" not in cov._score(task, white, post)
