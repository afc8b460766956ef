"""The sweep's combined report: the paper's Table 4 with intervals per method, EI against SNR.

Writes into the sweep folder `report.md`, `report.html` (self-contained) and `fig_sweep_ei.png`; with
the runs' results at hand it adds the paper's Table 5 with uncertainty for every level.
"""

from __future__ import annotations

import io
import logging
from pathlib import Path

import numpy as np

from .. import methods
from ..config import Config, resolve, snr_label
from ..uq.agreement import MEAN_TOL_SD, REFERENCE_KEY, SD_RATIO_RANGE, agreement
from ..uq.table5 import table5
from .canvas import DPI, TRUTH_STYLE
from .document import Alert, Block, BulletList, Figure, Heading, Paragraph, table
from .files import write_bytes, write_text
from .html import render_html
from .markdown import render_markdown
from .table5 import HEADER as T5_HEADER
from .table5 import table5_rows
from .units import DISPLAY, covers, ei_decimals, fmt_EI, fmt_EI_interval, fmt_EI_sd, fmt_pct, name

log = logging.getLogger(__name__)

FIGURE = "fig_sweep_ei.png"
#: the paper's Table 4 (deflection case, one deterministic PINN): SNR -> (EI [N m^2], Re %); the paper
#: prints EI in kN m^2 under an "N.m^2" label (1,033,610 for the true 1.03361e9 N m^2)
PAPER_TABLE4 = {
    None: (1.036091e9, 0.24),
    10.0: (1.043533e9, 0.96),
    20.0: (1.041879e9, 0.80),
    30.0: (1.037124e9, 0.34),
    40.0: (1.036607e9, 0.29),
}


def _snr(v) -> str:
    return "clean" if v is None else f"{snr_label(v)} dB"


def _truth_EI(results: list) -> float | None:
    for r in results or ():
        if getattr(r, "truth", None):
            return float(r.truth["EI"])
    return None


def table4(doc: dict, truth_EI: float | None = None) -> list[str]:
    """Markdown rows of Table 4 with intervals (kept for callers of the first version)."""
    return render_markdown([table4_block(doc, truth_EI)]).rstrip("\n").split("\n")


def table4_block(doc: dict, truth_EI: float | None = None):
    """Table 4 with intervals: a row per level and method; EI [N m^2] shown in GN m^2."""
    rows = []
    for lv in doc["levels"]:
        verdicts = {v.method: v.label for v in agreement(lv["methods"])}
        for key, m in lv["methods"].items():
            e = m["EI"]
            err = fmt_pct(e["rel_error_pct"]) if e.get("rel_error_pct") is not None else "n/a"
            d = ei_decimals(e["ci90"][1] - e["ci90"][0])
            rows.append(
                (
                    _snr(lv["snr_db"]),
                    name(key),
                    fmt_EI(e["mean"], d),
                    fmt_EI_sd(e["sd"]),
                    fmt_EI_interval(e["ci90"], d),
                    fmt_EI_interval(e["ci95"], d),
                    err,
                    f"{covers(e['ci90'], truth_EI)} / {covers(e['ci95'], truth_EI)}",
                    verdicts.get(key, "reference" if key == REFERENCE_KEY else "n/a"),
                )
            )
    return table(
        (
            "SNR",
            "method",
            "mean EI (GN m²)",
            "sd (GN m²)",
            "90 % interval",
            "95 % interval",
            "rel. error",
            "truth inside 90 / 95 %",
            "vs modal reference",
        ),
        rows,
        "Relative error = 100 (mean - truth) / truth; 'truth inside': whether the 90 % / 95 % interval "
        "contains the true EI; 'vs modal reference': the agreement verdict of the run report "
        f"(|Δmean| <= {MEAN_TOL_SD:g} reference sd and sd ratio in [{SD_RATIO_RANGE[0]:g}, {SD_RATIO_RANGE[1]:g}]).",
    )


def paper_block(doc: dict):
    rows = []
    for lv in doc["levels"]:
        p = PAPER_TABLE4.get(None if lv["snr_db"] is None else float(lv["snr_db"]))
        if p is not None:
            rows.append((_snr(lv["snr_db"]), fmt_EI(p[0]), f"{p[1]:.2f} %"))
    if doc.get("case") != "deflection" or not rows:
        return []
    return [
        Paragraph(
            "For comparison, the paper's Table 4 (one deterministic PINN, a point estimate with no "
            "interval; its EI column is in kN m², shown here in GN m²):"
        ),
        table(("SNR", "paper EI (GN m²)", "paper Re %"), rows),
    ]


def _linthresh(values: list[float]) -> float:
    """A power of ten at or below the smallest |value| (at least 1e-4 %): the linear zone of the symlog
    axis, so even the narrowest interval is drawn to scale."""
    v = np.abs(np.asarray(values, float))
    v = v[np.isfinite(v) & (v > 0)]
    if not v.size:
        return 0.1
    return float(10.0 ** np.floor(np.log10(max(v.min(), 1e-4))))


def sweep_figure(doc: dict, truth_EI: float | None, path: Path) -> str:
    """EI posteriors against SNR: mean, 90 % (thick) and 95 % (thin) intervals per method per level; with
    the truth known, a second panel shows them relative to it on a symmetric log scale, so the narrow
    intervals of the quiet levels stay visible next to the wide ones of the noisy levels."""
    from matplotlib.figure import Figure as MplFigure

    levels = doc["levels"]
    keys = list(dict.fromkeys(k for lv in levels for k in lv["methods"]))
    f, unit = DISPLAY["EI"]
    panels = [("EI", lambda v: v * f, f"EI ({unit})")]
    if truth_EI is not None:
        panels.append(
            ("rel", lambda v: 100.0 * (v - truth_EI) / truth_EI, "EI relative to the truth (%)")
        )
    fig = MplFigure(
        figsize=(max(6.0, 1.2 * len(levels) + 2.5) * len(panels), 5.0),
        dpi=DPI,
        layout="constrained",
    )
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    width = 0.6
    for ax, (kind, tr, label) in zip(axes, panels, strict=True):
        for j, key in enumerate(keys):
            off = (j - (len(keys) - 1) / 2) * width / max(len(keys), 1)
            pts = [
                (i + off, lv["methods"][key]["EI"])
                for i, lv in enumerate(levels)
                if key in lv["methods"]
            ]
            if not pts:
                continue
            xs = [x for x, _ in pts]
            mean = np.array([tr(e["mean"]) for _, e in pts])
            c90 = np.array([[tr(e["ci90"][0]), tr(e["ci90"][1])] for _, e in pts])
            c95 = np.array([[tr(e["ci95"][0]), tr(e["ci95"][1])] for _, e in pts])
            c = methods.colour(key)
            ax.errorbar(
                xs,
                mean,
                yerr=[mean - c95[:, 0], c95[:, 1] - mean],
                fmt="none",
                ecolor=c,
                elinewidth=1,
                capsize=3,
            )
            ax.errorbar(
                xs,
                mean,
                yerr=[mean - c90[:, 0], c90[:, 1] - mean],
                fmt="o",
                color=c,
                ecolor=c,
                elinewidth=4,
                ms=5,
                label=f"{name(key)}: mean, 90 % (thick) and 95 % (thin)",
            )
        if truth_EI is not None:
            ax.axhline(tr(truth_EI), label="true EI", **TRUTH_STYLE)
        if kind == "rel":
            lt = _linthresh(
                [
                    tr(lv["methods"][k]["EI"]["ci90"][q])
                    for lv in levels
                    for k in lv["methods"]
                    for q in (0, 1)
                ]
            )
            ax.set_yscale("symlog", linthresh=lt)
            ax.set_title(
                f"relative to the true EI (symmetric log scale, linear within ±{lt:g} %)",
                fontsize=9,
            )
        ax.set_xticks(range(len(levels)), [_snr(lv["snr_db"]) for lv in levels])
        ax.set_xlim(-0.6, len(levels) - 0.4)
        ax.set_xlabel("signal-to-noise ratio")
        ax.set_ylabel(label)
    axes[0].legend(fontsize=8, loc="best")
    fig.suptitle(
        f"Posterior of EI against SNR ({doc['case']} case, seed {doc['seed']})", fontsize=11
    )
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, metadata={"Software": None})
    write_bytes(path, buf.getvalue())
    return (
        "Posterior mean (dot), 90 % (thick bar) and 95 % (thin bar) credible intervals of EI per method "
        "at each SNR"
        + (
            "; dashed black line: the true EI; right: the same relative to the truth."
            if truth_EI is not None
            else "."
        )
    )


def config_of(result) -> Config | None:
    """The resolved configuration of a run, rebuilt from its manifest."""
    c = (getattr(result, "manifest", None) or {}).get("config")
    if not c:
        return None
    return resolve(c["case"], {k: c[k] for k in ("beam", "vehicle", "data", "prior") if k in c})


def table5_section(doc: dict, results: list, cfg: Config | None) -> list[Block]:
    """Table 5 with uncertainty at every level whose run had the truth and a predictor."""
    out: list[Block] = []
    notes = []
    for lv, res in zip(doc["levels"], results or (), strict=False):
        if res is None or res.truth is None:
            continue
        c = cfg or config_of(res)
        for key, p in res.posteriors.items():
            if p.predictor is None:
                continue
            try:
                t5 = table5(res, c, key)
            except Exception as exc:  # an extra: never lose the sweep report for it
                log.warning(
                    "warning: Table 5 for %s at SNR %s failed: %s: %s",
                    key,
                    _snr(lv["snr_db"]),
                    type(exc).__name__,
                    exc,
                )
                notes.append(
                    f"{name(key)} at {_snr(lv['snr_db'])}: left out ({type(exc).__name__}: {exc})."
                )
                continue
            out.append(table(T5_HEADER, table5_rows(t5), f"{_snr(lv['snr_db'])}, {name(key)}"))
    if not out and not notes:
        return []
    head: list[Block] = [
        Heading("Responses against the FE truth (paper Table 5 with uncertainty)"),
        Paragraph(
            "Per SNR and method: RMSE of the posterior predictive mean against the finite-element truth "
            "along the span (mm, kN m), the 90 % interval of the RMSE of single posterior draws, "
            "CV = RMSE / mean|truth| x 100, NMB = sum(pred - truth) / sum(truth) x 100, and the share "
            "of span points where the 90 % credible band contains the truth."
        ),
    ]
    return head + out + ([BulletList(tuple(notes))] if notes else [])


def sweep_document(
    doc: dict,
    results: list,
    figure: tuple[str, str] | None,
    figure_note: str | None,
    cfg: Config | None = None,
) -> list[Block]:
    truth = _truth_EI(results)
    blocks: list[Block] = [
        Heading(f"bayespinn sweep: {doc['case']} case, seed {doc['seed']}", 1),
        Paragraph(
            "The paper's Table 4 with credible intervals: per SNR and method, the posterior mean of EI, "
            "its 90 % and 95 % equal-tailed intervals and the relative error"
            + (f" against the true EI = {fmt_EI(truth)} GN m²." if truth is not None else ".")
        ),
    ]
    for lv in doc["levels"]:
        for v in agreement(lv["methods"]):
            if v.agrees is False:
                blocks.append(Alert(f"At {_snr(lv['snr_db'])}: {v.sentence()}"))
        for key, m in lv["methods"].items():
            if m.get("identified") is False:
                blocks.append(
                    Alert(
                        f"At {_snr(lv['snr_db'])}: **EI is not identified by these data** ({name(key)})."
                    )
                )
    blocks += [Heading("Table 4 with intervals"), table4_block(doc, truth), *paper_block(doc)]
    blocks.append(Heading("EI against SNR"))
    if figure is not None:
        blocks.append(Figure("Posterior of EI against SNR", figure[0], figure[1]))
    if figure_note:
        blocks.append(Paragraph(figure_note))
    blocks += table5_section(doc, results, cfg)
    blocks += [
        Heading("Runs"),
        BulletList(
            tuple(
                f"{_snr(lv['snr_db'])}: [report.md]({lv['folder']}/report.md), "
                f"[report.html]({lv['folder']}/report.html), `{lv['folder']}/summary.json`"
                for lv in doc["levels"]
            )
        ),
    ]
    return blocks


def write_sweep_reports(
    doc: dict, results: list, out: str | Path, *, cfg: Config | None = None
) -> dict[str, Path]:
    """Write report.md, report.html and the EI-against-SNR figure into the sweep folder `out`.

    doc : the sweep.json document (levels with their summary `methods`);
    results : the `pipeline.RunResult` of each level, in the order of doc['levels'] (may be empty: the
        truth line and Table 5 are then left out);
    cfg : the configuration (default: rebuilt from each run's manifest).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    figure, note = None, None
    try:
        figure = (FIGURE, sweep_figure(doc, _truth_EI(results), out / FIGURE))
    except Exception as exc:  # a figure must never lose the report
        log.warning("warning: sweep figure failed and is left out: %s: %s", type(exc).__name__, exc)
        note = f"The figure of EI against SNR is left out: drawing it failed ({type(exc).__name__}: {exc})."
    blocks = sweep_document(doc, results, figure, note, cfg)
    write_text(out / "report.md", render_markdown(blocks))
    title = f"bayespinn sweep: {doc['case']} case, seed {doc['seed']}"
    write_text(out / "report.html", render_html(blocks, out, title))
    paths = {"report.md": out / "report.md", "report.html": out / "report.html"}
    if figure is not None:
        paths[FIGURE] = out / FIGURE
    return paths
