"""Exceptions that the command line maps to exit codes.

`InputError` means *the user gave us something wrong* (exit code 2): it always names the field, the
value and what was expected, in one line.
"""

from __future__ import annotations


class InputError(ValueError):
    """Bad user input: a configuration value, a flag or a cell of a measurement file.

    Parameters
    ----------
    field : str
        Where the bad value sits, e.g. ``"beam.length"``, ``"--snr"`` or ``"data.csv row 4, column x"``.
    value : object
        The offending value, as given.
    expected : str
        What would have been accepted, e.g. ``"a finite number > 0"``.
    """

    def __init__(self, field: str, value: object, expected: str):
        self.field = field
        self.value = value
        self.expected = expected
        shown = repr(value) if not isinstance(value, str) else repr(value)
        if len(shown) > 80:
            shown = shown[:77] + "..."
        super().__init__(f"{field}: got {shown}, expected {expected}")


class TrainingDiverged(RuntimeError):
    """A training loop produced a non-finite loss or parameter (names the step)."""
