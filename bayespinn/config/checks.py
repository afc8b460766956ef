"""The checks of a configuration value that every section of the configuration shares (a finite number,
one > 0 or >= 0, an integer with a minimum), raising `InputError` that names the TOML key; in a module of
their own because the bridge, the analysis model and the girder posterior all use them."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import InputError


def _check_number(name: str, value: Any, *, positive: bool = False, nonneg: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
        raise InputError(name, value, "a number")
    v = float(value)
    if not math.isfinite(v):
        raise InputError(name, value, "a finite number")
    if positive and v <= 0:
        raise InputError(name, value, "a finite number > 0")
    if nonneg and v < 0:
        raise InputError(name, value, "a finite number >= 0")
    return v


def _check_int(name: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise InputError(name, value, f"an integer >= {minimum}")
    if value < minimum:
        raise InputError(name, value, f"an integer >= {minimum}")
    return int(value)
