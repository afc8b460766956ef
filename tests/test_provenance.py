"""A record names the code that computed it: the commit and dirty flag read when the package was imported,
not when the record is written (a study that runs for hours while its checkout moves on)."""

from __future__ import annotations

from bayespinn import provenance as pv


def test_provenance_names_the_code_imported_not_the_checkout_now(monkeypatch):
    started = pv.code_commit()
    p = pv.provenance()
    assert (p["git_commit"], p["git_dirty"]) == (started["commit"], started["dirty"])
    # the checkout moves on (a commit and an edit while the study runs): the records keep the old code
    monkeypatch.setattr(pv, "git_commit", lambda: "f" * 40)
    monkeypatch.setattr(pv, "git_dirty", lambda: True)
    p = pv.provenance()
    assert (p["git_commit"], p["git_dirty"]) == (started["commit"], started["dirty"])
    # the negative control: a freshly read state is the moved one, which the records must not take
    pv.code_commit.cache_clear()
    try:
        assert pv.provenance()["git_commit"] == "f" * 40
    finally:
        pv.code_commit.cache_clear()
        monkeypatch.undo()
        pv.code_commit()
