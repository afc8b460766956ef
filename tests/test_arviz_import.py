"""ArviZ's daily-notice stamp can race between processes importing it at once: the import is retried."""

from __future__ import annotations

import builtins
import sys

import pytest

from bayespinn.uq.arviz_import import import_arviz


def _failing_import(monkeypatch, failures: int) -> list[int]:
    real = builtins.__import__
    calls = [0]

    def fake(name, *args, **kwargs):
        if name == "arviz":
            calls[0] += 1
            if calls[0] <= failures:
                raise FileNotFoundError("daily_warning.tmp -> daily_warning")
        return real(name, *args, **kwargs)

    monkeypatch.delitem(sys.modules, "arviz", raising=False)
    monkeypatch.setattr(builtins, "__import__", fake)
    return calls


def test_a_lost_stamp_race_is_retried(monkeypatch):
    calls = _failing_import(monkeypatch, failures=1)
    az = import_arviz()
    assert calls[0] == 2 and hasattr(az, "from_netcdf")


def test_an_import_that_keeps_failing_is_raised(monkeypatch):
    # negative control: the retry is bounded, a real missing file is not swallowed
    _failing_import(monkeypatch, failures=10)
    with pytest.raises(FileNotFoundError):
        import_arviz()
