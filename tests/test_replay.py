"""Replays: today's code re-runs replicates of a study computed by older code; an identical replay vouches
for the study (a refactor), any difference leaves it stale."""

from __future__ import annotations

import copy
import json
from dataclasses import replace

import pytest

from bayespinn.config import preset
from bayespinn.errors import InputError
from bayespinn.executor import Executor
from bayespinn.options import RunOptions
from bayespinn.uq.coverage import coverage_study, replay, replay_path, study_freshness
from bayespinn.uq.sampler import MCMCSettings

OPTS = RunOptions(profile="smoke", mcmc=MCMCSettings(n_walkers=16, n_groups=2, min_steps=250))
ONE = Executor("local", workers=1)


@pytest.fixture(scope="module")
def study():
    return coverage_study(
        "modal", preset(), 20.0, replicates=2, seed=5, opts=OPTS, executor=ONE, progress=False
    )


def test_replay_reproduces_a_study(study):
    cert = replay(study, "modal", preset(), indices=[0, 1], opts=OPTS, executor=ONE)
    assert cert["identical"] and cert["differences"] == {} and cert["indices"] == [0, 1]
    assert cert["code_version"] == study["code_version"]


def test_replay_finds_a_changed_record(study):
    """Negative control: a record one ulp-ish away from what the code computes is caught."""
    bad = copy.deepcopy(study)
    bad["records"][1]["rank"] += 1e-9
    cert = replay(bad, "modal", preset(), indices=[1], opts=OPTS, executor=ONE)
    assert not cert["identical"] and list(cert["differences"]["1"]) == ["rank"]


def test_replay_refuses_other_settings(study):
    with pytest.raises(InputError):
        replay(
            study,
            "modal",
            preset(),
            indices=[0],
            opts=replace(OPTS, noise_prior="snr"),
            executor=ONE,
        )
    with pytest.raises(InputError):
        replay(study, "modal", preset(), indices=[7], opts=OPTS, executor=ONE)


def test_an_identical_replay_vouches_for_older_code(study, tmp_path):
    old = copy.deepcopy(study)
    old["code_version"] = "0123456789ab"
    old["code_versions"] = {"0123456789ab": 2}
    path = tmp_path / "modal_mcmc-snr20.json"
    path.write_text(json.dumps(old), encoding="utf-8")
    assert study_freshness(path)[0] is False  # older code, nothing vouches for it
    cert = replay(old, "modal", preset(), indices=[1], opts=OPTS, executor=ONE)
    replay_path(path).write_text(json.dumps(cert), encoding="utf-8")
    fresh, how = study_freshness(path)
    assert fresh and how.startswith("replayed")
    # a certificate that found a difference vouches for nothing
    replay_path(path).write_text(json.dumps({**cert, "identical": False}), encoding="utf-8")
    assert study_freshness(path)[0] is False
    # nor one for another study's code
    replay_path(path).write_text(
        json.dumps({**cert, "study_code_versions": {"ffffffffffff": 2}}), encoding="utf-8"
    )
    assert study_freshness(path)[0] is False
