"""Configuration, synthetic data, the measurement CSV and the command line's handling of bad input."""

import json
import subprocess
import sys

import numpy as np
import pytest

from bayespinn.config import EXETER_EI, parse_snr, preset, resolve
from bayespinn.data.measurements import read_csv
from bayespinn.data.synthetic import realised_snr, simulate
from bayespinn.errors import InputError
from bayespinn.physics.modal import ModalModel

#: simulate's truth (converged FE) vs closed form, contract/issue targets
DEFLECTION_TRUTH_TOL, STRAIN_TRUTH_TOL = 1e-3, 1e-2


def _cli(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "bayespinn", *args], capture_output=True, text=True, cwd=cwd
    )


def _rel_rms(a, b):
    return float(np.sqrt(np.mean((a - b) ** 2)) / np.sqrt(np.mean(b**2)))


def test_exeter_preset():
    cfg = preset()
    assert cfg.beam.EI == pytest.approx(1.03361e9, rel=1e-5) and EXETER_EI == cfg.beam.EI
    assert cfg.duration == pytest.approx(17.28 / 7.115)
    truck = preset("strain").vehicle
    assert truck.loads.sum() == pytest.approx(0.55 * (2 * 67.2e3 + 2 * 89.8e3))
    assert preset("strain").duration == pytest.approx((17.28 + 6.5) / 7.115)


def test_toml_overrides(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text(
        "[beam]\nlength = 20.0\nEI = 2e9\n[vehicle]\nspeed = 10.0\naxles = [{load = 5e4, offset = 0.0}, {load = 6e4, offset = 3.0}]\n[data]\nn_points = 50\n"
    )
    cfg = resolve("deflection", f)
    assert (cfg.beam.length, cfg.beam.EI, cfg.vehicle.speed, cfg.data.n_points) == (
        20.0,
        2e9,
        10.0,
        50,
    )
    assert cfg.vehicle.offsets.tolist() == [0.0, 3.0]
    assert cfg.beam.mass_per_length == 289.0  # untouched preset value


@pytest.mark.parametrize(
    "text,field",
    [
        ("[beam]\nlength = -3.0\n", "beam.length"),
        ("[beam]\nEI = 'stiff'\n", "beam.EI"),
        ("[beam\nlength = 3\n", "--config"),
        ("[vehicle]\naxles = [{load = -1.0, offset = 0.0}]\n", "vehicle.axles[0].load"),
        ("[beam]\nlenght = 3.0\n", "beam.lenght"),
    ],
)
def test_bad_toml_names_the_field(tmp_path, text, field):
    f = tmp_path / "bad.toml"
    f.write_text(text)
    with pytest.raises(InputError) as e:
        resolve("deflection", f)
    assert e.value.field == field


@pytest.mark.parametrize("s", ["nan", "inf", "abc", "-5", "0"])
def test_bad_snr(s):
    with pytest.raises(InputError):
        parse_snr(s)


def test_simulate_clean_matches_closed_form(exeter):
    d = simulate(exeter, None, 3)
    assert len(d) == 100 and np.array_equal(d.value, d.value_true)
    ref = ModalModel(exeter.beam, exeter.vehicle, d.x, d.t, n_modes=40).predict(exeter.beam.EI)
    assert _rel_rms(d.value, ref) < DEFLECTION_TRUTH_TOL


def test_simulate_strain_matches_closed_form(exeter_strain):
    d = simulate(exeter_strain, None, 0)
    assert set(d.sensor) == {"S1", "S2", "S3", "S4"}
    ref = ModalModel(
        exeter_strain.beam, exeter_strain.vehicle, d.x, d.t, *d.weights, n_modes=40
    ).predict(exeter_strain.beam.EI)
    assert _rel_rms(d.value, ref) < STRAIN_TRUTH_TOL
    # bottom flange in tension under a load near midspan
    s4 = (d.sensor == "S4") & (np.abs(d.t - 0.5 * exeter_strain.duration) < 0.1)
    assert np.all(d.value[s4] > 0)


def test_realised_snr_and_seed(exeter):
    a, b = simulate(exeter, 20.0, 4), simulate(exeter, 20.0, 4)
    np.testing.assert_array_equal(a.value, b.value)
    assert abs(realised_snr(a.value, a.value_true) - 20.0) < 1.5
    c = simulate(exeter, 20.0, 5)
    assert not np.array_equal(a.value, c.value)


def test_csv_round_trip(tmp_path, exeter_strain):
    d = simulate(exeter_strain, 30.0, 1)
    d.to_csv(tmp_path / "s.csv")
    r = read_csv(tmp_path / "s.csv", exeter_strain.beam.length)
    for f in ("x", "t", "value", "y", "value_true"):
        np.testing.assert_array_equal(getattr(r, f), getattr(d, f))
    assert list(r.sensor) == list(d.sensor) and list(r.kind) == list(d.kind)


GOOD = "x,t,value,kind\n1.0,0.5,0.001,deflection\n"


@pytest.mark.parametrize(
    "content,where",
    [
        ("x,t,value,kind\n1.0,0.5,nan,deflection\n", "row 2, column value"),
        ("x,t,value,kind\n99.0,0.5,0.001,deflection\n", "row 2, column x"),
        ("x,t,value,kind\n1.0,-0.5,0.001,deflection\n", "row 2, column t"),
        ("x,t,kind\n1.0,0.5,deflection\n", "header"),
        ("", "--data"),
        ("x,t,value,kind\n1.0,0.5,abc,deflection\n", "row 2, column value"),
        ("x,t,value,kind\n1.0,0.5,0.001,tilt\n", "row 2, column kind"),
        ("x,t,value,kind,y\n1.0,0.5,1e-5,strain,\n", "row 2, column y"),
        ("x,t,value,kind\n1.0,0.5,inf,deflection\n", "row 2, column value"),
    ],
)
def test_bad_csv(tmp_path, content, where):
    f = tmp_path / "m.csv"
    f.write_text(content)
    with pytest.raises(InputError) as e:
        read_csv(f, 17.28)
    assert where in e.value.field


def test_binary_csv(tmp_path):
    f = tmp_path / "m.csv"
    f.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(InputError):
        read_csv(f, 17.28)


def test_cli_simulate_and_bad_input(tmp_path):
    r = _cli(
        "simulate",
        "--case",
        "deflection",
        "--snr",
        "clean",
        "--seed",
        "3",
        "--out",
        str(tmp_path / "a.csv"),
    )
    assert r.returncode == 0, r.stderr
    assert len((tmp_path / "a.csv").read_text().splitlines()) == 101
    bad_toml = tmp_path / "bad.toml"
    bad_toml.write_text("[beam]\nlength = -1\n")
    for args in (
        ["--snr", "nan"],
        ["--snr", "inf"],
        ["--snr", "abc"],
        ["--snr=-5"],
        ["--snr", "10", "--config", str(bad_toml)],
        ["--snr", "10", "--case", "tilt"],
        ["--snr", "10", "--device", "tpu"],
        ["--snr", "10", "--bpinn-variant", "fulll"],
    ):
        out = tmp_path / "b.csv"
        r = _cli("simulate", *args, "--out", str(out))
        assert r.returncode == 2, (args, r.stderr)
        assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
        assert not out.exists()


def test_cli_run_bad_data_leaves_nothing(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("x,t,value,kind\n1.0,0.5,nan,deflection\n")
    out = tmp_path / "run"
    r = _cli("run", "--data", str(bad), "--method", "modal", "--out", str(out))
    assert r.returncode == 2 and "column value" in r.stderr and "Traceback" not in r.stderr
    assert not (out / "summary.json").exists()


def test_cuda_without_gpu_is_bad_input(tmp_path):
    import torch

    if torch.cuda.is_available():
        pytest.skip("a GPU is present")
    out = tmp_path / "run"
    r = _cli("run", "--snr", "10", "--method", "modal", "--device", "cuda", "--out", str(out))
    assert r.returncode == 2 and "--device" in r.stderr and "cuda" in r.stderr.lower()
    assert not out.exists()


def test_simulate_offers_only_the_flags_it_uses():
    """simulate makes data: its help lists no flag that chooses how a method runs, and such a flag is
    refused as unknown (exit 2), while run still offers them."""
    sim = _cli("simulate", "--help").stdout
    for flag in ("--members", "--bpinn-variant", "--profile", "--device", "--workers", "--method"):
        assert flag not in sim
    assert "--seed" in sim and "--config" in sim
    assert "--members" in _cli("run", "--help").stdout
    r = _cli("simulate", "--snr", "10", "--members", "3")
    assert r.returncode == 2 and "--members" in r.stderr


def test_cli_coverage_resumes_from_its_file(tmp_path):
    """`coverage --resume` reuses the replicates of the --out file of the same study and runs the rest;
    without --resume the study starts afresh."""
    out = tmp_path / "cov.json"
    args = (
        "coverage",
        "--method",
        "modal",
        "--snr",
        "30",
        "--profile",
        "smoke",
        "--out",
        str(out),
        "--quiet",
    )
    assert _cli(*args, "--replicates", "1").returncode == 0
    first = json.loads(out.read_text(encoding="utf-8"))
    r = _cli(*args, "--replicates", "2", "--resume")
    assert r.returncode == 0, r.stderr
    res = json.loads(out.read_text(encoding="utf-8"))
    assert res["resumed_replicates"] == 1 and res["records"][0] == first["records"][0]
    assert res["fingerprint"] == first["fingerprint"] and len(res["records"]) == 2
    assert _cli(*args, "--replicates", "2").returncode == 0
    assert json.loads(out.read_text(encoding="utf-8"))["resumed_replicates"] == 0


def test_cli_coverage_resume_keeps_replicates_of_another_commit(tmp_path):
    """A resume reuses the replicates of the same study whatever commit computed them (each record names
    its own), goes on from the checkpoint an interrupted run left, and consumes it."""
    out = tmp_path / "cov.json"
    args = ("coverage", "--method", "modal", "--snr", "30", "--profile", "smoke")
    args += ("--out", str(out), "--quiet")
    assert _cli(*args, "--replicates", "1").returncode == 0
    doc = json.loads(out.read_text(encoding="utf-8"))
    doc["records"][0].update(git_commit="0123456789abcdef", git_dirty=False)  # an older commit's
    out.write_text(json.dumps(doc), encoding="utf-8")
    partial = out.with_name(out.name + ".partial.jsonl")
    r = _cli(*args, "--replicates", "2", "--resume")
    assert r.returncode == 0, r.stderr
    res = json.loads(out.read_text(encoding="utf-8"))
    assert res["records"][0] == doc["records"][0] and res["resumed_replicates"] == 1
    assert res["commits"]["0123456789ab"] == 1 and sum(res["commits"].values()) == 2
    assert not partial.exists()


@pytest.mark.parametrize(
    "argv, field",
    [
        (["coverage", "--method", "ensemble", "--snr", "30", "--replicates", "0"], "--replicates"),
        (["run", "--snr", "10", "--seed", "-1"], "--seed"),
        (["run", "--snr", "10", "--members", "two"], "--members"),
        (["coverage", "--method", "modal", "--snr", "30", "--level", "1.5"], "--level"),
    ],
)
def test_a_bad_flag_value_names_its_flag(argv, field):
    """A flag whose value its type refuses is reported as that flag, its value and what was expected,
    not as argparse's "invalid conv value"."""
    from bayespinn.cli import build_parser

    with pytest.raises(InputError) as err:
        build_parser().parse_args(argv)
    assert err.value.field == field and "invalid" not in str(err.value)
    assert str(err.value).startswith(f"{field}: got '{argv[-1]}', expected ")


@pytest.mark.parametrize(
    "command",
    [
        ["run", "--snr", "10", "--method", "modal"],
        ["sweep", "--snr", "10,20", "--method", "modal"],
        ["coverage", "--method", "modal", "--snr", "10", "--replicates", "2"],
        ["simulate", "--snr", "10"],
        ["bench"],
    ],
)
def test_an_out_that_cannot_be_written_is_refused_before_any_work(tmp_path, command, capsys):
    """--out below a file (so never creatable) is bad input, found before the command computes anything:
    exit 2, one line naming --out and the path, and nothing written."""
    from bayespinn.cli import main

    blocker = tmp_path / "a-file"
    blocker.write_text("x")
    out = blocker / "sub" / ("result" if command[0] in ("run", "sweep") else "result.json")
    assert main([*command, "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert (
        len(err) == 1
        and err[0].startswith("bayespinn: error: --out: got '/")
        and "a-file" in err[0]
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-file"] and blocker.read_text() == "x"


def test_an_out_of_the_wrong_kind_is_refused(tmp_path):
    from bayespinn.commands import writable_out

    (tmp_path / "folder").mkdir()
    (tmp_path / "file.json").write_text("{}")
    with pytest.raises(InputError, match="not an existing folder"):
        writable_out(tmp_path / "folder", folder=False)
    with pytest.raises(InputError, match="not an existing file"):
        writable_out(tmp_path / "file.json", folder=True)
    assert writable_out(tmp_path / "new" / "deeper", folder=True) == tmp_path / "new" / "deeper"
    assert not (tmp_path / "new").exists()  # checking creates nothing
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file.json", "folder"]
