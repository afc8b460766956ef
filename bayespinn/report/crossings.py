"""The report's section on what a crossing leaves uncertain: the posteriors of the speed, the entry time,
the damping, the force fluctuation and the suspension, per method and (with several crossings) per
crossing with its own fit check."""

from __future__ import annotations

from .document import Block, Heading, table
from .units import fmt, fmt_interval, name

#: summary keys of the inferred nuisances, with their display names and units
NUISANCES = (
    ("speed", "speed", "m/s"),
    ("entry_time", "entry time", "s"),
    ("damping_ratio", "girder damping ratio", "-"),
    ("axle_force_sd", "axle-force fluctuation (share of the load)", "-"),
    ("axle_force_time_scale", "its time scale", "s"),
    ("axle_force_correlation", "its correlation between axles", "-"),
    ("body_frequency", "suspension bounce frequency", "Hz"),
    ("body_damping", "suspension damping ratio", "-"),
    ("EI", "EI within the combination", "N m^2"),
    ("crossing_error", "crossing-level error of EI (relative sd)", "-"),
)
HEADER = ("method", "crossing", "quantity", "mean", "sd", "90 % interval", "fit check")


def _rows(method: str, where: str, entries: dict, fit: str = "") -> list[tuple]:
    out = []
    for key, label, unit in NUISANCES:
        e = entries.get(key)
        if not isinstance(e, dict) or "mean" not in e:
            continue
        out.append(
            (
                name(method),
                where,
                f"{label} ({unit})",
                fmt(e["mean"]),
                fmt(e.get("sd"), ".3g"),
                fmt_interval(e.get("ci90")),
                fit,
            )  # fmt: skip
        )
    return out


def nuisance_section(summary: dict) -> list[Block]:
    """The section, or nothing when no method inferred any nuisance."""
    rows: list[tuple] = []
    for key, m in summary.get("methods", {}).items():
        rows += _rows(key, "all", {k: v for k, v in m.items() if k != "EI"})
        for cname, e in (m.get("crossings") or {}).items():
            fc = (e.get("fit_check") or {}).get("verdict", "")
            rows += _rows(key, cname, e, fc)
    if not rows:
        return []
    cap = (
        "Posteriors of what the recording leaves uncertain; with several crossings each has its own speed "
        "and entry time and its own fit check (with fluctuating forces also its own damping, force law "
        "and noise, the 'all' rows then pooling the crossings, and its own EI about the shared one)."
    )
    return [Heading("What the crossing leaves uncertain"), table(HEADER, rows, cap)]
