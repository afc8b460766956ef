"""The paper's Table 4 with intervals: EI identified from deflections at clean, 10, 20, 30 and 40 dB.

Each method is swept with `bayespinn.sweep.sweep` into <out>/table4/<method>/ (one full sweep folder
per method: sweep.json, report.md/html, the EI-against-SNR figure and a run folder per level); the
combined sweep report over all methods present goes into <out>/table4/, and the table itself into
<out>/table4.md and <out>/table4.json: per level and method the posterior mean of EI, its 90 % and
95 % intervals, the relative error, whether the intervals contain the truth, and the paper's single
point estimate beside it. Running it again for some methods replaces their rows and keeps the others.

    python studies/table4.py --methods modal --out reports/paper
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path
from types import SimpleNamespace

import common as c

from bayespinn.config import preset
from bayespinn.report.document import Alert, BulletList, Heading, Paragraph, table
from bayespinn.report.sweep import PAPER_TABLE4, write_sweep_reports
from bayespinn.report.units import fmt_pct, name
from bayespinn.sweep import sweep
from bayespinn.uq.agreement import MEAN_TOL_SD, SD_RATIO_RANGE, agreement

log = logging.getLogger("studies.table4")

SCHEMA = "bayespinn.studies.table4/1"
LEVELS = "clean,10,20,30,40"


def row_of(lv: dict, key: str, truth_EI: float, folder: str) -> dict:
    """One table row from a sweep level's summary entry for one method."""
    m = lv["methods"][key]
    e = m["EI"]
    paper = PAPER_TABLE4.get(None if lv["snr_db"] is None else float(lv["snr_db"]))
    return {
        "snr_db": lv["snr_db"],
        "method": key,
        "EI": e,
        "truth_in_ci90": c.inside(e["ci90"], truth_EI),
        "truth_in_ci95": c.inside(e["ci95"], truth_EI),
        "identified": m.get("identified"),
        "converged": (m.get("diagnostics") or {}).get("converged"),
        "paper": None
        if paper is None
        else {
            "EI": paper[0],
            "rel_error_pct": paper[1],
            "in_ci90": c.inside(e["ci90"], paper[0]),
        },
        "runtime_s": m.get("runtime_s"),
        "folder": folder,
        "summary": m,
    }


def sort_key(r: dict) -> tuple:
    return (c.snr_key(r["snr_db"]), c.method_key(r["method"]))


def combined_doc(doc: dict) -> dict:
    """A sweep.json over every method of the table (levels from the per-method sweeps)."""
    levels: dict = {}
    for r in doc["rows"]:
        lv = levels.setdefault(
            c.snr_key(r["snr_db"]),
            {
                "snr_db": r["snr_db"],
                "folder": r["folder"].removeprefix("table4/"),
                "methods": {},
                "folders": {},
            },
        )
        lv["methods"][r["method"]] = r["summary"]
        lv["folders"][r["method"]] = r["folder"].removeprefix("table4/")
    return {
        "schema": "bayespinn.sweep/1",
        "case": "deflection",
        "seed": sorted({doc["runs"][r["run"]]["seed"] for r in doc["rows"]})[0]
        if doc["rows"]
        else 0,
        "levels": [levels[k] for k in sorted(levels)],
        "note": "combined from the per-method sweeps in the sub-folders; 'folder' is the first method's",
    }


def blocks(doc: dict) -> list:
    truth = doc["truth"]["EI"]
    runs = list(doc["runs"])
    verdicts: dict = {}
    by_level: dict = {}
    for r in doc["rows"]:
        by_level.setdefault(c.snr_key(r["snr_db"]), {})[r["method"]] = r["summary"]
    for k, methods in by_level.items():
        verdicts[k] = {v.method: v.label for v in agreement(methods)}
    rows = []
    for r in doc["rows"]:
        e, p = r["EI"], r["paper"] or {}
        rows.append(
            (
                c.snr_text(r["snr_db"]),
                name(r["method"]),
                c.kN(e["mean"]),
                f"{e['sd'] / 1e3:,.0f}",
                c.kN_interval(e["ci90"]),
                c.kN_interval(e["ci95"]),
                fmt_pct(e["rel_error_pct"]),
                f"{c.yes_no(r['truth_in_ci90'])} / {c.yes_no(r['truth_in_ci95'])}",
                c.kN(p.get("EI")),
                f"{p['rel_error_pct']:.2f} %" if p else "n/a",
                c.yes_no(p.get("in_ci90")),
                verdicts[c.snr_key(r["snr_db"])].get(
                    r["method"], "reference" if r["method"] == "modal_mcmc" else "n/a"
                ),
                c.run_cell(doc, r),
            )
        )
    out = [
        Heading("Table 4 with intervals: EI from deflections at each SNR", 1),
        Paragraph(
            f"Case study 1 (one 37 kN axle at 7.115 m/s, 100 random deflection samples). True EI = "
            f"{c.kN(truth)} kN m² (= {truth:.6g} N m²). EI is shown in kN m², the unit of the paper's "
            "Table 4 (printed there under an 'N.m²' label). The paper's column is its one deterministic "
            "PINN: a point estimate with no interval."
        ),
    ]
    for r in doc["rows"]:
        if r.get("identified") is False:
            out.append(
                Alert(
                    f"At {c.snr_text(r['snr_db'])}: **EI is not identified by these data** ({name(r['method'])})."
                )
            )
        if r.get("converged") is False:
            out.append(
                Alert(
                    f"At {c.snr_text(r['snr_db'])}: {name(r['method'])} did not meet its convergence criteria."
                )
            )
    out.append(
        table(
            (
                "SNR",
                "method",
                "posterior mean EI (kN m²)",
                "sd (kN m²)",
                "90 % interval (kN m²)",
                "95 % interval (kN m²)",
                "rel. error",
                "truth in 90 / 95 %",
                "paper EI (kN m²)",
                "paper Re %",
                "paper EI in our 90 %",
                "vs modal reference",
                "run",
            ),
            rows,
            "Relative error = 100 (mean - truth) / truth; intervals are equal-tailed; 'vs modal reference': "
            f"agreement with the modal reference posterior (|Δmean| <= {MEAN_TOL_SD:g} reference sd and sd ratio "
            f"in [{SD_RATIO_RANGE[0]:g}, {SD_RATIO_RANGE[1]:g}]); 'run': the invocation listed under Provenance.",
        )
    )
    out += c.not_run_yet(doc)
    out += [
        Heading("Files"),
        BulletList(
            (
                "`table4.json`: these rows in SI units (EI in N m²), with each method's full summary entry;",
                "`table4/report.md`, `table4/report.html`: the combined sweep report (figure of EI against SNR);",
                "`table4/<method>/`: that method's sweep folder (`sweep.json`, a run folder per level with "
                "`summary.json`, `data.csv`, posteriors, figures and Table 5 with uncertainty).",
            )
        ),
        Heading("Provenance"),
        BulletList(tuple(c.provenance_lines(doc["runs"], runs))),
    ]
    return out


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    p = c.parser("The paper's Table 4 with credible intervals (deflection case, SNR sweep).")
    p.add_argument("--snr", default=LEVELS, help=f"comma list of levels (default {LEVELS})")
    args = p.parse_args(argv)
    c.setup_logging(args.quiet)
    methods = c.methods_of(args.methods)
    levels = c.levels_of(args.snr)
    cfg = preset("deflection")
    out = Path(args.out)
    keys = [c.key_of(m) for m in methods]
    prov = c.provenance(__file__, argv, args, methods=keys, levels=levels)
    new_rows = []
    for m, key in zip(methods, keys, strict=True):
        log.info("table4: sweeping %s over %s", key, ", ".join(c.snr_text(v) for v in levels))
        sdoc = sweep(
            cfg,
            levels=levels,
            methods=[m],
            seed=args.seed,
            out=out / "table4" / key,
            opts=c.run_options(args),
        )
        for lv in sdoc["levels"]:
            new_rows.append(row_of(lv, key, cfg.beam.EI, f"table4/{key}/{lv['folder']}"))
    doc = c.load_table(out / "table4.json", SCHEMA)
    doc.update(case="deflection", truth={"EI": cfg.beam.EI}, units={"EI": "N m^2"})
    c.merge(doc, new_rows, prov, ("snr_db", "method"), sort_key)
    sweep_doc = combined_doc(doc)
    write_sweep_reports(
        sweep_doc,
        [SimpleNamespace(truth={"EI": cfg.beam.EI}, posteriors={})],
        out / "table4",
        cfg=cfg,
    )
    c.write_json(out / "table4" / "sweep.json", sweep_doc)
    c.write_json(out / "table4.json", doc)
    c.write_markdown(out / "table4.md", blocks(doc))
    log.info("wrote %s and %s", out / "table4.md", out / "table4.json")
    return 0


if __name__ == "__main__":
    c.entry(main)
