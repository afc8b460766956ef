"""Run records and their replays (`bayespinn.records`): an identical rerun by today's code vouches for a
record computed by older code; a difference, another command or older code does not."""

from __future__ import annotations

import copy
import json

import pytest

from bayespinn.errors import InputError
from bayespinn.records import REPLAY, replay_certificate, run_freshness, today_versions

SUMMARY = {
    "schema": "bayespinn.summary/1",
    "methods": {
        "modal_mcmc": {
            "EI": {"mean": 1.03e9, "sd": 1.1e7},
            "sigma": {"mean": 1.5e-4, "sd": 2e-6},
            "diagnostics": {"rhat": 1.001, "ess_bulk": 4000.0},
            "runtime_s": 2.6,
        }
    },
}
COMMAND = [".venv/bin/bayespinn", "run", "--snr", "20", "--method", "modal", "--seed", "11"]


def folder(path, summary, command, versions):
    path.mkdir()
    (path / "summary.json").write_text(json.dumps(summary), encoding="utf-8")
    manifest = {"command": command, "code_versions": versions, "timings_s": {"total_s": 3.0}}
    (path / "manifest.json").write_text(json.dumps(manifest), encoding="utf-8")
    return path


@pytest.fixture
def record(tmp_path):
    return folder(
        tmp_path / "record", SUMMARY, [*COMMAND, "--out", "a"], {"modal_mcmc": "0123456789ab"}
    )


def rerun(tmp_path, summary=SUMMARY, command=COMMAND, versions=None):
    versions = versions or today_versions(["modal_mcmc"])
    return folder(tmp_path / "rerun", summary, ["x", *command[1:], "--out", "b"], versions)


def test_an_identical_rerun_vouches_for_the_record(record, tmp_path):
    assert run_freshness(record)[0] is False
    slow = copy.deepcopy(SUMMARY)
    slow["methods"]["modal_mcmc"]["runtime_s"] = 9.9  # times are not compared
    slow["methods"]["modal_mcmc"]["diagnostics"]["fit_runtime_s"] = 9.9
    cert = replay_certificate(record, rerun(tmp_path, slow))
    assert cert["identical"]
    (record / REPLAY).write_text(json.dumps(cert), encoding="utf-8")
    fresh, how = run_freshness(record)
    assert fresh and how.startswith("replayed")


def test_a_changed_number_is_a_difference(record, tmp_path):
    other = copy.deepcopy(SUMMARY)
    other["methods"]["modal_mcmc"]["EI"]["sd"] *= 1 + 1e-9
    cert = replay_certificate(record, rerun(tmp_path, other))
    assert not cert["identical"] and list(cert["differences"]["modal_mcmc"]) == ["EI"]
    assert not cert["bit_identical"]
    (record / REPLAY).write_text(json.dumps(cert), encoding="utf-8")
    assert run_freshness(record)[0] is False


def test_a_reordered_sum_is_the_same_number_but_not_the_same_bits(record, tmp_path):
    """Another thread count reorders floating-point sums: a last-digit change (1e-15 relative) is within
    `REPLAY_RTOL`, so the replay vouches for the record, and the certificate says it was not bit-identical."""
    other = copy.deepcopy(SUMMARY)
    other["methods"]["modal_mcmc"]["sigma"]["mean"] *= 1 + 1e-15
    cert = replay_certificate(record, rerun(tmp_path, other))
    assert cert["identical"] and not cert["bit_identical"] and not cert["differences"]
    # an error estimate in nats is compared absolutely (`NATS_ATOL`), any other number relatively
    today = today_versions(["modal_mcmc"])

    def with_nats(name, v):
        d = copy.deepcopy(SUMMARY)
        d["methods"]["modal_mcmc"]["diagnostics"]["check_nats"] = v
        return folder(tmp_path / name, d, [*COMMAND, "--out", name], today)

    base = with_nats("r0", 3.9e-4)
    assert replay_certificate(base, with_nats("r1", 3.9e-4 + 2.2e-14))["identical"]
    assert not replay_certificate(base, with_nats("r2", 3.9e-4 + 1e-6))["identical"]


def test_another_command_or_older_code_is_refused(record, tmp_path):
    with pytest.raises(InputError):
        replay_certificate(record, rerun(tmp_path, command=[*COMMAND[:-1], "12"]))
    with pytest.raises(InputError):
        replay_certificate(
            record, folder(tmp_path / "old", SUMMARY, COMMAND, {"modal_mcmc": "0" * 12})
        )
