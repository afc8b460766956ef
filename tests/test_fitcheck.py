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
from bayespinn.uq import fitcheck, fitcheck_text
from bayespinn.uq.posterior import Posterior

#: false-failure rate of the statistical tests below
FALSE_FAILURE = 1e-3


def _oracle(data, sigma=1.0, rho=None):
    """A posterior whose prediction is the noise-free truth: the residuals are exactly the noise (with
    an AR(1) coefficient rho: a posterior of the AR(1) noise model at that coefficient)."""
    truth = np.asarray(data.value_true, float)
    strain = np.asarray(data.kind) == "strain"

    def predictor(x, t, quantity, n, rng):
        rows = strain if quantity == "curvature" else ~strain
        v = truth[rows] if quantity == "deflection" else -truth[rows] / data.y[rows]
        return np.broadcast_to(v, (n, v.size))

    post = Posterior("oracle", np.ones((1, 4)), np.full((1, 4), sigma), predictor=predictor)
    if rho is not None:
        post.noise_ar1 = np.full(4, rho)
    return post


def _verdicts(cfg, n, *, transform=None, seed0=0, rho=None, check=None):
    """The fit check's results on n datasets of the layout of cfg: the truth plus white noise (AR(1) at
    coefficient rho when given, and an AR(1) oracle), perturbed by transform(layout, noise, rng)."""
    from bayespinn.data.synthetic import ar1_noise

    check = check or fitcheck.check
    layout = bp.simulate(cfg, None, 0)
    L, T = cfg.beam.length, cfg.duration
    out = []
    for i in range(n):
        r = np.random.default_rng(seed0 + i)
        sd = 1e-4 * np.abs(layout.value_true).max()
        z = r.standard_normal(len(layout))
        noise = sd * (z if rho is None else ar1_noise(z, layout, rho))
        if transform is not None:
            noise = transform(layout, noise, r)
        data = layout.with_values(layout.value_true + noise)
        out.append(check(_oracle(data, sd, rho), data, L, T, seed=i))
    return out


def _alarms(cfg, n, **kw):
    return sum(fc["verdict"] == "misfit" for fc in _verdicts(cfg, n, **kw))


def few_alarms(hits: int, n: int) -> bool:
    """False alarms within the upper edge of the binomial acceptance region of a check at its stated rate
    (false-failure rate FALSE_FAILURE)."""
    return hits <= stats.binom.isf(FALSE_FAILURE, n, fitcheck.FALSE_ALARM)


def _always(verdict):
    return lambda post, data, length, duration, *, seed=0: {"verdict": verdict, "reasons": []}


@pytest.mark.parametrize("case", ["deflection", "strain"])
def test_white_noise_rarely_raises_the_alarm(case):
    """Residuals that are white noise: alarms follow Binomial(n, FALSE_ALARM) (the bootstrap's p-value is
    calibrated, not merely conservative); the upper edge of the acceptance region at a 1e-3 false-failure
    rate. Negative control: a check that always says misfit fails the same acceptance."""
    cfg = bp.resolve(case, {"data": {"sample_rate": 100.0}} if case == "strain" else None)
    n = 300
    assert few_alarms(_alarms(cfg, n), n)
    assert not few_alarms(_alarms(cfg, 20, check=_always("misfit")), 20)


def test_smooth_structure_and_serial_correlation_raise_it():
    """Negative controls: a smooth shape in the residuals (peak 3 noise sd, RMS about 1.1 sd over 100
    points) and AR(1) noise (coefficient 0.8) under the white-noise model are flagged almost always, and
    named: smooth structure, serial correlation. A check that always says fits fails the same test."""
    d = bp.resolve("deflection")

    def bump(layout, noise, r):
        sd = noise.std()
        return noise + 3.0 * sd * np.sin(np.pi * layout.x / d.beam.length) * (layout.t / d.duration)

    got = _verdicts(d, 40, transform=bump)
    assert sum(fc["verdict"] == "misfit" for fc in got) >= 36
    assert all("smooth_structure" in fc["reasons"] for fc in got if fc["verdict"] == "misfit")
    assert _alarms(d, 40, transform=bump, check=_always("fits")) < 36
    s = bp.resolve("strain", {"data": {"sample_rate": 100.0}})

    def ar1(layout, noise, r):
        out = noise.copy()
        for name in set(layout.sensor):
            rows = np.flatnonzero(layout.sensor == name)
            for a, b in zip(rows[:-1], rows[1:], strict=True):
                out[b] = 0.8 * out[a] + 0.6 * noise[b]
        return out

    got = _verdicts(s, 40, transform=ar1)
    assert all(fc["verdict"] == "misfit" and "serial_correlation" in fc["reasons"] for fc in got)
    assert all('noise = "ar1"' in fc["detail"] for fc in got)


def test_ar1_noise_fits_its_own_model_and_smooth_structure_still_does_not():
    """Under the AR(1) noise model (coefficient 0.8, as simulated): AR(1) noise alone rarely raises the
    alarm (binomial region at FALSE_ALARM); a smooth bump sin(pi t / T) of one noise sd added to every
    gauge, which AR(1) cannot explain, is flagged as smooth structure almost always (measured 20 of 20);
    the check with its smooth statistic removed (negative control) misses it. At 200 Hz, as the AR(1)
    example: at 100 Hz the same bump over half the samples is caught about half the time."""
    s = bp.resolve("strain", {"data": {"sample_rate": 200.0}})
    n = 40
    assert few_alarms(_alarms(s, n, rho=0.8), n)

    def bump(layout, noise, r):
        return noise + noise.std() * np.sin(np.pi * layout.t / s.duration)

    got = _verdicts(s, 20, rho=0.8, transform=bump)
    assert (
        sum(fc["verdict"] == "misfit" and "smooth_structure" in fc["reasons"] for fc in got) >= 17
    )
    assert all(fc["null"] == "ar1" and fc["whitening_ar1"] > 0.7 for fc in got)


def test_without_its_smooth_statistic_the_check_misses_a_bump(monkeypatch):
    """Negative control of the test above: the same bumps, the smooth statistic disabled."""
    s = bp.resolve("strain", {"data": {"sample_rate": 200.0}})

    def bump(layout, noise, r):
        return noise + noise.std() * np.sin(np.pi * layout.t / s.duration)

    def none(sums, series, g, timing, crossings):
        R = sums.energy.shape[0]
        return np.full(R, -np.inf), np.full((R, len(fitcheck.fs.BANDS)), -np.inf)

    monkeypatch.setattr(fitcheck.fs, "smooth_statistic", none)
    got = _verdicts(s, 10, rho=0.8, transform=bump)
    assert sum(fc["verdict"] == "misfit" for fc in got) < 17 * 10 / 20


def test_one_sensor_is_named():
    """A gauge reading 5 % high (a calibration error) at 20 dB: misfit, naming that gauge, in the reasons
    and in the detail."""
    s = bp.resolve("strain", {"data": {"sample_rate": 100.0}})

    def gain(layout, noise, r):
        return noise + 0.05 * layout.value_true * (layout.sensor == "S2")

    for fc in _verdicts(s, 5, transform=gain):
        assert fc["verdict"] == "misfit" and "one_sensor:S2" in fc["reasons"], fc["reasons"]
        assert "sensor S2" in fc["detail"] and fc["worst_sensor"]["name"] == "S2"


def _with_crossings(data, labels):
    from bayespinn.data.measurements import Measurements

    if "crossing" in {f.name for f in dataclasses.fields(Measurements)}:
        return dataclasses.replace(data, crossing=np.asarray(labels).astype(str))
    object.__setattr__(data, "crossing", np.asarray(labels).astype(str))
    return data


def test_several_crossings_name_the_worst():
    """Six crossings of the four gauges, one (c4) with gauge S2 reading 10 % high: misfit, the worst
    crossing named (reasons and worst_crossing) with its own reasons; each crossing has its verdict. The
    same data with one label, or none, is one crossing (no by_crossing)."""
    s = bp.resolve("strain", {"data": {"sample_rate": 100.0}})
    lay = bp.simulate(s, None, 0)
    sd = 0.05 * np.sqrt(np.mean(lay.value_true**2))
    r = np.random.default_rng(5)
    k = 6
    cat = {f: np.concatenate([getattr(lay, f)] * k) for f in ("x", "t", "kind", "y", "sensor")}
    truth = np.concatenate([lay.value_true] * k)
    labels = np.repeat([f"c{i}" for i in range(k)], len(lay))
    value = truth + sd * r.standard_normal(truth.size)
    value += 0.1 * truth * ((labels == "c4") & (cat["sensor"] == "S2"))
    from bayespinn.data.measurements import Measurements

    data = _with_crossings(
        Measurements(cat["x"], cat["t"], value, cat["kind"], cat["y"], cat["sensor"], truth), labels
    )
    fc = fitcheck.check(_oracle(data, sd), data, s.beam.length, s.duration, seed=0)
    assert fc["verdict"] == "misfit" and fc["worst_crossing"] == "c4"
    assert "crossing:c4" in fc["reasons"] and "one_sensor:S2" in fc["reasons"]
    assert set(fc["by_crossing"]) == {f"c{i}" for i in range(k)}
    assert fc["by_crossing"]["c4"]["verdict"] == "misfit"
    assert sum(c["verdict"] == "misfit" for c in fc["by_crossing"].values()) <= 2
    one = _with_crossings(dataclasses.replace(data), np.full(truth.size, "c0"))
    for d in (
        one,
        dataclasses.replace(data, **({"crossing": None} if hasattr(data, "crossing") else {})),
    ):
        assert "by_crossing" not in fitcheck.check(_oracle(d, sd), d, s.beam.length, s.duration)


def test_p_values_carry_their_monte_carlo_resolution():
    """The p-value's resolution is 1 / (replicates + 1); at its floor the detail says "p < 1/1000" rather
    than quoting the floor as a measurement."""
    d = bp.resolve("deflection")

    def bump(layout, noise, r):
        return noise + 20.0 * noise.std() * np.sin(np.pi * layout.x / d.beam.length)

    (fc,) = _verdicts(d, 1, transform=bump)
    B = fitcheck.REPLICATES
    assert fc["replicates"] == B and fc["p_value_resolution"] == pytest.approx(1 / (B + 1))
    assert fc["p_values"]["smooth_structure"] == pytest.approx(1 / (B + 1))
    assert f"p < 1/{B + 1}" in fc["detail"] and "0.001" not in fc["detail"]
    assert 0 < fc["p_value_se"] < 0.01
    assert fitcheck_text.p_text(0.25, B) == "p = 0.25"


def test_hat_directions_recover_a_linear_fit():
    """For a linear-Gaussian model the posterior covariance of the mean prediction is sigma^2 times the hat
    matrix: from 400 posterior draws, three directions of leverage about 1 spanning the design."""
    rng = np.random.default_rng(0)
    n, sigma = 300, 0.7
    G = np.linalg.qr(rng.standard_normal((n, 3)))[0] * 5.0
    cov = sigma**2 * np.linalg.inv(G.T @ G)
    theta = rng.multivariate_normal(np.zeros(3), cov, size=400)
    series = fitcheck.fs.layout(np.zeros(n), np.arange(n, dtype=float), np.full(n, "a"), None, 1, n)
    order, blocks = fitcheck.fs.order_of(series)
    V, h = fitcheck.fs.hat_directions((theta @ G.T)[:, order], sigma, None, blocks)
    assert V.shape == (n, 3) and np.all(np.abs(h - 1) < 0.35), h
    Qg = np.linalg.qr(G[order])[0]
    assert np.linalg.svd(Qg.T @ V, compute_uv=False).min() > 0.99


def _modal_check(cfg_true, cfg_model, snr, seed, noise=None):
    data = bp.simulate(cfg_true, snr, seed)
    if noise is not None:
        data = data.with_values(data.value_true + noise(data))
    res = bp.analyse(data, cfg_model, methods="modal", seed=seed)
    return res.summary["methods"]["modal_mcmc"]["fit_check"]


def test_modal_reference_end_to_end():
    """Through `analyse`: the well-specified Exeter data fit; data from a truck with a second axle the model
    does not know do not, and the reason named is smooth structure."""
    d = bp.resolve("deflection")
    ok = _modal_check(d, d, 30, 0)
    assert ok["verdict"] == "fits" and set(ok) >= {"p_value", "statistic", "residual_autocorr"}
    two = dataclasses.replace(
        d, vehicle=Vehicle(d.vehicle.speed, (Axle(37000.0, 0.0), Axle(15000.0, 3.0)))
    )
    bad = _modal_check(two, d, 30, 0)
    assert bad["verdict"] == "misfit" and bad["reasons"][0] == "smooth_structure", bad["reasons"]
    assert ok["reasons"] == [] and ok["detail"].startswith("The residuals are what white noise")


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


@pytest.mark.slow
def test_modal_reference_under_ar1_noise_flags_a_wrong_speed():
    """The modal reference with the AR(1) likelihood on AR(1) strain noise (coefficient 0.8, 200 Hz,
    20 dB): data from the stated speed fit; data from a vehicle 1 % faster than stated, which puts EI
    about 2-3 posterior sd off (measured with a linearised fit: +1.9 to +2.7 sd), do not, and the reason
    named is the response shifted or stretched in time (smooth structure in its timing band), which
    the fitted AR(1) coefficient cannot explain."""
    s = bp.resolve(
        "strain", {"data": {"sample_rate": 200.0, "noise_ar1": 0.8}, "model": {"noise": "ar1"}}
    )
    fast = dataclasses.replace(
        s, vehicle=dataclasses.replace(s.vehicle, speed=s.vehicle.speed * 1.01)
    )
    ok = _modal_check(s, s, 20, 1)
    assert ok["verdict"] == "fits" and ok["null"] == "ar1", ok["detail"]
    bad = _modal_check(fast, s, 20, 1)
    assert bad["verdict"] == "misfit" and "smooth_structure" in bad["reasons"], bad["detail"]
    assert bad["smooth_band"] == "timing" and "speed" in bad["detail"]


def test_calibration_study_records_false_alarms_with_provenance(tmp_path):
    """`studies/fitcheck_calibration.py` (one replicate of one cell: the plumbing, not the calibration):
    a record with the false alarms, the binomial region and the provenance; a rerun resumes without
    recomputing; a method it does not know exits 2 naming --methods."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    script = repo / "studies" / "fitcheck_calibration.py"
    args = ["--case", "deflection", "--snr", "40", "--replicates", "1", "--out", str(tmp_path)]
    run = lambda *a: subprocess.run(  # noqa: E731
        [sys.executable, str(script), *a, "--quiet"], capture_output=True, text=True, cwd=repo
    )
    r = run(*args)
    assert r.returncode == 0, r.stderr[-3000:]
    path = tmp_path / "calibration-modal-exeter-deflection-snr40.json"
    doc = json.loads(path.read_text())
    s = doc["summary"]
    assert s["replicates"] == 1 and s["false_alarms"] in (0, 1) and s["region"][0] <= s["region"][1]
    assert s["stated_rate"] == fitcheck.FALSE_ALARM and s["inside"] == (
        s["region"][0] <= s["false_alarms"] <= s["region"][1]
    )
    prov = doc["provenance"]
    assert {"command", "seed", "git_commit", "versions", "machine"} <= set(prov)
    rec = doc["records"][0]
    assert rec["verdict"] in ("fits", "misfit") and isinstance(rec["reasons"], list)
    assert run(*args).returncode == 0
    assert json.loads(path.read_text())["records"] == doc["records"]
    bad = run(*args, "--methods", "modal,nope")
    assert bad.returncode == 2 and "--methods" in bad.stderr and "Traceback" not in bad.stderr


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
        assert ("The model does not fit these data" in md) is misfit
        if misfit:
            head = md.split("\n## ", 1)[0]
            assert "The model does not fit these data" in head and "fig_residuals.png" in head


def test_a_predictor_with_fewer_draws_than_asked_is_used_as_it_is():
    """An ensemble returns a whole number of draws per member, fewer than asked; a point predictor one
    row: the prediction draws take what the predictor has instead of failing on the shape."""
    data = bp.simulate(bp.resolve("strain"), 30, 0)
    post = _oracle(data)
    inner = post.predictor
    post.predictor = lambda x, t, q, n, rng: inner(x, t, q, n, rng)[: n - 2]
    d = fitcheck.prediction_draws(post, data, draws=32)
    assert d.shape == (30, len(data))
    np.testing.assert_allclose(d[0], data.value_true, rtol=1e-12, atol=0)
    post.predictor = lambda x, t, q, n, rng: inner(x, t, q, 1, rng)
    assert fitcheck.prediction_draws(post, data, draws=32).shape == (1, len(data))
