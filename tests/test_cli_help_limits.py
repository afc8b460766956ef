"""The command line for a new user: the command list (`bayespinn`, `bayespinn help`), inputs outside what
the model and the machine carry refused at once (exit 2, the field and the range named, nothing written),
and a terminal that holds the answer rather than every training step."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import pytest

from bayespinn import limits
from bayespinn.cli import COMMANDS, main
from bayespinn.config import Axle, Vehicle, preset, resolve
from bayespinn.errors import InputError

#: the issue's bound on `bayespinn run --snr 10`'s terminal
MAX_TERMINAL_LINES = 40


def _listed(text: str) -> None:
    for cmd, line in COMMANDS.items():
        assert f"  {cmd}" in text and line in text, cmd


def test_help_lists_every_command_with_one_line(capsys):
    assert main(["help"]) == 0
    out = capsys.readouterr().out
    _listed(out)
    rows = [r for r in out.splitlines() if r.startswith("  ")]
    assert len(rows) == len(COMMANDS)  # one line each


def test_no_command_is_an_error_with_the_same_listing(capsys):
    assert main([]) == 2
    err = capsys.readouterr()
    assert err.out == "" and "a command is required" in err.err
    _listed(err.err)
    assert main(["frobnicate"]) == 2
    err = capsys.readouterr().err
    assert "command: got 'frobnicate'" in err
    _listed(err)


def test_help_of_a_command_and_of_nonsense(capsys):
    assert main(["help", "simulate"]) == 0
    assert "usage: bayespinn simulate" in capsys.readouterr().out
    assert main(["help", "nope"]) == 2
    _listed(capsys.readouterr().err)


def test_the_console_script_alone_prints_the_listing():
    r = subprocess.run(
        [sys.executable, "-m", "bayespinn"], capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 2
    _listed(r.stderr)


@pytest.mark.parametrize(
    ("toml", "field", "expected"),
    [
        ("[data]\nn_points = 100000000\n", "data.n_points", f"[2, {limits.MAX_SAMPLES}]"),
        ("[vehicle]\nspeed = 1e-9\n", "vehicle.speed", "a speed in [0.287, 344] m/s"),
    ],
)
@pytest.mark.parametrize("command", ["simulate", "run"])
def test_absurd_inputs_exit_2_naming_the_field_and_the_range(
    tmp_path, capsys, toml, field, expected, command
):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(toml, encoding="utf-8")
    out = tmp_path / ("out.csv" if command == "simulate" else "run")
    assert main([command, "--snr", "10", "--config", str(cfg), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"bayespinn: error: {field}: got ")
    assert expected in err[0]
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["bad.toml"]


def test_speed_range_follows_the_girder():
    """The speed range is the crossing duration's [T1 / 2, 600 T1] for the girder's first period T1: just
    inside passes, just outside is refused, and a stiffer girder (shorter T1) moves both ends up."""
    cfg = preset("deflection")
    lo, hi = limits.speed_range(cfg.beam, cfg.vehicle)
    T1 = limits.first_period(cfg.beam)
    travel = cfg.beam.length
    assert lo == pytest.approx(travel / (600 * T1)) and hi == pytest.approx(travel / (T1 / 2))
    for v, ok in ((lo * 1.01, True), (hi * 0.99, True), (lo * 0.99, False), (hi * 1.01, False)):
        veh = dataclasses.replace(cfg.vehicle, speed=v)
        if ok:
            dataclasses.replace(cfg, vehicle=veh)
        else:
            with pytest.raises(InputError, match="vehicle.speed"):
                dataclasses.replace(cfg, vehicle=veh)
    stiff = dataclasses.replace(cfg.beam, EI=4 * cfg.beam.EI)
    lo4, hi4 = limits.speed_range(stiff, cfg.vehicle)
    assert lo4 == pytest.approx(2 * lo) and hi4 == pytest.approx(2 * hi)


def test_the_other_ranges(tmp_path):
    cfg = preset("strain")
    T = cfg.duration
    with pytest.raises(InputError, match=r"data.sample_rate.*at least 10 samples per gauge"):
        dataclasses.replace(cfg, data=dataclasses.replace(cfg.data, sample_rate=9.0 / T))
    with pytest.raises(InputError, match=r"data.sample_rate.*one per time step"):
        dataclasses.replace(cfg, data=dataclasses.replace(cfg.data, sample_rate=1.01 * 12000 / T))
    with pytest.raises(InputError, match="beam.section_depth"):
        dataclasses.replace(
            cfg, beam=dataclasses.replace(cfg.beam, section_depth=cfg.beam.length / 4)
        )
    with pytest.raises(InputError, match="beam.EI"):  # 37 kN deflecting a 17 m span by over L / 100
        dataclasses.replace(cfg, beam=dataclasses.replace(cfg.beam, EI=1e7))
    with pytest.raises(InputError, match="beam.mass_per_length"):
        dataclasses.replace(cfg, beam=dataclasses.replace(cfg.beam, mass_per_length=1e5))
    with pytest.raises(InputError, match="beam.damping_ratio"):
        dataclasses.replace(cfg, beam=dataclasses.replace(cfg.beam, damping_ratio=1.0))
    p = (
        tmp_path / "slow.toml"
    )  # a crossing given per [[crossing]] table is checked as its own vehicle
    p.write_text('[[crossing]]\nname = "c0"\nspeed = 1e-3\n', encoding="utf-8")
    try:
        resolve("deflection", p)
    except InputError as e:
        assert "speed" in e.field
    else:  # pragma: no cover - a configuration without [[crossing]] support would pass here
        pytest.fail("a crossing at 1 mm/s was accepted")
    # the limits leave the paper's and the examples' inputs alone, and the Vehicle itself unchecked
    Vehicle(speed=0.01, axles=(Axle(37000.0, 0.0),))


def test_the_sample_budget_matches_what_it_counts():
    """MAX_SAMPLES counts the PINN's per-sample state, which must stay the largest per-sample array (the fit
    check's bootstrap chunk, the predictive draws), and the FE step count: the constants must not drift."""
    from bayespinn.physics.fem import FESettings
    from bayespinn.pinn.settings import TrainSettings
    from bayespinn.uq import fitcheck_stats, posterior

    s = TrainSettings()
    assert (limits.PINN_WIDTH, limits.PINN_DEPTH) == (s.width, s.depth)
    assert limits.ENSEMBLE_MEMBERS == 5  # the --members default
    per_member = limits.BYTES_PER_SAMPLE // limits.ENSEMBLE_MEMBERS
    assert max(fitcheck_stats.CHUNK, posterior.PREDICTIVE_DRAWS) * 8 <= per_member * 5
    assert limits.MAX_SAMPLES * limits.BYTES_PER_SAMPLE <= limits.MEMORY_BUDGET
    assert limits.FE_STEPS == FESettings().n_steps


def _terminal(args: list[str]) -> list[str]:
    """The lines `bayespinn run` leaves on a terminal (stdout and stderr; a progress bar redrawn with
    carriage returns is one line)."""
    r = subprocess.run(
        [sys.executable, "-m", "bayespinn", "run", *args],
        capture_output=True,
        text=True,
        timeout=900,
        env={**__import__("os").environ, "OMP_NUM_THREADS": "1"},
    )
    assert r.returncode == 0, r.stderr[-2000:]
    # a terminal row per newline; what a carriage return redraws stays on its row (splitlines would
    # count every redraw of a bar as a line)
    rows = [row.rsplit("\r", 1)[-1] for row in (r.stderr + r.stdout).rstrip("\n").split("\n")]
    # captured output is no terminal, so tqdm writes each refresh of a bar on a row of its own; a terminal
    # redraws the bar in place: consecutive refreshes of one bar (same label, a '%|' gauge) are one row
    out: list[str] = []
    for row in rows:
        bar = "%|" in row and row.split(":", 1)[0]
        if bar and out and "%|" in out[-1] and out[-1].split(":", 1)[0] == bar:
            out[-1] = row
        else:
            out.append(row)
    return out


def _check_terminal(lines: list[str]) -> None:
    text = "\n".join(lines)
    assert len(lines) <= MAX_TERMINAL_LINES, text
    assert "not drawn" not in text  # nothing about figures the case never draws
    assert ": step " not in text and "PINN fit:" not in text  # per-step lines only with --verbose
    assert "90 % interval" in text and "Fit: The model fits the data" in text
    assert "Agreement:" in text


def test_a_modal_run_prints_the_table_and_the_headline(tmp_path):
    _check_terminal(
        _terminal(
            ["--snr", "10", "--method", "modal", "--profile", "smoke", "--out", str(tmp_path / "r")]
        )
    )


@pytest.mark.slow
def test_a_run_of_every_method_fits_in_40_lines(tmp_path):
    """`bayespinn run --snr 10` with every method (smoke profile): at most 40 lines; --verbose adds the
    per-step lines (the negative control of the count)."""
    lines = _terminal(["--snr", "10", "--profile", "smoke", "--out", str(tmp_path / "r")])
    _check_terminal(lines)
    assert "Deep ensemble and B-PINN agree" in "\n".join(lines) or "disagrees" in "\n".join(lines)
    verbose = _terminal(
        ["--snr", "10", "--profile", "smoke", "--method", "ensemble", "--members", "2", "--verbose",
         "--out", str(tmp_path / "v")]
    )  # fmt: skip
    assert any(": step " in x for x in verbose) and len(verbose) > len(lines) / 2
