"""The realistic-crossings study's machinery at a smoke-sized setting: one girder, one crossing (a tiny
simulator and a short MCMC), the record's keys, the draws a function of the seed within the stated
tolerances, and a negative control: a speed stated 3 % off with nothing declared is counted by the
summary as a miss or a misfit."""

from __future__ import annotations

import dataclasses
import json

import pytest

STUDY_SCRIPT = "crossings"  # the `study` fixture (conftest.py) imports it

pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")


def test_draws_are_seeded_and_within_the_stated_tolerances(study):
    a, b = study.draw(50, 1, 3), study.draw(50, 1, 3)
    assert a == b and a != study.draw(51, 1, 3)
    for k in range(20):
        d = study.draw(7, 0, k)
        assert abs(d["stated_speed"] / d["speed"] - 1) <= study.SPEED_TOL
        assert abs(d["stated_entry_time"] - d["entry_time"]) <= study.ENTRY_TOL
        assert d["road"] == ("A", "B")[k % 2]
        assert 0.005 <= d["damping_ratio"] <= 0.02 and 1.5 <= d["body_frequency"] <= 3.5
    # the family's girders differ from the Exeter preset
    spans = {study.girder(g, 50).beam.length for g in range(3)}
    assert len(spans) == 3


def test_one_crossing_record_and_page(study, tmp_path):
    argv = ["--girders", "1", "--crossings", "1", "--smoke", "--forces", "constant"]
    argv += ["--out", str(tmp_path)]
    assert study.main(argv) == 0
    rec = json.loads((tmp_path / "crossings" / "g0-c0.json").read_text())
    for name in ("declared", "today"):
        e = rec[name]
        assert {"EI", "hit", "z", "fit_check", "runtime_s", "converged"} <= set(e)
        assert {"mean", "sd", "ci90"} <= set(e["EI"])
        assert e["fit_check"]["verdict"] in ("fits", "misfit")
    assert {"speed", "entry_time", "damping_ratio"} <= set(rec["declared"])
    assert "speed" not in rec["today"]
    assert {"command", "seed", "git_commit", "versions", "machine", "date"} <= set(
        rec["provenance"]
    )
    doc = json.loads((tmp_path / "crossings" / "study.json").read_text())
    assert doc["summary"]["done"] == 1 and not doc["summary"]["partial"]
    assert (tmp_path / "crossings.md").read_text().startswith("# Realistic crossings")


def test_speed_stated_three_percent_off_is_a_miss_or_misfit(study):
    """Negative control: constant forces on a smooth road (nothing the analysis model lacks) but the
    stated speed 3 % high and taken as exact: the summary must count a miss or a misfit."""
    args = study.build_parser().parse_args(["--smoke"])
    g = study.girder_for(args, 0)
    d = study.draw(args.seed, 0, 0)
    d = {**d, "stated_speed": 1.03 * d["speed"], "stated_entry_time": d["entry_time"]}
    truth = study.truth_config(g, d)
    truth = dataclasses.replace(
        truth,
        vehicle=dataclasses.replace(truth.vehicle, model="forces"),
        road=study.Road(roughness=0.0),
    )
    data = study.simulate(truth, 30.0, d["data_seed"], True)
    e = study.analyse(data, study.stated_config(g, d, False, "constant"), g.beam.EI, 30.0, 0, True)
    s = study.summarise([{"today": e}], "today")
    assert s["hits"] == 0 or s["misfit"] == 1
    assert abs(e["z"]) > 4


def _record(ei_z: float, speed_z: float, entry_z: float, fb_z: float | None = None) -> dict:
    truth = {"speed": 10.0, "entry_time": 0.5, "body_frequency": 2.5}
    post = lambda k, z: {"mean": truth[k] + 0.1 * z, "sd": 0.1, "ci90": [0, 0]}  # noqa: E731
    dec = {"z": ei_z, "speed": post("speed", speed_z), "entry_time": post("entry_time", entry_z)}
    if fb_z is not None:
        dec["body_frequency"] = post("body_frequency", fb_z)
    return {"truth_and_stated": truth, "declared": dec}


def test_nuisance_summary_separates_misses_that_follow_the_speed(study):
    """EI's rms z is split by whether the speed's posterior holds its truth, with the correlation: four
    crossings whose EI misses go with the speed's, against the same EI z's paired with calm speeds."""
    recs = [_record(3.0, -4.0, -5.0, 1.0), _record(-3.0, 5.0, 4.0), _record(0.5, -0.5, 0.0, 1.0),
            _record(-1.0, 1.0, 1.0, 3.0)]  # fmt: skip
    nu = study.nuisances(recs)
    assert nu["n"] == 4 and nu["speed_within"] == 2
    assert nu["EI_rms_z_speed_beyond"] == pytest.approx(3.0)
    assert nu["EI_rms_z_speed_within"] == pytest.approx((0.5**2 / 2 + 1 / 2) ** 0.5)
    assert nu["rms_z"]["body_frequency"] == pytest.approx(
        (11 / 3) ** 0.5
    )  # the record lacking it skipped
    assert nu["corr_EI_speed"] < -0.9
    # negative control: the same EI z's beside speeds that hold their truth are not attributed to them
    calm = study.nuisances(
        [
            _record(r["declared"]["z"], s, 0.0)
            for r, s in zip(recs, (0.3, 0.3, -0.3, -0.3), strict=True)
        ]
    )
    assert calm["speed_within"] == 4 and calm["EI_rms_z_speed_beyond"] is None
    assert abs(calm["corr_EI_speed"]) < 0.3


def test_reverse_runs_the_crossings_last_first_and_resume_skips_done_ones(
    study, tmp_path, monkeypatch
):
    """Two processes share a study, one each way: `--reverse` runs the last crossing first, and with
    `--resume` a crossing whose record exists is not run again (the negative control: without `--resume`
    every crossing runs)."""
    ran = []

    def fake(args, argv, g, k):
        ran.append((g, k))
        return {
            "schema": study.RECORD_SCHEMA,
            "fingerprint": study.fingerprint(args),
            "g": g,
            "k": k,
        }

    monkeypatch.setattr(study, "run_crossing", fake)
    monkeypatch.setattr(study, "write_study", lambda *a, **k: {})
    argv = ["--girders", "2", "--crossings", "3", "--only-girder", "1", "--out", str(tmp_path)]
    study.run_study(study.build_parser().parse_args([*argv, "--reverse"]), argv)
    assert ran == [(1, 2), (1, 1), (1, 0)]
    (tmp_path / "crossings" / "g1-c1.json").unlink()
    ran.clear()
    study.run_study(study.build_parser().parse_args([*argv, "--resume"]), argv)
    assert ran == [(1, 1)]
    ran.clear()
    study.run_study(study.build_parser().parse_args(argv), argv)
    assert ran == [(1, 0), (1, 1), (1, 2)]
