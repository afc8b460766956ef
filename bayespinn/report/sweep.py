"""The sweep's combined report: the paper's Table 4 with intervals per method."""

from __future__ import annotations

from pathlib import Path

from ..config import snr_label
from ..data.measurements import atomic_write_text
from .markdown import NAMES, fmt_EI


def table4(doc: dict) -> list[str]:
    rows = [
        "| SNR | method | mean EI (GN m²) | sd | 90 % interval | 95 % interval | rel. error |",
        "|---|---|---|---|---|---|---|",
    ]
    for lv in doc["levels"]:
        for key, m in lv["methods"].items():
            e = m["EI"]
            err = f"{e['rel_error_pct']:+.2f} %" if "rel_error_pct" in e else "n/a"
            rows.append(
                f"| {snr_label(lv['snr_db'])} | {NAMES.get(key, key)} | {fmt_EI(e['mean'])} | {fmt_EI(e['sd'])} | "
                f"[{fmt_EI(e['ci90'][0])}, {fmt_EI(e['ci90'][1])}] | [{fmt_EI(e['ci95'][0])}, {fmt_EI(e['ci95'][1])}] | {err} |"
            )
    return rows


def write_sweep_reports(doc: dict, results: list, out: Path) -> None:
    lines = [f"# bayespinn sweep: {doc['case']} case, seed {doc['seed']}", "",
             "The paper's Table 4 with credible intervals (EI in GN m²; the paper's values are in kN m² x 1e-3).", "",
             *table4(doc), ""]
    atomic_write_text(Path(out) / "report.md", "\n".join(lines))
