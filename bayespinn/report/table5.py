"""The paper's Table 5 with uncertainty, formatted: display rows and Markdown of `uq.table5.table5`'s dict
(the metrics and their definitions are there)."""

from __future__ import annotations

from ..uq.table5 import N_POINTS, QUANTITIES, table5  # noqa: F401  (the report's entry point)
from .units import DISPLAY, fmt, name

HEADER = (
    "t (s)",
    "u RMSE (mm)",
    "u RMSE 90 % over draws",
    "u CV %",
    "u NMB %",
    "u band covers FE",
    "M RMSE (kN m)",
    "M RMSE 90 % over draws",
    "M CV %",
    "M NMB %",
    "M band covers FE",
)


def table5_rows(t5: dict) -> list[tuple[str, ...]]:
    """Display rows (mm, kN m, %) of a `table5` dict, in the order of HEADER."""
    out = []
    for r in t5["rows"]:
        cells = [f"{r['t']:.2f}"]
        for q in QUANTITIES:
            f, _ = DISPLAY[q]
            m = r[q]
            cells += [
                fmt(m["rmse"] * f, ".3g"),
                f"[{fmt(m['rmse_ci90'][0] * f, '.3g')}, {fmt(m['rmse_ci90'][1] * f, '.3g')}]",
                fmt(m["cv_pct"], ".2f"),
                fmt(m["nmb_pct"], "+.2f"),
                f"{100 * m['coverage']:.0f} %",
            ]
        out.append(tuple(cells))
    return out


def table5_markdown(t5: dict) -> str:
    """The Markdown table of a `table5` dict, with a line naming the method and the definitions."""
    lines = [
        f"Table 5 with uncertainty, {name(t5['method'])}: posterior predictive mean against the FE truth at "
        f"{t5['n_points']} interior span points; CV = RMSE / mean|truth| x 100, NMB = sum(pred - truth) / "
        f"sum(truth) x 100; 'band covers FE': share of points where the {100 * t5['level']:.0f} % band "
        "contains the truth.",
        "",
        "| " + " | ".join(HEADER) + " |",
        "|" + "---|" * len(HEADER),
    ]
    lines += ["| " + " | ".join(r) + " |" for r in table5_rows(t5)]
    return "\n".join(lines) + "\n"
