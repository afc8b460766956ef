"""Every figure the project states is backed by a committed record, and every committed page is current.

- README: each bullet of the "Status" section cites at least one record (a committed JSON under
  reports/), and every number in the bullet is found in the records it cites, at the precision shown
  (as a value, as a percentage of a fraction, or in a recorded command). A negative control plants a
  number that no record holds and expects it to be flagged.
- A bullet that quotes a record computed by code that has changed since (its code versions are not
  today's) must say "stale".
- Study pages: each committed page under reports/paper is exactly what today's code renders from its
  committed JSON (`studies/render.py`). A page whose rows were computed by code that has changed since
  then says so row by row (stale), and this test fails until the page is re-rendered to say it.
"""

from __future__ import annotations

import json
import math
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
RECORD = re.compile(r"reports/[\w./-]+\.json")
#: a number as written in prose: optional sign, digits with optional thousands commas, optional decimals,
#: optional exponent; not part of a word (R-hat's "R", a path, a version such as 3.11)
NUMBER = re.compile(r"(?<![\w.])[-+−]?\d[\d,]*(?:\.\d+)?(?:e[-+]?\d+)?(?![\w])")


def status_bullets(text: str) -> list[str]:
    """The bullets of the README's '## Status' section, continuation lines joined."""
    m = re.search(r"^## Status[^\n]*\n(.*?)(?=^## )", text, re.S | re.M)
    assert m, "README has no '## Status' section"
    bullets, cur = [], None
    for line in m.group(1).splitlines():
        if line.startswith("- "):
            if cur is not None:
                bullets.append(cur)
            cur = line[2:]
        elif cur is not None and line.startswith("  "):
            cur += " " + line.strip()
        elif cur is not None and not line.strip():
            bullets.append(cur)
            cur = None
    if cur is not None:
        bullets.append(cur)
    return bullets


def _numbers_in_json(obj, out: list[float]) -> None:
    if isinstance(obj, dict):
        for v in obj.values():
            _numbers_in_json(v, out)
    elif isinstance(obj, list):
        for v in obj:
            _numbers_in_json(v, out)
    elif isinstance(obj, bool):
        return
    elif isinstance(obj, int | float):
        if math.isfinite(obj):
            out.append(float(obj))
    elif isinstance(obj, str):
        for tok in NUMBER.findall(obj):
            try:
                out.append(float(tok.replace(",", "").replace("−", "-")))
            except ValueError:
                pass


def record_numbers(paths: list[str]) -> list[float]:
    vals: list[float] = []
    for p in paths:
        _numbers_in_json(json.loads((ROOT / p).read_text(encoding="utf-8")), vals)
    return vals


def _decimals(tok: str) -> int:
    mant = tok.split("e")[0]
    return len(mant.split(".")[1]) if "." in mant else 0


def backed(tok: str, values: list[float]) -> bool:
    """Is the number `tok` (as written) one of `values` shown at its precision (or as a percentage)?"""
    x = float(tok.replace(",", "").replace("−", "-"))
    if "e" in tok:  # scientific: 3 significant digits agree
        return any(
            v != 0 and abs(v - x) <= 0.5 * 10 ** (math.floor(math.log10(abs(x))) - _decimals(tok))
            for v in values
        )
    d = _decimals(tok)
    half = 0.5 * 10**-d + 1e-12
    for v in values:
        for cand in (v, 100 * v):
            if abs(cand - x) <= half or abs(abs(cand) - abs(x)) <= half:
                return True
    return False


def unbacked(bullet: str) -> list[str]:
    """The numbers of a status bullet that no record it cites holds (all of them when it cites none)."""
    paths = RECORD.findall(bullet)
    missing = [p for p in paths if not (ROOT / p).is_file()]
    assert not missing, f"records cited but not committed: {missing}"
    text = RECORD.sub(" ", bullet)
    text = re.sub(r"\]\([^)]*\)", "]", text)  # link targets
    vals = record_numbers(paths)
    return [tok for tok in NUMBER.findall(text) if not backed(tok, vals)]


def record_is_fresh(path: str) -> bool | None:
    """Was the record computed by today's code? None for records that carry no code version (table JSON)."""
    from bayespinn.records import run_freshness
    from bayespinn.uq.coverage import study_freshness

    p = ROOT / path
    doc = json.loads(p.read_text(encoding="utf-8"))
    if doc.get("schema") == "bayespinn.coverage/1":
        return study_freshness(p)[0]
    if p.name in ("summary.json", "manifest.json"):
        return run_freshness(p.parent)[0]
    return study_records_fresh(doc)


def study_records_fresh(doc: dict) -> bool | None:
    """A study file whose records each carry the code versions of the methods that computed them (the
    family of bridges): fresh when every record's are today's. None for files that carry none."""
    from bayespinn.records import today_versions

    recs = doc.get("records")
    if not isinstance(recs, list) or not recs:
        return None
    if not all(isinstance(r, dict) and isinstance(r.get("code_versions"), dict) for r in recs):
        return None
    return all(r["code_versions"] == today_versions(r["code_versions"]) for r in recs)


def test_every_status_number_names_a_record():
    bullets = status_bullets(README.read_text(encoding="utf-8"))
    assert len(bullets) >= 3
    problems = {}
    for b in bullets:
        if not RECORD.search(b):
            problems[b[:60]] = "cites no record"
            continue
        bad = unbacked(b)
        if bad:
            problems[b[:60]] = f"numbers without a record: {bad}"
        stale = [p for p in RECORD.findall(b) if record_is_fresh(p) is False]
        unsaid = unflagged(b, stale)
        if unsaid:
            problems[b[:60]] = (
                f"quotes records computed by code that has changed since, without saying so: {unsaid}"
            )
    assert not problems, json.dumps(problems, indent=1)


def sentences(bullet: str) -> list[str]:
    """A bullet cut into sentences: at a full stop followed by a space and a capital, a quote or a bracket
    (a record's path, a version or a decimal has no space after its dots)."""
    return re.split(r"(?<=\.)\s+(?=[A-Z*(`])", bullet)


def unflagged(bullet: str, stale: list[str]) -> list[str]:
    """The stale records of `stale` that the bullet cites without saying "stale" in the sentence that cites
    them or the one before it: a bullet that calls one figure stale does not excuse the others."""
    ss = sentences(bullet)
    out = []
    for path in stale:
        for i, s in enumerate(ss):
            if path in s and not any("stale" in t.lower() for t in ss[max(i - 1, 0) : i + 1]):
                out.append(path)
                break
    return out


def test_a_stale_record_must_be_called_stale_where_it_is_cited():
    """Negative control: "stale" elsewhere in a bullet does not cover a record cited two sentences on."""
    b = (
        "The old run is stale (record: `reports/a.json`). Another sentence. "
        "The new run took 3 s (record: `reports/b.json`)."
    )
    assert unflagged(b, ["reports/a.json"]) == []
    assert unflagged(b, ["reports/b.json"]) == ["reports/b.json"]
    assert unflagged(b.replace("Another sentence. ", ""), ["reports/b.json"]) == []


def test_a_study_with_one_record_of_other_code_is_stale():
    """Negative control: a family study whose records are today's code is fresh; one record computed by
    another version of one method makes the whole file stale."""
    from bayespinn.records import today_versions

    today = today_versions(["modal_mcmc", "bpinn"])
    doc = {"records": [{"code_versions": dict(today)}, {"code_versions": dict(today)}]}
    assert study_records_fresh(doc) is True
    doc["records"][1]["code_versions"]["bpinn"] = "0" * 12
    assert study_records_fresh(doc) is False
    assert study_records_fresh({"records": [{"code_version": "abc"}]}) is None


def test_a_number_without_a_record_is_caught():
    """Negative control: the checker flags a planted number, and a bullet citing no record."""
    bullets = [b for b in status_bullets(README.read_text(encoding="utf-8")) if RECORD.search(b)]
    planted = bullets[0] + " It also took 987.654 s."
    assert "987.654" in unbacked(planted)
    assert not RECORD.search("The ensemble is 1.23x wider.")


def test_backed_reads_precision_and_percentages():
    assert backed("0.90", [0.9025]) and backed("90.2", [0.9025]) and backed("361", [361.0])
    assert backed("-0.42", [-0.4213]) and backed("1.03e9", [1.0336e9])
    assert not backed("0.91", [0.9025]) and not backed("362", [361.0])


# ------------------------------------------------------------------------------------------ pages
PAGES = ("coverage", "table4", "table5", "table6", "family", "girders", "girder_pinns", "fitcheck")


@pytest.fixture(scope="module")
def render():
    sys.path.insert(0, str(ROOT / "studies"))  # the study scripts import each other by name
    import render as r

    return r


@pytest.mark.parametrize("page", PAGES)
def test_committed_pages_are_what_todays_code_renders(page, render):
    out = ROOT / "reports" / "paper"
    text = render.page_text(page, out)
    if text is None:
        pytest.skip(f"no {page}.json committed")
    committed = (out / f"{page}.md").read_text(encoding="utf-8")
    assert committed == text, (
        f"reports/paper/{page}.md is not what today's code renders from {page}.json (its rows' freshness or "
        "layout changed): run `python studies/render.py --out reports/paper` and commit the pages"
    )
