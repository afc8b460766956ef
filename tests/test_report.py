"""Reports: run folders with figures, report.md and a self-contained report.html; verdicts; Table 5.

One small modal-only run (40 deflection points, the `smoke` profile, a few seconds) is shared by the
module; other situations (PINN methods, identifiability, failures) are built from it by hand, so no
PINN is trained here.
"""

from __future__ import annotations

import base64
import dataclasses
import json
import logging
import re
from pathlib import Path

import numpy as np
import pytest

from bayespinn.config import preset
from bayespinn.options import RunOptions
from bayespinn.pipeline import RunResult, run
from bayespinn.report import agreement, table5, table5_markdown, write_reports
from bayespinn.report import figures as figmod
from bayespinn.report.sweep import write_sweep_reports
from bayespinn.uq.agreement import compare
from bayespinn.uq.modal_mcmc import ModalPredictor
from bayespinn.uq.posterior import Posterior
from bayespinn.uq.predictive import fe_truth

#: per-sensor figures of scattered deflection points: one per quarter of the span
DEFL_SENSORS = tuple(f"fig_sensor_x{k}.png" for k in range(1, 5))
RUN_FIGURES = (
    "fig_posteriors.png",
    "fig_residuals.png",
    *DEFL_SENSORS,
    "fig_data_fit.png",
    "fig_span_profiles.png",
)
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
#: Table 5 oracle: exact arithmetic on float64 profiles of ~1e-3 m and ~1e5 N m
ORACLE_TOL = 1e-9


def small_config(case: str = "deflection"):
    cfg = preset(case)
    return dataclasses.replace(
        cfg, data=dataclasses.replace(cfg.data, n_points=40, sample_rate=20.0)
    )


@pytest.fixture(scope="module")
def defl(tmp_path_factory):
    """(cfg, RunResult, folder) of a modal-only deflection run at 20 dB."""
    cfg = small_config()
    out = tmp_path_factory.mktemp("run") / "defl"
    res = run(
        cfg,
        methods=["modal"],
        snr_db=20.0,
        seed=0,
        out=out,
        opts=RunOptions(profile="smoke"),
        argv=["test"],
    )
    return cfg, res, out


def assert_self_contained(folder: Path, expected_figures) -> str:
    """report.html embeds every figure of report.md as a PNG data URI and points nowhere outside."""
    md = (folder / "report.md").read_text(encoding="utf-8")
    html = (folder / "report.html").read_text(encoding="utf-8")
    referenced = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", md)
    assert sorted(referenced) == sorted(expected_figures)
    for name in referenced:
        assert (folder / name).read_bytes().startswith(PNG_MAGIC)
    srcs = re.findall(r'src="([^"]*)"', html)
    assert len(srcs) == len(referenced) == html.count("<img ")
    embedded = []
    for s in srcs:
        assert s.startswith("data:image/png;base64,"), s[:60]
        embedded.append(base64.b64decode(s.split(",", 1)[1], validate=True))
    assert sorted(embedded) == sorted((folder / n).read_bytes() for n in referenced)
    for bad in ("http://", "https://", "<script", "<link", "url(", "@import", "<iframe"):
        assert bad not in html.lower(), bad
    for href in re.findall(r'href="([^"]*)"', html):
        assert ":" not in href and not href.startswith("//"), href
    return html


def test_modal_posterior_file_serves_arviz(defl):
    from arviz_check import check_inference_data

    _, res, out = defl
    check_inference_data(out / "posterior_modal_mcmc.nc", res.data, "emcee")


def test_run_writes_figures_and_both_reports(defl):
    cfg, res, out = defl
    for f in RUN_FIGURES + ("report.md", "report.html", "summary.json", "manifest.json"):
        assert (out / f).is_file(), f
    assert not (out / "fig_gauges.png").exists()  # deflection data: no gauges
    md = (out / "report.md").read_text(encoding="utf-8")
    html = assert_self_contained(out, RUN_FIGURES)
    e = res.summary["methods"]["modal_mcmc"]["EI"]
    mean = f"{e['mean'] / 1e9:.4f}"
    for text in (md, html):  # the same content in both
        assert mean in text
        for section in (
            "Data",
            "Flexural rigidity EI",
            "Measurement noise σ",
            "agreement verdict",
            "Diagnostics",
            "Run times",
            "Figures",
            "Table 5",
            "Manifest",
            "Resolved configuration",
        ):
            assert section in text, section
        assert "Only the modal reference ran" in text
        assert "rel. error" in text and "truth unknown" not in text
        assert "the truth and the SNR are unknown" not in text


def test_reports_are_a_function_of_the_result(defl, tmp_path):
    """Same result, same figures: PNG bytes and report text do not depend on when they are written."""
    cfg, res, out = defl
    write_reports(res, cfg, tmp_path)
    for f in RUN_FIGURES + ("report.md",):
        assert (tmp_path / f).read_bytes() == (out / f).read_bytes(), f


def test_the_manifest_file_records_the_reports_time(defl):
    """manifest.json carries the analysis' timings and the report's (`report_s`); the result keeps only the
    analysis', so a report written from it again is the same report."""
    cfg, res, out = defl
    on_disk = json.loads((out / "manifest.json").read_text())["timings_s"]
    assert on_disk["report_s"] > 0
    assert on_disk["total_s"] == res.manifest["timings_s"]["total_s"]
    assert "report_s" not in res.manifest["timings_s"]


def _pinn_like(cfg, res) -> RunResult:
    """The modal run plus an overconfident 'ensemble' (5 draws) and a 'bpinn' without predictor that
    says EI is not identified."""
    truth = res.truth
    modal = res.posteriors["modal_mcmc"]
    m, s = float(modal.EI.mean()), float(modal.EI.std())
    ens_EI = (m + 3 * s + 0.05 * s * np.arange(-2, 3))[None, :]
    ens = Posterior(
        "ensemble",
        ens_EI,
        np.full_like(ens_EI, truth["sigma"]),
        info={
            "members": 5,
            "member_EI": ens_EI.ravel().tolist(),
            "warnings": ["the members disagree: test"],
        },
        runtime_s=1.0,
        predictor=ModalPredictor(cfg, ens_EI.ravel(), 6),
    )
    bp = Posterior("bpinn", modal.EI * 1.5, modal.sigma, info={"identified": False}, runtime_s=2.0)
    posts = {"modal_mcmc": modal, "ensemble": ens, "bpinn": bp}
    summary = {**res.summary, "methods": {k: p.summary(truth) for k, p in posts.items()}}
    return RunResult(res.data, truth, posts, summary, res.manifest)


def test_verdict_identifiability_and_missing_predictor(defl, tmp_path):
    cfg, res, _ = defl
    fake = _pinn_like(cfg, res)
    write_reports(fake, cfg, tmp_path)
    md = (tmp_path / "report.md").read_text(encoding="utf-8")
    # its summary entries carry no fit check, so no residual figure
    html = assert_self_contained(tmp_path, [f for f in RUN_FIGURES if f != "fig_residuals.png"])
    for text in (md, html):
        assert "EI is not identified by these data" in text
        assert "Deep ensemble DISAGREES with the modal reference" in text
        assert "overconfident" in text
        assert "No posterior predictive for B-PINN" in text
        assert (
            "Deep ensemble: the members disagree: test" in text
        )  # a method's own warnings are alerts
    # the not-identified sentence sits above the tables, as an alert
    assert md.index("EI is not identified by these data") < md.index("## Data")
    assert '<div class="alert"' in html.split("<h2>Data</h2>")[0]


def test_a_failing_figure_does_not_lose_the_report(defl, tmp_path, monkeypatch, caplog):
    cfg, res, _ = defl

    def boom(*args, **kwargs):
        raise RuntimeError("simulated drawing failure")

    figs = tuple(
        (f, t, boom if f == "fig_span_profiles.png" else fn) for f, t, fn in figmod.FIGURES
    )
    monkeypatch.setattr(figmod, "FIGURES", figs)
    with caplog.at_level(logging.WARNING):
        write_reports(res, cfg, tmp_path)
    assert any(
        "fig_span_profiles.png" in r.getMessage()
        for r in caplog.records
        if r.levelno == logging.WARNING
    )
    assert not (tmp_path / "fig_span_profiles.png").exists()
    assert_self_contained(
        tmp_path, ("fig_posteriors.png", "fig_residuals.png", *DEFL_SENSORS, "fig_data_fit.png")
    )
    assert "simulated drawing failure" in (tmp_path / "report.md").read_text(encoding="utf-8")


def test_measured_strain_data_with_a_held_out_gauge(tmp_path):
    """Measured data (truth unknown) from gauge S2 only: the report says the truth and SNR are unknown
    and the gauge figure shows S1, S3 and S4 as not used for training (paper Fig. 7)."""
    from bayespinn.data.synthetic import simulate

    cfg = small_config("strain")
    data = simulate(cfg, 30.0, seed=1)
    csv = tmp_path / "s2.csv"
    data.select(data.sensor == "S2").to_csv(csv)
    out = tmp_path / "run"
    res = run(
        cfg,
        methods=["modal"],
        snr_db=None,
        data_path=str(csv),
        seed=0,
        out=out,
        opts=RunOptions(profile="smoke"),
    )
    assert res.truth is None
    figs = [f for f in RUN_FIGURES if f not in DEFL_SENSORS] + [
        "fig_gauges.png",
        "fig_sensor_S2.png",
    ]
    html = assert_self_contained(out, figs)
    md = (out / "report.md").read_text(encoding="utf-8")
    for text in (md, html):
        assert "the truth and the SNR are unknown" in text
        assert "Gauges not used for training (a genuine out-of-sample check): S1, S3, S4." in text
        assert "Table 5" not in text  # needs the truth
        assert "n/a (truth unknown)" in text


def test_agreement_verdicts():
    ref = {"EI": {"mean": 1.0e9, "sd": 1.0e7}}
    ok = compare({"EI": {"mean": 1.005e9, "sd": 1.1e7}}, ref, "ensemble")
    assert ok.agrees is True and ok.mean_diff_sd == pytest.approx(0.5)
    far = compare({"EI": {"mean": 1.02e9, "sd": 1.0e7}}, ref, "ensemble")
    assert far.agrees is False and "mean +2.00 reference sd" in far.reasons[0]
    narrow = compare({"EI": {"mean": 1.0e9, "sd": 0.5e7}}, ref, "bpinn")
    assert narrow.agrees is False and "overconfident" in narrow.reasons[0]
    wide = compare({"EI": {"mean": 1.0e9, "sd": 2.0e7}}, ref, "bpinn")
    assert wide.agrees is False and "underconfident" in wide.reasons[0]
    # the limits themselves: 1 sd and [0.67, 1.5] are inside
    assert compare({"EI": {"mean": 1.0099e9, "sd": 1.49e7}}, ref, "ensemble").agrees is True
    alone = agreement({"ensemble": {"EI": {"mean": 1e9, "sd": 1e7}}})
    assert alone[0].agrees is None
    assert agreement({"modal_mcmc": ref}) == []


def _scaled_truth_predictor(cfg, factor):
    def predictor(x, t, quantity, n_draws, rng):
        return np.tile(factor * fe_truth(cfg, x, t, quantity), (4, 1))

    return predictor


def test_table5_against_an_oracle(defl):
    """A predictor returning 1.1 x the FE truth: NMB = +10 %, CV = 10 rms|truth| / mean|truth| %,
    RMSE = 0.1 rms(truth); the exact truth gives zeros and full coverage (negative control)."""
    cfg, res, _ = defl
    modal = res.posteriors["modal_mcmc"]
    for factor, nmb in ((1.1, 10.0), (1.0, 0.0)):
        p = dataclasses.replace(modal, predictor=_scaled_truth_predictor(cfg, factor))
        fake = dataclasses.replace(res, posteriors={"modal_mcmc": p})
        t5 = table5(fake, cfg, "modal_mcmc", n_points=51)
        assert t5["times"] == [0.60, 1.22, 1.82]
        x = np.linspace(0, cfg.beam.length, 53)[1:-1]
        for row in t5["rows"]:
            for q in ("deflection", "moment"):
                truth = fe_truth(cfg, x, np.full(x.size, row["t"]), q)
                m = row[q]
                rms = float(np.sqrt(np.mean(truth**2)))
                assert m["rmse"] == pytest.approx(
                    abs(factor - 1) * rms, rel=ORACLE_TOL, abs=ORACLE_TOL * rms
                )
                assert m["nmb_pct"] == pytest.approx(nmb, abs=ORACLE_TOL * 100)
                cv = 100 * abs(factor - 1) * rms / float(np.mean(np.abs(truth)))
                assert m["cv_pct"] == pytest.approx(cv, abs=ORACLE_TOL * 100)
                assert m["coverage"] == (1.0 if factor == 1.0 else 0.0)
    md = table5_markdown(t5)
    assert md.count("\n| 0.60 |") == 1 and "CV = RMSE / mean|truth| x 100" in md


def test_table5_on_the_modal_posterior(defl):
    cfg, res, _ = defl
    t5 = table5(res, cfg, "modal_mcmc")
    for row in t5["rows"]:
        for q in ("deflection", "moment"):
            m = row[q]
            assert m["rmse"] >= 0 and 0.0 <= m["coverage"] <= 1.0
            assert m["rmse_ci90"][0] <= m["rmse_ci90"][1]
    with pytest.raises(ValueError, match="truth"):
        table5(dataclasses.replace(res, truth=None), cfg, "modal_mcmc")
    with pytest.raises(ValueError, match="predictive"):
        table5(res, cfg, "bpinn")


def test_sweep_report(defl, tmp_path):
    """Table 4 with intervals per level and the EI-against-SNR figure, self-contained."""
    cfg, res, _ = defl
    levels = [
        {"snr_db": s, "folder": f"snr{s}", "methods": res.summary["methods"]} for s in (20.0, 40.0)
    ]
    doc = {"schema": "bayespinn.sweep/1", "case": "deflection", "seed": 0, "levels": levels}
    write_sweep_reports(doc, [res, res], tmp_path)
    html = assert_self_contained(tmp_path, ("fig_sweep_ei.png",))
    md = (tmp_path / "report.md").read_text(encoding="utf-8")
    e = res.summary["methods"]["modal_mcmc"]["EI"]
    for text in (md, html):
        assert text.count("Modal reference (emcee)") >= 2
        assert f"{e['rel_error_pct']:+.2f} %" in text
        assert "20 dB" in text and "40 dB" in text and "paper EI" in text
        assert "Table 5" in text
    assert 'href="snr20.0/report.html"' in html
    # without results (no truth, no Table 5) it still writes both reports
    write_sweep_reports(doc, [], tmp_path / "bare")
    assert_self_contained(tmp_path / "bare", ("fig_sweep_ei.png",))


# ------------------------------------------------------------------------------------- the answer first
#: the headline must sit within the first lines of report.md (what a reader sees without scrolling)
HEADLINE_LINES = 15


def test_the_answer_comes_first_in_both_reports(defl):
    """EI's 90 % interval, the fit verdict and the agreement verdict in words within the first 15 lines of
    report.md, and as the first text of report.html above any table; provenance at the end."""
    cfg, res, out = defl
    md = (out / "report.md").read_text(encoding="utf-8")
    head = "\n".join(md.splitlines()[:HEADLINE_LINES])
    e = res.summary["methods"]["modal_mcmc"]["EI"]
    lo, hi = (f"{v / 1e9:.3f}" for v in e["ci90"])
    assert f"90 % interval {lo} to {hi} GN·m²" in head
    assert "**Fit:** The model fits the data" in head
    assert "**Agreement:** Only the modal reference ran" in head
    assert md.index("**Fit:**") < md.index("|")  # above every table
    assert md.index("## Flexural rigidity EI") < md.index("## Data") < md.index("## Manifest")
    html = (out / "report.html").read_text(encoding="utf-8")
    body = html.split("<body>", 1)[1]
    assert body.index('class="headline') < body.index("<table")
    assert f"90 % interval {lo} to {hi} GN·m²" in body.split("<table")[0]


def test_the_headline_says_when_a_pinn_disagrees(defl):
    from bayespinn.report.headline import answer

    cfg, res, _ = defl
    a = answer(_pinn_like(cfg, res), advise=lambda r, k: pytest.fail("no misfit: no advice"))
    agree = dict(a.items)["Agreement"]
    assert "**Deep ensemble disagrees** with the modal reference" in agree and not a.ok
    lines = a.lines()
    assert lines[0].startswith("EI = ") and not any("**" in x for x in lines)


def _misfit_run(toml: str, case: str, n_points: int = 100):
    """A modal-only smoke analysis of a misspecified example at 30 dB."""
    import bayespinn as bp

    cfg = bp.resolve(case, toml)
    cfg = dataclasses.replace(cfg, data=dataclasses.replace(cfg.data, n_points=n_points))
    data = bp.simulate(cfg, snr_db=30.0, seed=0)
    return cfg, bp.analyse(data, cfg, methods=("modal",), seed=0, profile="smoke")


def test_a_misfit_says_so_first_with_the_advice_its_residuals_point_to(tmp_path):
    """Bearings that resist rotation analysed as pins: the report's first sentence says the model does not
    fit and advises inferring the support springs, chosen by the residuals (the same code advises EI per
    segment for the damaged girder: `test_the_advice_follows_the_residuals`)."""
    cfg, res = _misfit_run("examples/bearings-as-pinned.toml", "deflection")
    assert res.summary["methods"]["modal_mcmc"]["fit_check"]["verdict"] == "misfit"
    write_reports(res, cfg, tmp_path)
    md = (tmp_path / "report.md").read_text(encoding="utf-8")
    first = next(line for line in md.splitlines()[1:] if line.strip())
    first_sentence = first.split(". ")[0]
    assert first_sentence.startswith("**The model does not fit these data**")
    assert 'infer the support springs (`[model] supports = "springs"`)' in first_sentence
    html = (tmp_path / "report.html").read_text(encoding="utf-8")
    assert 'class="headline warning"' in html
    assert "infer the support springs" in html.split("<table")[0]


@pytest.mark.slow
def test_the_advice_follows_the_residuals():
    """The negative control of the advice: a softer segment analysed as uniform EI (strain gauges) gets
    'EI per segment', not the springs the bearings got."""
    from bayespinn.report.advice import diagnose

    cfg, res = _misfit_run("examples/damaged-as-uniform.toml", "strain")
    adv = diagnose(res, cfg, "modal_mcmc")
    assert "EI_segments" in adv.text and "supports" not in adv.text


def test_noise_advice_reads_the_fit_checks_statistics():
    """Serial correlation alone points to the noise model; with smooth structure too it does not (that is
    a model's shape, diagnosed from the residuals); an AR(1) model already there gets no such advice."""
    from bayespinn.report.advice import noise_advice

    cfg = preset("strain")
    serial = {
        "p_values": {"serial_correlation": 0.0005, "smooth_structure": 0.4},
        "residual_autocorr": 0.8,
    }
    both = {"p_values": {"serial_correlation": 0.0005, "smooth_structure": 0.0005}}
    adv = noise_advice(serial, cfg)
    assert adv is not None and '`[model] noise = "ar1"`' in adv.text and "+0.80" in adv.cause
    assert noise_advice(both, cfg) is None
    ar1 = dataclasses.replace(cfg, model=dataclasses.replace(cfg.model, noise="ar1"))
    assert noise_advice(serial, ar1) is None
    assert noise_advice({}, cfg) is None  # a fit check without per-statistic p-values


def test_one_sensor_out_of_line_points_to_that_sensor():
    from bayespinn.report.advice import sensor_advice

    fc = {"reasons": ["one_sensor:S3"], "worst_sensor": {"name": "S3", "variance_ratio": 4.2}}
    adv = sensor_advice(fc)
    assert adv is not None and "sensor S3" in adv.text and "4.2 times" in adv.cause
    assert sensor_advice({"reasons": ["one_sensor:S3", "smooth_structure"]}) is None
    assert sensor_advice({"reasons": ["serial_correlation"]}) is None and sensor_advice({}) is None


def _png_height(path: Path) -> int:
    import struct

    return struct.unpack(">II", path.read_bytes()[16:24])[1]


def test_per_sensor_figures_give_one_row_per_crossing(defl, tmp_path):
    """Deflection points grouped by stretch of the span, one figure each; a `crossing` column gives each
    crossing a row of its own (the figure grows by one row), and without it the file is one crossing."""
    from bayespinn.report.sensors import crossings_of, sensor_figure, sensor_groups

    cfg, res, _ = defl
    groups = sensor_groups(res.data, cfg.beam.length)
    assert [g[0] for g in groups] == ["x1", "x2", "x3", "x4"]
    assert sum(int(g[2].sum()) for g in groups) == len(res.data)  # every point in one group
    assert crossings_of(res.data)[0][0] is None
    d = res.data
    two = dataclasses.replace(
        d,
        **{
            f: np.concatenate([getattr(d, f), getattr(d, f)])
            for f in ("x", "t", "value", "kind", "y", "sensor")
        },
        value_true=None,
        crossing=np.array(["c0"] * len(d) + ["c1"] * len(d)),
    )
    both = RunResult(two, res.truth, res.posteriors, res.summary, res.manifest, res.config)
    assert [n for n, _ in crossings_of(two)] == ["c0", "c1"]
    rng = np.random.default_rng(0)
    one = sensor_figure(res, groups[1][2], "one", tmp_path / "one.png", rng)
    rows = sensor_groups(two, cfg.beam.length)[1][2]
    sensor_figure(both, rows, "two", tmp_path / "two.png", rng)
    assert "90 %" in one
    assert _png_height(tmp_path / "two.png") > 1.7 * _png_height(tmp_path / "one.png")


def test_the_report_says_where_a_disagreement_comes_from():
    """Each PINN's network share is stated; a PINN that disagrees with a reference whose model fits is
    blamed, one that disagrees with a misfitting reference puts the reference's model in question, and one
    that agrees with a misfitting reference is said to share its error."""
    from bayespinn.report.content import network_lines

    def methods(ref_verdict, pinn_mean):
        return {
            "modal_mcmc": {
                "EI": {"mean": 1.0e9, "sd": 1.0e7},
                "fit_check": {"verdict": ref_verdict},
            },
            "ensemble": {"EI": {"mean": pinn_mean, "sd": 1.0e7}, "network_share": 3.4e-5},
        }

    def text(ref_verdict, pinn_mean):
        m = methods(ref_verdict, pinn_mean)
        (block,) = network_lines(m, {v.method: v for v in agreement(m)})
        return " ".join(block.items)

    assert "carries 0.0034 % of the fitted response" in text("fits", 1.0e9)
    assert "comes from the PINN" in text("fits", 1.05e9)
    assert "reference's model is in question" in text("misfit", 1.05e9)
    assert "shares the reference's error" in text("misfit", 1.0e9)
    assert "shares" not in text("fits", 1.0e9) and "PINN" not in text("fits", 1.0e9).split(":")[1]
    assert network_lines({"modal_mcmc": {"EI": {"mean": 1.0e9, "sd": 1.0e7}}}, {}) == []
