"""The fit check: quiet on data the model explains, loud on data it cannot (issue 23's negative controls).

The statistics are tested against exact predictions (a posterior whose prediction is the truth leaves
white noise), with binomial acceptance regions; then end to end through the modal reference on a
well-specified dataset, a missing axle and smoothed (serially correlated) strain noise.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import stats

import bayespinn as bp
from bayespinn.config import Axle, Vehicle
from bayespinn.uq import fitcheck
from bayespinn.uq.posterior import Posterior

#: false-failure rate of the statistical tests below
FALSE_FAILURE = 1e-3


def _oracle(data, sigma=1.0):
    """A posterior whose prediction is the noise-free truth: the residuals are exactly the noise."""
    truth = np.asarray(data.value_true, float)
    strain = np.asarray(data.kind) == "strain"

    def predictor(x, t, quantity, n, rng):
        rows = strain if quantity == "curvature" else ~strain
        v = truth[rows] if quantity == "deflection" else -truth[rows] / data.y[rows]
        return np.broadcast_to(v, (n, v.size))

    return Posterior("oracle", np.ones((1, 4)), np.full((1, 4), sigma), predictor=predictor)


def _alarms(cfg, n, *, transform=None, seed0=0):
    layout = bp.simulate(cfg, None, 0)
    L, T = cfg.beam.length, cfg.duration
    out = 0
    for i in range(n):
        r = np.random.default_rng(seed0 + i)
        noise = r.standard_normal(len(layout)) * 1e-4 * np.abs(layout.value_true).max()
        if transform is not None:
            noise = transform(layout, noise, r)
        data = layout.with_values(layout.value_true + noise)
        fc = fitcheck.check(_oracle(data), data, L, T, seed=i)
        out += fc["verdict"] == "misfit"
    return out


@pytest.mark.parametrize("case", ["deflection", "strain"])
def test_white_noise_rarely_raises_the_alarm(case):
    """Residuals that are white noise: alarms follow at most Binomial(n, FALSE_ALARM); the upper edge of the
    acceptance region at a 1e-3 false-failure rate."""
    cfg = bp.resolve(case, {"data": {"sample_rate": 100.0}} if case == "strain" else None)
    n = 300
    hits = _alarms(cfg, n)
    assert hits <= stats.binom.isf(FALSE_FAILURE, n, fitcheck.FALSE_ALARM), hits


def test_smooth_structure_and_serial_correlation_raise_it():
    """Negative controls: a smooth shape in the residuals (peak 3 noise sd, RMS about 1.1 sd over 100
    points; at peak 1.5 sd the check caught about half) and AR(1) noise (coefficient 0.8) are flagged
    almost always."""
    d = bp.resolve("deflection")

    def bump(layout, noise, r):
        sd = noise.std()
        return noise + 3.0 * sd * np.sin(np.pi * layout.x / d.beam.length) * (layout.t / d.duration)

    assert _alarms(d, 40, transform=bump) >= 36
    s = bp.resolve("strain", {"data": {"sample_rate": 100.0}})

    def ar1(layout, noise, r):
        out = noise.copy()
        for name in set(layout.sensor):
            rows = np.flatnonzero(layout.sensor == name)
            for a, b in zip(rows[:-1], rows[1:], strict=True):
                out[b] = 0.8 * out[a] + 0.6 * noise[b]
        return out

    assert _alarms(s, 40, transform=ar1) == 40


def test_statistics_have_their_white_noise_distributions():
    """The energy share in k orthonormal columns of white noise is Beta(k/2, (n-k)/2); the pooled lag-1
    autocorrelation has mean about -1/n and sd about 1/sqrt(n)."""
    rng = np.random.default_rng(0)
    n, k = 400, 16
    Q, _ = np.linalg.qr(rng.standard_normal((n, k)))
    e = rng.standard_normal((4000, n))
    share = fitcheck.smooth_share(Q, e)
    assert stats.kstest(share, stats.beta(k / 2, (n - k) / 2).cdf).pvalue > FALSE_FAILURE
    rho = fitcheck.lag1([np.arange(n)], e)
    assert abs(rho.mean() + 1 / n) < 4 / np.sqrt(n * 4000)
    assert rho.std() == pytest.approx(1 / np.sqrt(n), rel=0.1)


def _modal_check(cfg_true, cfg_model, snr, seed, noise=None):
    data = bp.simulate(cfg_true, snr, seed)
    if noise is not None:
        data = data.with_values(data.value_true + noise(data))
    res = bp.analyse(data, cfg_model, methods="modal", seed=seed)
    return res.summary["methods"]["modal_mcmc"]["fit_check"]


def test_modal_reference_end_to_end():
    """Through `analyse`: the well-specified Exeter data fit; data from a truck with a second axle the model
    does not know do not."""
    d = bp.resolve("deflection")
    ok = _modal_check(d, d, 30, 0)
    assert ok["verdict"] == "fits" and set(ok) >= {"p_value", "statistic", "residual_autocorr"}
    two = dataclasses.replace(
        d, vehicle=Vehicle(d.vehicle.speed, (Axle(37000.0, 0.0), Axle(15000.0, 3.0)))
    )
    assert _modal_check(two, d, 30, 0)["verdict"] == "misfit"


@pytest.mark.slow
def test_modal_reference_flags_smoothed_strain_noise():
    """Strain records whose noise was smoothed over five samples (what "baseline-adjusted and smoothed"
    records have) do not fit the white-noise model, and the autocorrelation says why."""
    s = bp.resolve("strain", {"data": {"sample_rate": 100.0}})

    def smoothed(data):
        raw = data.value - data.value_true
        out = raw.copy()
        for name in set(data.sensor):
            rows = np.flatnonzero(data.sensor == name)
            out[rows] = np.convolve(raw[rows], np.ones(5) / np.sqrt(5), mode="same")
        return out

    bad = _modal_check(s, s, 20, 0, noise=smoothed)
    assert bad["verdict"] == "misfit" and bad["residual_autocorr"] > 0.5


def test_fitcheck_study_records_verdicts_per_level_and_resumes(tmp_path):
    """`studies/fitcheck.py` (2 replicates over two levels; the numbers are the plumbing's, not a calibration
    claim): one verdict per replicate at its level, the expected verdict's share with its exact interval,
    the 90 % intervals' hits; a rerun recomputes nothing; a bad --expect exits 2 naming the flag."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    script = repo / "studies" / "fitcheck.py"
    args = ["--snr", "20,30", "--replicates", "2", "--out", str(tmp_path), "--quiet"]
    run = lambda *a: subprocess.run(  # noqa: E731
        [sys.executable, str(script), *a], capture_output=True, text=True, cwd=repo
    )
    r = run(*args)
    assert r.returncode == 0, r.stderr[-3000:]
    path = tmp_path / "fitcheck" / "exeter-deflection-snr20_30.json"
    doc = json.loads(path.read_text())
    assert [x["snr_db"] for x in doc["records"]] == [20.0, 30.0]
    assert all(x["verdict"] in ("fits", "misfit") and 0 < x["p_value"] <= 1 for x in doc["records"])
    s = doc["summary"]
    assert s["replicates"] == 2 and s["expected"] == sum(
        x["verdict"] == "fits" for x in doc["records"]
    )
    lo, hi = s["share_ci95"]
    assert 0 <= lo <= s["share"] <= hi <= 1 and set(s["by_snr"]) == {"20", "30"}
    assert set(s["coverage"]) == {"EI"} and 0 <= s["coverage"]["EI"]["hits"] <= 2
    assert "exeter-deflection-snr20_30" in (tmp_path / "fitcheck.md").read_text()
    before = [x["time_s"] for x in doc["records"]]
    assert run(*args).returncode == 0
    assert [x["time_s"] for x in json.loads(path.read_text())["records"]] == before
    bad = run(*args, "--expect", "maybe")
    assert bad.returncode == 2 and "--expect" in bad.stderr and "Traceback" not in bad.stderr


def test_a_misfit_report_heads_with_the_alert_and_draws_the_residuals(tmp_path):
    """The report of a misfit run: the alert first, pointing to the residual figure, which is written; a
    well-specified run's report has the figure but no alert (the negative control)."""
    d = bp.resolve("deflection")
    two = dataclasses.replace(
        d, vehicle=Vehicle(d.vehicle.speed, (Axle(37000.0, 0.0), Axle(15000.0, 3.0)))
    )
    for cfg_true, misfit in ((two, True), (d, False)):
        data = bp.simulate(cfg_true, 30, 0)
        res = bp.analyse(data, d, methods="modal", seed=0)
        out = bp.write_run(res, tmp_path / str(misfit))
        md = (out / "report.md").read_text(encoding="utf-8")
        assert (out / "fig_residuals.png").stat().st_size > 0
        assert ("The data contradict the model" in md) is misfit
        if misfit:
            head = md.split("\n## ", 1)[0]
            assert "The data contradict the model" in head and "fig_residuals.png" in head
