"""Every figure the project states is one named field of one committed record, and every page is current.

- docs/results.md is what `studies/results_page.py` generates from the committed records: each row names
  a record and a key path into it, prints that field at the spec's precision, and shows the provenance
  (commit, date, machine) of the run that computed it. Negative controls: a value changed in its last
  printed digit, and an entry pointed at a nearby field of similar magnitude, must both be caught.
- The README quotes no measured figures: it links to docs/results.md.
- Study pages: each committed page under reports/paper is exactly what today's code renders from its
  committed JSON (`studies/render.py`).
"""

from __future__ import annotations

import dataclasses
import re
import subprocess
import sys
from pathlib import Path

import pytest

from bayespinn import records

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "studies"))  # the study scripts import each other by name

import results_page as rp  # noqa: E402


def _full_history() -> bool:
    """Dates of older records come from git (their commit's date): a full clone is needed to regenerate."""
    try:
        r = subprocess.run(
            ["git", "-C", str(ROOT), "rev-parse", "--is-shallow-repository"],
            capture_output=True,
            text=True,
            timeout=10,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return False
    return r.returncode == 0 and r.stdout.strip() == "false"


needs_git = pytest.mark.skipif(not _full_history(), reason="needs a full git clone (record dates)")


@pytest.fixture(scope="module")
def page() -> str:
    return rp.PAGE.read_text(encoding="utf-8")


@pytest.fixture(scope="module")
def generated() -> str:
    return rp.render()


# ------------------------------------------------------------------------------------ results page
@needs_git
def test_the_results_page_is_generated_from_the_records(page, generated):
    assert page == generated, (
        "docs/results.md is not what the records give: run `python studies/results_page.py` and commit it"
    )
    assert rp.problems(page) == []


def test_the_page_covers_every_kind_of_study(page):
    cited = set(rp.records())
    for must in (
        "reports/paper/coverage.json",
        "reports/paper/family.json",
        "reports/paper/table4.json",
        "reports/paper/table5.json",
        "reports/paper/table6.json",
        "reports/paper/girder_pinns/damaged-girder-deflection-snr30.json",
        "reports/records/exeter-snr10-seed0/summary.json",
    ):
        assert must in cited, must
    for prefix in ("reports/paper/coverage/", "reports/paper/girders/", "reports/paper/fitcheck/"):
        assert any(r.startswith(prefix) for r in cited), prefix
    figures = [e.figure for e in rp.entries()]
    assert len(set(figures)) == len(figures), "two figures of one name"
    assert len(rp.table_rows(page)) == len(figures) > 300


def _one_row(page: str, figure: str) -> str:
    (line,) = [ln for ln in page.splitlines() if ln.startswith(f"| {figure} |")]
    return line


def _bump_last_digit(value: str) -> str:
    """The value with its last printed digit (of the mantissa, for 1.0336e+09) moved by one."""
    mant = value.split("e")[0]
    i = max(i for i, ch in enumerate(mant) if ch.isdigit())
    return value[:i] + str((int(value[i]) + 1) % 10) + value[i + 1 :]


@pytest.mark.parametrize(
    "figure",
    [
        "deep ensemble, 30 dB: 90 % intervals holding the truth",  # an integer
        "deflection, 30 dB, B-PINN: mean z",  # signed, two decimals
        "Table 4, modal reference, 10 dB: EI mean [N m^2]",  # five significant digits
    ],
)
def test_a_value_changed_in_its_last_digit_is_caught(page, figure):
    """Negative control: the page with one value's last printed digit changed."""
    line = _one_row(page, figure)
    cells = line.split(" | ")
    cells[1] = _bump_last_digit(cells[1])
    forged = page.replace(line, " | ".join(cells))
    assert forged != page
    found = rp.problems(forged)
    assert len(found) == 1 and found[0].startswith(f"{figure}: shows")


def _pointed_elsewhere(figure: str, key: str) -> list:
    secs = []
    for s in rp.sections():
        es = tuple(dataclasses.replace(e, key=key) if e.figure == figure else e for e in s.entries)
        secs.append(dataclasses.replace(s, entries=es))
    assert any(e.key == key for s in secs for e in s.entries)
    return secs


@pytest.mark.parametrize(
    "figure, nearby",
    [
        # the ensemble's hits (92) against the reference's on the same datasets (91), a field beside it
        (
            "deep ensemble, 10 dB: 90 % intervals holding the truth",
            "rows[method=ensemble,snr_db=10].paired_reference.reference_hits",
        ),
        # equal values (94 and 94): the key path alone tells them apart
        (
            "deep ensemble, 30 dB: 90 % intervals holding the truth",
            "rows[method=ensemble,snr_db=30].paired_reference.reference_hits",
        ),
        # the family's mean z (-0.02) against the mean z of the bridges with alpha >= 0.04 (-0.04)
        (
            "deflection, 30 dB, deep ensemble: mean z",
            'studies.deflection-snr30.criteria.ensemble.by_alpha."alpha>=0.04".mean_z',
        ),
    ],
)
def test_an_entry_pointed_at_a_nearby_field_is_caught(page, figure, nearby):
    """Negative control: the spec's entry pointed at a neighbouring field of similar magnitude."""
    secs = _pointed_elsewhere(figure, nearby)
    found = rp.problems(page, secs)
    assert len(found) == 1 and found[0].startswith(f"{figure}: cites")
    assert rp.render(secs) != rp.render()


def test_the_readme_quotes_no_figures_and_links_the_results():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert "docs/results.md" in text
    assert not re.search(r"reports/(paper|records)/[\w./-]+\.json", text), "README cites a record"
    assert "## Status" not in text


def test_user_documents_name_no_issue_numbers():
    for p in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        hits = re.findall(r"issues?\s*#?\d+", p.read_text(encoding="utf-8"), flags=re.I)
        assert not hits, (p.name, hits)


# ------------------------------------------------------------------------------------- key paths
DOC = {
    "rows": [
        {"method": "modal_mcmc", "snr_db": None, "hits": 1},
        {"method": "modal_mcmc", "snr_db": 10.0, "hits": 2, "ci": [3.0, 4.0]},
        {"method": "ensemble", "snr_db": 10.0, "hits": 5},
    ],
    "coverage": {"EI_segments[0]": {"hits": 7}},
}


def test_a_key_path_names_exactly_one_field():
    assert records.get(DOC, "rows[method=modal_mcmc,snr_db=10].hits") == 2
    assert records.get(DOC, "rows[method=modal_mcmc,snr_db=null].hits") == 1
    assert records.get(DOC, "rows[1].ci[1]") == 4.0
    assert records.get(DOC, 'coverage."EI_segments[0]".hits') == 7
    for bad in (
        "rows[method=modal_mcmc].hits",  # two rows match
        "rows[method=bpinn].hits",  # none
        "rows[7].hits",
        "rows[0].misses",
        "coverage.EI_segments[0].hits",  # unquoted: a field EI_segments, then an index
        "rows..hits",
    ):
        with pytest.raises(KeyError):
            records.get(DOC, bad)


@needs_git
def test_an_older_record_loads_with_its_commit_and_a_date():
    """A run folder written before records carried a date: its commit's date stands in for it."""
    man = records.load(ROOT / "reports/records/exeter-snr10-seed0/manifest.json")
    assert "date" not in man and man["git_commit"]
    prov = records.provenance_of("reports/records/exeter-snr10-seed0/summary.json", "methods", ROOT)
    assert prov["commit"] == man["git_commit"][:12]
    assert re.fullmatch(r"\d{4}-\d{2}-\d{2}, (commit date|committed)", prov["date"])
    assert prov["machine"].endswith("2 cores")


# ------------------------------------------------------------------------------------------ pages
PAGES = ("coverage", "table4", "table5", "table6", "family", "girders", "girder_pinns", "fitcheck")
#: coverage studies of other girders and cases, each its own page
PAGES += tuple(p.stem for p in sorted((ROOT / "reports" / "paper").glob("coverage-*.json")))


@pytest.fixture(scope="module")
def render():
    import render as r

    return r


@pytest.mark.parametrize("name", PAGES)
def test_committed_pages_are_what_todays_code_renders(name, render):
    out = ROOT / "reports" / "paper"
    text = render.page_text(name, out)
    if text is None:
        pytest.skip(f"no {name}.json committed")
    committed = (out / f"{name}.md").read_text(encoding="utf-8")
    assert committed == text, (
        f"reports/paper/{name}.md is not what today's code renders from {name}.json: run "
        "`python studies/render.py --out reports/paper` and commit the pages"
    )
