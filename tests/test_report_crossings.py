"""The report's section on a crossing's nuisances: present with the inferred quantities (one crossing, and
per crossing with its fit check), absent when nothing was inferred."""

from __future__ import annotations

from bayespinn.report.crossings import nuisance_section
from bayespinn.report.document import Table


def _entry(mean: float) -> dict:
    return {"mean": mean, "sd": 0.1 * mean, "ci90": [0.9 * mean, 1.1 * mean]}


def test_one_crossing_lists_each_inferred_quantity():
    s = {"methods": {"modal_mcmc": {"speed": _entry(7.1), "body_frequency": _entry(2.2)}}}
    blocks = nuisance_section(s)
    tab = next(b for b in blocks if isinstance(b, Table))
    labels = [r[2] for r in tab.rows]
    assert labels == ["speed (m/s)", "suspension bounce frequency (Hz)"]
    assert tab.rows[0][3] == "7.1"


def test_several_crossings_carry_their_fit_checks_and_nothing_inferred_gives_no_section():
    per = {"c0": {"speed": _entry(7.0), "fit_check": {"verdict": "fits"}},
           "c1": {"entry_time": _entry(0.4), "fit_check": {"verdict": "misfit"}}}  # fmt: skip
    tab = next(b for b in nuisance_section({"methods": {"modal_mcmc": {"crossings": per}}})
               if isinstance(b, Table))  # fmt: skip
    assert [(r[1], r[6]) for r in tab.rows] == [("c0", "fits"), ("c1", "misfit")]
    assert nuisance_section({"methods": {"modal_mcmc": {"EI": _entry(1e9)}}}) == []


def test_combined_crossings_show_the_crossing_error_and_each_crossings_own_ei():
    m = {
        "EI": _entry(1e9),
        "crossing_error": _entry(0.002),
        "crossings": {"c0": {"EI": _entry(1.01e9), "fit_check": {"verdict": "fits"}}},
    }
    tab = next(b for b in nuisance_section({"methods": {"modal_mcmc": m}}) if isinstance(b, Table))
    rows = [(r[1], r[2]) for r in tab.rows]
    assert rows == [
        ("all", "crossing-level error of EI (relative sd) (-)"),
        ("c0", "EI within the combination (N m^2)"),
    ]  # the shared EI is the headline's, not a nuisance row
