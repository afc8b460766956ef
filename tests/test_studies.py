"""The study scripts run end to end with tiny arguments (numpyro-examples style), so they never rot.

Each script is run as a subprocess, as a user would, into tmp_path with the smoke profile and the modal
reference (seconds); the PINN methods' smoke runs take about a minute and are marked slow.
"""

from __future__ import annotations

import importlib.util
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
STUDIES = REPO / "studies"
#: a subprocess that takes longer than this has hung (the slowest fast-tier script takes ~20 s)
TIMEOUT_S = 300


def study(script: str, *args: str, expect: int = 0) -> subprocess.CompletedProcess:
    r = subprocess.run(
        [sys.executable, str(STUDIES / script), *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        env={**os.environ, "MPLBACKEND": "Agg"},
    )
    assert r.returncode == expect, (
        f"{script} {' '.join(args)} exited {r.returncode}\n{r.stderr[-4000:]}"
    )
    return r


def load(path: Path) -> dict:
    assert path.exists(), f"{path} not written"
    return json.loads(path.read_text(encoding="utf-8"))


def assert_provenance(md: str, script: str) -> None:
    """The Markdown says how it was made: command, profile, seed, date, machine."""
    assert f"python studies/{script}" in md
    assert "profile **smoke**" in md and "seed 0" in md
    assert "CPU cores" in md and "torch threads" in md
    assert "20" in md.split("## Provenance", 1)[1]  # the date


@pytest.fixture(scope="module")
def studies_lib():
    sys.path.insert(0, str(STUDIES))
    try:
        import common

        yield common
    finally:
        sys.path.remove(str(STUDIES))


def test_table4_then_table5_modal(tmp_path):
    study(
        "table4.py",
        "--profile",
        "smoke",
        "--methods",
        "modal",
        "--snr",
        "clean,30",
        "--out",
        str(tmp_path),
        "--quiet",
    )
    doc = load(tmp_path / "table4.json")
    assert doc["schema"] == "bayespinn.studies.table4/1"
    assert [(r["snr_db"], r["method"]) for r in doc["rows"]] == [
        (None, "modal_mcmc"),
        (30.0, "modal_mcmc"),
    ]
    for r in doc["rows"]:
        e = r["EI"]
        assert e["ci95"][0] <= e["ci90"][0] <= e["mean"] <= e["ci90"][1] <= e["ci95"][1]
        assert isinstance(r["truth_in_ci90"], bool) and math.isfinite(e["rel_error_pct"])
        assert r["paper"]["EI"] > 1e9 and (tmp_path / r["folder"] / "summary.json").exists()
    for f in (
        "table4/sweep.json",
        "table4/report.md",
        "table4/report.html",
        "table4/modal_mcmc/sweep.json",
    ):
        assert (tmp_path / f).exists(), f
    md = (tmp_path / "table4.md").read_text(encoding="utf-8")
    assert (
        "1,036,091" in md and "1,033,610" in md
    )  # the paper's clean estimate and the truth, in kN m^2
    assert_provenance(md, "table4.py")

    # Table 5 reuses table4's data and gets the very same posterior back
    study(
        "table5.py",
        "--profile",
        "smoke",
        "--methods",
        "modal",
        "--snr",
        "30",
        "--out",
        str(tmp_path),
        "--quiet",
    )
    t5 = load(tmp_path / "table5.json")
    (row,) = t5["rows"]
    assert row["snr_db"] == 30.0 and row["same_posterior_as_table4"] is True
    assert row["source"].startswith(
        "stored by table4's run"
    )  # the run folder's table5.json, no re-inference
    # without the stored table the level is inferred again on table4's data: the same table comes back
    (tmp_path / "table4" / "modal_mcmc" / "snr30" / "table5.json").unlink()
    study(
        "table5.py",
        "--profile",
        "smoke",
        "--methods",
        "modal",
        "--snr",
        "30",
        "--out",
        str(tmp_path),
        "--quiet",
    )
    (again,) = load(tmp_path / "table5.json")["rows"]
    assert (
        again["source"].startswith("data of table4") and again["same_posterior_as_table4"] is True
    )
    assert again["table5"] == row["table5"]
    assert [round(x["t"], 2) for x in row["table5"]["rows"]] == [0.60, 1.22, 1.82]
    for x in row["table5"]["rows"]:
        for q in ("deflection", "moment"):
            assert x[q]["rmse"] >= 0 and 0.0 <= x[q]["coverage"] <= 1.0
    assert_provenance((tmp_path / "table5.md").read_text(encoding="utf-8"), "table5.py")


def test_table6_modal_with_and_without_data(tmp_path):
    study(
        "table6.py",
        "--profile",
        "smoke",
        "--methods",
        "modal",
        "--sample-rate",
        "50",
        "--out",
        str(tmp_path),
        "--quiet",
    )
    doc = load(tmp_path / "table6.json")
    rows = {r["scenario"]: r for r in doc["rows"]}
    assert rows["data"]["gauges"] == ["S2"] and rows["data"]["identified"] is True
    assert rows["none"]["rows"] == 0 and rows["none"]["identified"] is False
    assert (tmp_path / rows["data"]["folder"] / "report.md").exists()
    md = (tmp_path / "table6.md").read_text(encoding="utf-8")
    assert "EI is not identified by these data" in md
    assert_provenance(md, "table6.py")


def test_coverage_modal(tmp_path):
    study(
        "coverage.py",
        "--profile",
        "smoke",
        "--methods",
        "modal",
        "--snr",
        "30",
        "--replicates",
        "3",
        "--out",
        str(tmp_path),
        "--quiet",
    )
    doc = load(tmp_path / "coverage.json")
    (row,) = doc["rows"]
    assert row["replicates"] == 3 and 0 <= row["hits"] <= 3
    lo, hi = row["acceptance_99"]
    assert 0 <= lo <= hi <= 3
    full = load(tmp_path / row["file"])
    assert full["schema"] == "bayespinn.coverage/1" and len(full["records"]) == 3
    assert_provenance((tmp_path / "coverage.md").read_text(encoding="utf-8"), "coverage.py")
    # --report-only rebuilds the page; a PINN study of the same datasets is set beside the reference,
    # dataset by dataset (here a copy of the modal study posing as the ensemble: z = 0, sd ratio 1)
    (tmp_path / "coverage" / "ensemble-snr30.json").write_text(
        json.dumps(dict(full, method="ensemble")), encoding="utf-8"
    )
    doc["rows"].append(dict(row, method="ensemble", file="coverage/ensemble-snr30.json"))
    (tmp_path / "coverage.json").write_text(json.dumps(doc), encoding="utf-8")
    study("coverage.py", "--report-only", "--out", str(tmp_path), "--quiet")
    rows = {r["method"]: r for r in load(tmp_path / "coverage.json")["rows"]}
    pr = rows["ensemble"]["paired_reference"]
    assert pr["datasets"] == 3 and pr["mean_z"] == 0.0 and pr["median_sd_ratio"] == 1.0
    # the ranks of both on the shared datasets: the copy's are the reference's, so are their p values
    assert pr["rank_uniformity_p"] == pr["reference_rank_uniformity_p"] == full["rank_uniformity_p"]
    assert "paired_reference" not in rows["modal_mcmc"]
    assert "dataset by dataset" in (tmp_path / "coverage.md").read_text(encoding="utf-8")
    # a study carried on later: --resume reuses the 3 replicates of its file and runs one more
    study(
        "coverage.py",
        "--profile",
        "smoke",
        "--methods",
        "modal",
        "--snr",
        "30",
        "--replicates",
        "4",
        "--resume",
        "--out",
        str(tmp_path),
        "--quiet",
    )
    again = {r["method"]: r for r in load(tmp_path / "coverage.json")["rows"]}["modal_mcmc"]
    assert again["replicates"] == 4 and again["resumed_replicates"] == 3
    assert load(tmp_path / again["file"])["records"][:3] == full["records"]
    # each replicate names its commit; the row says which commits its replicates came from
    from bayespinn.provenance import commits, commits_text

    counts = commits(load(tmp_path / again["file"])["records"])
    assert sum(counts.values()) == 4
    assert again["code"] == ("replicates at " + commits_text(counts)) or set(counts) == {
        "unrecorded"
    }
    # a replicate of an older commit, resumed: it is kept and counted under its own commit
    f = tmp_path / again["file"]
    old = load(f)
    old["records"][0].update(git_commit="0123456789abcdef", git_dirty=False)
    f.write_text(json.dumps(old), encoding="utf-8")
    study("coverage.py", "--report-only", "--out", str(tmp_path), "--quiet")
    row = {r["method"]: r for r in load(tmp_path / "coverage.json")["rows"]}["modal_mcmc"]
    assert "0123456789ab (1)" in row["code"]
    # a study file rewritten without its row being merged (a run stopped in a later level, before rows
    # were merged level by level) must not lend the row its commits
    f.write_text(json.dumps(dict(load(f), hits=(again["hits"] + 1) % 5)), encoding="utf-8")
    study("coverage.py", "--report-only", "--out", str(tmp_path), "--quiet")
    row = {r["method"]: r for r in load(tmp_path / "coverage.json")["rows"]}["modal_mcmc"]
    assert row["code"].startswith("the row's numbers are not those of")


def test_bad_method_is_bad_usage(tmp_path):
    r = study("table4.py", "--methods", "nonsense", "--out", str(tmp_path), expect=2)
    assert "--method" in r.stderr
    assert not (tmp_path / "table4.json").exists()


def test_merge_replaces_rows_of_the_rerun_methods_only(studies_lib):
    c = studies_lib

    def sort(r):
        return (c.snr_key(r["snr_db"]), c.method_key(r["method"]))

    doc = {"schema": "s", "rows": [], "runs": {}}
    p1 = {"date": "d1", "methods": ["modal_mcmc"]}
    c.merge(
        doc,
        [
            {"snr_db": 10.0, "method": "modal_mcmc", "v": 1},
            {"snr_db": None, "method": "modal_mcmc", "v": 1},
        ],
        p1,
        ("snr_db", "method"),
        sort,
    )
    p2 = {"date": "d2", "methods": ["ensemble"]}
    c.merge(doc, [{"snr_db": 10.0, "method": "ensemble", "v": 2}], p2, ("snr_db", "method"), sort)
    assert [(r["snr_db"], r["method"]) for r in doc["rows"]] == [
        (None, "modal_mcmc"),
        (10.0, "modal_mcmc"),
        (10.0, "ensemble"),
    ]
    p3 = {"date": "d3", "methods": ["modal_mcmc"]}
    c.merge(doc, [{"snr_db": 10, "method": "modal_mcmc", "v": 3}], p3, ("snr_db", "method"), sort)
    assert [r["v"] for r in doc["rows"]] == [1, 3, 2]
    assert len(doc["runs"]) == 3
    p4 = {"date": "d4", "methods": ["modal_mcmc"]}
    c.merge(doc, [{"snr_db": None, "method": "modal_mcmc", "v": 4}], p4, ("snr_db", "method"), sort)
    assert set(doc["runs"]) == {c.run_id(p) for p in (p2, p3, p4)}  # run 1 no longer has rows


def test_replicates_option(studies_lib):
    # loaded under another name: `coverage` is also the name of a well-known package
    spec = importlib.util.spec_from_file_location("studies_coverage", STUDIES / "coverage.py")
    cov_script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(cov_script)
    assert cov_script.replicates_of(None, ["modal", "bpinn"]) == {"modal": 200, "bpinn": 20}
    assert cov_script.replicates_of("4", ["modal", "ensemble"]) == {"modal": 4, "ensemble": 4}
    assert cov_script.replicates_of("ensemble=7", ["modal", "ensemble"]) == {
        "modal": 200,
        "ensemble": 7,
    }


@pytest.mark.slow
def test_table4_pinn_rows_merge_with_modal(tmp_path):
    study(
        "table4.py",
        "--profile",
        "smoke",
        "--methods",
        "modal",
        "--snr",
        "30",
        "--out",
        str(tmp_path),
        "--quiet",
    )
    study(
        "table4.py",
        "--profile",
        "smoke",
        "--methods",
        "ensemble",
        "--members",
        "2",
        "--snr",
        "30",
        "--out",
        str(tmp_path),
        "--quiet",
    )
    doc = load(tmp_path / "table4.json")
    assert [r["method"] for r in doc["rows"]] == ["modal_mcmc", "ensemble"]
    assert len(doc["runs"]) == 2
    sweep = load(tmp_path / "table4" / "sweep.json")
    assert set(sweep["levels"][0]["methods"]) == {"modal_mcmc", "ensemble"}


@pytest.mark.slow
def test_table6_pinn_methods_without_data_do_not_crash(tmp_path):
    study(
        "table6.py",
        "--profile",
        "smoke",
        "--methods",
        "ensemble,bpinn",
        "--members",
        "2",
        "--sample-rate",
        "50",
        "--out",
        str(tmp_path),
        "--quiet",
    )
    doc = load(tmp_path / "table6.json")
    for r in doc["rows"]:
        if r["scenario"] == "none":
            assert "error" in r or r["identified"] is False


def test_check_quadrature_accepts_the_modal_reference_and_rejects_a_wrong_one(tmp_path):
    """The issue's acceptance check on a real run folder; negative control: the same run checked
    against a bridge with a different true mass (so a different exact posterior) must fail."""
    run = tmp_path / "run"
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "bayespinn",
            "run",
            "--snr",
            "20",
            "--method",
            "modal",
            "--seed",
            "5",
            "--out",
            str(run),
            "--quiet",
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )
    assert r.returncode == 0, r.stderr
    ok = study("check_quadrature.py", str(run))
    assert "meets the acceptance" in ok.stdout
    heavy = tmp_path / "heavy.toml"
    heavy.write_text("[beam]\nmass_per_length = 400.0\n")
    bad = study("check_quadrature.py", str(run), "--config", str(heavy), expect=1)
    assert "MISSES" in bad.stdout


@pytest.mark.slow
def test_pde_sd_sweep_rebuilds_members_with_each_factor(tmp_path):
    """The strain diagnostic (issue 21): one ensemble, each member's last layer rebuilt per PDE pseudo-sd
    factor. A larger pseudo-sd says less about EI from the physics, so the members' marginals widen; were
    the factor not applied, every factor would give the same widths and this would fail."""
    study("pde_sd_sweep.py", "0", "--case", "strain", "--profile", "smoke", "--out", str(tmp_path))
    doc = load(tmp_path / "pde-sd-strain-bridge0.json")
    assert doc["case"] == "strain" and doc["profile"] == "smoke" and doc["ref_sd_log_EI"] > 0
    rows = doc["factors"]
    assert list(rows) == ["1", "3", "10", "30", "100", "ess", "gls"]
    for r in rows.values():
        assert 1 <= len(r["member_z"]) == len(r["member_width"]) <= 5
        assert all(math.isfinite(w) and w > 0 for w in r["member_width"])
    widths = [sum(r["member_width"]) / len(r["member_width"]) for r in list(rows.values())[:5]]
    assert widths[-1] > 1.05 * widths[0], widths
    for c in doc["residual_correlation"]:  # the factor each member's "ess" row used
        assert 1.0 <= c["n_eff"] <= c["n"]
        assert c["factor"] == pytest.approx(math.sqrt(c["n"] / c["n_eff"]), rel=1e-3)


def test_residual_effective_count_follows_the_correlation(monkeypatch):
    """`pde_sd_sweep.fit_correlation`'s n_eff = n^2 / sum_ij C_ij: a constant field is one observation,
    a smooth one a handful, white noise hundreds. The control: summing the correlation only within the
    blocks it is computed in (not over every pair) would count the constant field as n / 500 = 2. The fit
    runs on 200 points (600 in the study) to keep the test fast."""
    sys.path.insert(0, str(STUDIES))
    try:
        import pde_sd_sweep as S
    finally:
        sys.path.remove(str(STUDIES))
    rng = np.random.default_rng(1)
    n = 1000
    xi, tau = rng.uniform(size=n), rng.uniform(size=n)
    monkeypatch.setattr(S, "CORR_FIT_POINTS", 200)
    fit = lambda r: S.fit_correlation(xi, tau, r, np.random.default_rng(0))  # noqa: E731
    const = fit(np.ones(n) + 1e-3 * rng.normal(size=n))
    assert const["n_eff"] < 1.5, const
    smooth = fit(np.sin(3 * xi) * np.cos(4 * tau))
    assert 1.0 < smooth["n_eff"] < 10.0, smooth
    white = fit(rng.normal(size=n))
    assert white["n_eff"] > 200.0, white
    assert white["factor"] == pytest.approx(math.sqrt(n / white["n_eff"]))


def test_strain_offset_check_recovers_the_truth_from_its_own_model(tmp_path):
    """The point-load model fitted to its own prediction returns the true EI, and the Gaussian model with
    its bias factor does too (the factor is that very fit); without the factor it would sit log(factor)
    away, which the control checks is far more than the tolerance."""
    study("strain_offset_check.py", "--bridges", "1", "--out", str(tmp_path))
    (row,) = load(tmp_path / "offset-checks-strain.json")
    own = row["fits_log_ratio"]["clean_modal"]
    assert abs(own["point"]) < 1e-8 and abs(own["gauss_corrected"]) < 1e-7
    assert abs(math.log(row["beta_factor"])) > 1e3 * 1e-7  # the control: uncorrected is far off


def test_gpu_compare_sets_the_studies_side_by_side_on_the_datasets_both_ran(tmp_path):
    """A GPU study extended past the CPU study's replicates is compared with it on the shared datasets only;
    the extra replicates count in the GPU study's own row against the reference. Control: an extreme
    replicate beyond the CPU study moves the whole-study sd of z but not the side-by-side ratio."""
    head = {"seed": 0, "snr_db": 30.0, "case": "deflection", "truth": "fixed", "level": 0.9}
    head |= {"seeding": "seed/snr/index", "method": "ensemble", "runtime_s": 1.0}

    def doc(errs, sds, method="ensemble"):
        recs = [
            {"index": i, "rel_error_pct": e, "sd_rel_pct": s, "hit": abs(e) < 1.64 * s}
            for i, (e, s) in enumerate(zip(errs, sds, strict=True))
        ]
        hits = sum(r["hit"] for r in recs)
        return head | {"method": method, "replicates": len(recs), "hits": hits, "records": recs}

    cpu_dir = tmp_path / "cpu"
    cpu_dir.mkdir()
    ref = doc([0.0, 0.1, -0.1, 0.0], [0.2] * 4, "modal_mcmc")
    (cpu_dir / "modal_mcmc-snr30.json").write_text(json.dumps(ref))
    (cpu_dir / "ensemble-snr30.json").write_text(json.dumps(doc([0.02, 0.1, -0.14], [0.2] * 3)))
    gpu = tmp_path / "gpu.json"
    gpu.write_text(json.dumps(doc([0.0, 0.12, -0.12, 2.0], [0.2, 0.2, 0.2, 0.22])))
    r = study("gpu_compare.py", str(gpu), "--cpu", str(cpu_dir))
    assert "On the 3 datasets both studies ran" in r.stdout
    res = json.loads((tmp_path / "gpu.compare.json").read_text())
    assert res["shared_datasets"] == 3 and res["gpu_vs_reference"]["datasets"] == 3
    assert res["gpu_all_vs_reference"]["datasets"] == 4
    assert res["gpu_all_vs_reference"]["max_abs_z"] == pytest.approx(10.0)  # the extreme replicate
    assert res["gpu_vs_reference"]["sd_z"] == pytest.approx(0.1)  # z = 0, 0.1, -0.1
    assert res["sd_z_ratio_to_cpu"] == pytest.approx(0.1 / np.std([0.1, 0.0, -0.2], ddof=1))
    assert res["median_sd_ratio_ratio_to_cpu"] == pytest.approx(1.0)


def test_rerun_lists_every_cited_study_with_its_expected_time():
    """`studies/rerun.py --dry-run` runs nothing and lists one job per record the results page cites (or
    says why a record is kept as it is), each with its expected time from its record; --only picks one,
    and an unknown name is bad usage."""
    sys.path.insert(0, str(REPO / "studies"))
    import rerun
    import results_page

    state = REPO / "reports" / ".rerun-state.json"
    before = state.read_text(encoding="utf-8") if state.exists() else None
    made = {j.record for j in rerun.jobs()}
    for rec in results_page.records():
        sibling = rec.replace("manifest.json", "summary.json")
        covered = rec in made or sibling in made or rec in rerun.KEPT
        # pages of re-run studies: the coverage tables (coverage-<girder>-<case> too) and the family's
        page = rec.endswith(("coverage.json", "family.json"))
        page = page or (rec.startswith("reports/paper/coverage-") and rec.count("/") == 2)
        covered = covered or page
        assert covered, f"no job re-runs {rec}"
    fam = {j.record for j in rerun.jobs() if j.name.startswith("family-")}
    assert {f"reports/paper/family/{s}.json" for s in ("deflection-snr30", "strain-snr30")} <= fam
    r = subprocess.run(
        [sys.executable, "studies/rerun.py", "--dry-run"], capture_output=True, text=True, cwd=REPO
    )
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    jobs = [ln for ln in lines if ": expected " in ln]
    assert len(jobs) == len(rerun.jobs()) and all(" on " in ln for ln in jobs)
    assert any(ln.startswith("coverage-ensemble-snr30: expected ") and "h" in ln for ln in jobs)
    assert (
        "--resume" not in r.stdout
    )  # a re-run starts each study afresh, resumable by its checkpoint
    one = subprocess.run(
        [sys.executable, "studies/rerun.py", "--dry-run", "--only", "table4"],
        capture_output=True, text=True, cwd=REPO,
    )  # fmt: skip
    assert one.returncode == 0 and one.stdout.count(": expected ") == 1
    bad = subprocess.run(
        [sys.executable, "studies/rerun.py", "--dry-run", "--only", "no-such-study"],
        capture_output=True, text=True, cwd=REPO,
    )  # fmt: skip
    assert bad.returncode == 2 and "no-such-study" in bad.stderr and "Traceback" not in bad.stderr
    assert (state.read_text(encoding="utf-8") if state.exists() else None) == before  # no state


def test_rerun_re_runs_the_crossing_entries_after_the_crossings_study():
    """The crossings study starts its study.json afresh, so the joint analyses and the Exeter check (entries
    of that file) are jobs of their own after it, each expected to take its entry's recorded run time; the
    crossings study itself is expected to take the sum of its crossing records' times (its study.json lists
    them by id)."""
    sys.path.insert(0, str(REPO / "studies"))
    import rerun

    jobs = rerun.jobs()
    names = [j.name for j in jobs]
    i = names.index("crossings")
    after = [
        "crossings-joint-g0",
        "crossings-joint-g1",
        "crossings-joint-g2",
        "crossings-exeter-check",
    ]
    assert names[i + 1 : i + 5] == after
    study = json.loads((REPO / jobs[i].record).read_text(encoding="utf-8"))
    for job in jobs[i + 1 : i + 5]:
        assert job.record == jobs[i].record and "--skip-family" in job.command
        seconds, _ = rerun.expected_seconds(job)
        assert seconds == (study.get(job.key) or {}).get("runtime_s")
    total, how = rerun.expected_seconds(jobs[i])
    assert total > 3600 and "replicates" in how  # 30 analysed crossings, minutes each


def test_rerun_says_a_study_just_restarted_has_no_time_yet(tmp_path, monkeypatch):
    """A study file that a running job has started afresh holds no replicate: its expected time is unknown,
    and the dry run says why (not that the study reuses other runs' posteriors, which is Table 5's case)."""
    sys.path.insert(0, str(REPO / "studies"))
    import rerun

    (tmp_path / "study.json").write_text(
        json.dumps({"schema": "x", "records": []}), encoding="utf-8"
    )
    (tmp_path / "table.json").write_text(json.dumps({"schema": "x", "rows": []}), encoding="utf-8")
    monkeypatch.setattr(rerun, "ROOT", tmp_path)
    seconds, how = rerun.expected_seconds(rerun.Job("s", ("true",), "study.json"))
    assert seconds is None and "started it afresh" in how
    seconds, how = rerun.expected_seconds(rerun.Job("t", ("true",), "table.json"))
    assert seconds is None and "reuses other runs" in how
