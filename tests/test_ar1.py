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
