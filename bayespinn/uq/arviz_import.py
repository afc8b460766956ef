"""Import ArviZ safely when several processes start at once.

ArviZ 0.23 writes a once-a-day stamp file on import through a fixed temporary name; two processes
importing it in the same second (test workers, a worker pool) can both write that name, and the
slower one's rename then fails with FileNotFoundError. The stamp is written by then, so a second
import succeeds. The notice it guards (a future refactor of ArviZ) is not about anything bayespinn
does, so it is silenced here."""

from __future__ import annotations

import warnings


def import_arviz():
    """The `arviz` module, imported with its daily notice silenced and its stamp-file race retried."""
    for attempt in range(3):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", FutureWarning)
                import arviz
            return arviz
        except FileNotFoundError:
            if attempt == 2:
                raise
    raise AssertionError("unreachable")
