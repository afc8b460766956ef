"""summary.json and manifest.json follow the JSON Schemas shipped in the package (bayespinn/schemas/)."""

from __future__ import annotations

import copy
import json
from importlib import resources

import jsonschema
import pytest

from bayespinn.config import preset
from bayespinn.options import RunOptions
from bayespinn.pipeline import run


def schema(name: str) -> dict:
    return json.loads(
        resources.files("bayespinn").joinpath(f"schemas/{name}.schema.json").read_text("utf-8")
    )


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A modal-only smoke run (seconds), written as a user's run is."""
    out = tmp_path_factory.mktemp("schemas") / "run"
    run(
        preset(),
        methods=["modal"],
        snr_db=20.0,
        seed=0,
        out=out,
        opts=RunOptions(profile="smoke"),
        argv=["test"],
        write_report=False,
    )
    return out


@pytest.mark.parametrize("name", ["summary", "manifest"])
def test_produced_files_follow_their_schema(folder, name):
    s = schema(name)
    jsonschema.Draft202012Validator.check_schema(s)
    doc = json.loads((folder / f"{name}.json").read_text(encoding="utf-8"))
    jsonschema.validate(doc, s, cls=jsonschema.Draft202012Validator)


@pytest.mark.parametrize("name", ["summary", "manifest"])
def test_committed_records_follow_their_schema(name):
    """Every committed run record (reports/records, reports/paper run folders) of today's schema."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1] / "reports"
    s = schema(name)
    for p in sorted(root.rglob(f"{name}.json")):
        doc = json.loads(p.read_text(encoding="utf-8"))
        man = json.loads((p.parent / "manifest.json").read_text(encoding="utf-8"))
        if "code_versions" not in man and "date" not in man:
            continue  # written before the schemas existed
        jsonschema.validate(doc, s, cls=jsonschema.Draft202012Validator)


def test_schema_rejects_a_broken_summary(folder):
    """Negative control: a summary without its EI interval, or with an unknown case, fails validation."""
    s = schema("summary")
    doc = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
    broken = copy.deepcopy(doc)
    del broken["methods"]["modal_mcmc"]["EI"]["ci90"]
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(broken, s)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({**doc, "case": "torsion"}, s)
