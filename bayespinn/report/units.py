"""Display units and number formats of the reports. Files and the API stay SI; reports *show*
EI in GN m^2, deflection in mm, moment in kN m and strain in microstrain, always labelled."""

from __future__ import annotations

import math

from .. import methods
from ..uq.agreement import REFERENCE_KEY  # noqa: F401  (the reports' reference key)

#: quantity -> (factor from SI to the display unit, display unit)
DISPLAY = {
    "EI": (1e-9, "GN m²"),
    "deflection": (1e3, "mm"),
    "moment": (1e-3, "kN m"),
    "strain": (1e6, "µε"),
}


def name(key: str) -> str:
    """Display name of a method's summary key (from the method registry; the key itself if unknown)."""
    return methods.display(key)


def fmt_EI(v: float | None, decimals: int = 4) -> str:
    """EI [N m^2] in GN m^2 with `decimals` decimals ('n/a' for None or NaN)."""
    if v is None or not math.isfinite(v):
        return "n/a"
    return f"{v / 1e9:.{decimals}f}"


def ei_decimals(width: float | None) -> int:
    """Decimals (GN m^2) that resolve an interval of `width` [N m^2]: 4, more for very narrow ones."""
    if width is None or not math.isfinite(width) or width <= 0:
        return 4
    return int(min(9, max(4, math.ceil(-math.log10(width / 1e9)) + 2)))


def fmt_EI_sd(v: float | None) -> str:
    """A spread of EI [N m^2] in GN m^2, 3 significant digits (tiny ones stay visible)."""
    return fmt(None if v is None else v / 1e9, ".3g")


def fmt_EI_interval(ci, decimals: int | None = None) -> str:
    """'[lo, hi]' of an EI interval [N m^2] in GN m^2, by default with enough decimals to tell lo from hi."""
    if not ci or len(ci) != 2 or ci[0] is None or ci[1] is None:
        return "n/a"
    d = ei_decimals(ci[1] - ci[0]) if decimals is None else decimals
    return f"[{fmt_EI(ci[0], d)}, {fmt_EI(ci[1], d)}]"


def fmt_pct(v: float | None) -> str:
    """A signed percentage: 2 decimals, or 2 significant digits when below 0.01 %."""
    if v is None or not math.isfinite(v):
        return "n/a"
    return f"{v:+.2f} %" if abs(v) >= 0.01 or v == 0 else f"{v:+.1e} %"


def sigma_unit(case: str) -> tuple[float, str]:
    """(factor, unit) to display the noise sd of a case: mm for deflection, µε for strain."""
    return DISPLAY["deflection"] if case == "deflection" else DISPLAY["strain"]


def fmt(v: float | None, spec: str = ".4g") -> str:
    """A number, or 'n/a' for None / NaN / inf."""
    if v is None:
        return "n/a"
    try:
        f = float(v)
    except (TypeError, ValueError):
        return str(v)
    return f"{f:{spec}}" if math.isfinite(f) else "n/a"


def fmt_interval(ci, factor: float = 1.0, spec: str = ".4g") -> str:
    """'[lo, hi]' of an interval in display units."""
    if not ci or len(ci) != 2 or ci[0] is None or ci[1] is None:
        return "n/a"
    return f"[{fmt(ci[0] * factor, spec)}, {fmt(ci[1] * factor, spec)}]"


def covers(ci, truth: float | None) -> str:
    """'yes' / 'no' whether an interval [lo, hi] contains the truth; 'n/a' without one."""
    if truth is None or not ci or ci[0] is None or ci[1] is None:
        return "n/a"
    return "yes" if ci[0] <= truth <= ci[1] else "**no**"
