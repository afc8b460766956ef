"""What a run report says, as document blocks (rendered to report.md and report.html alike)."""

from __future__ import annotations

import numpy as np

from ..config import Config, snr_label
from ..uq.agreement import MEAN_TOL_SD, SD_RATIO_RANGE, agreement, caveats
from .appendix import data_section, diagnostics_section, manifest_section, runtime_section
from .crossings import nuisance_section
from .document import Alert, Block, BulletList, Figure, Heading, Paragraph, table
from .figures import FigureFile
from .table5 import HEADER as T5_HEADER
from .table5 import table5_rows
from .units import (
    REFERENCE_KEY,
    covers,
    ei_decimals,
    fmt,
    fmt_EI,
    fmt_EI_interval,
    fmt_EI_sd,
    fmt_interval,
    fmt_pct,
    name,
    sigma_unit,
)

NOT_IDENTIFIED = "EI is not identified by these data"


def title(summary: dict) -> str:
    snr = snr_label(summary.get("snr_db"))
    where = (
        "unknown SNR (measured data)"
        if summary.get("truth") is None
        else ("clean data" if summary.get("snr_db") is None else f"SNR {snr} dB")
    )
    return f"bayespinn report: {summary['case']} case, {where}"


def not_identified(methods: dict) -> list[tuple[str, str]]:
    """(method key, explanation or '') for every method whose entry says `identified: false`."""
    out = []
    for key, m in methods.items():
        if m.get("identified") is False:
            why = [
                str(v)
                for k, v in m.items()
                if "identif" in k and k != "identified" and isinstance(v, str)
            ]
            out.append((key, " ".join(why)))
    return out


def alerts(summary: dict) -> list[Block]:
    """The statements under the headline: identifiability, unconverged samplers, warnings, disagreement."""
    out: list[Block] = []  # a misfit heads the report in the headline (`headline.answer`)
    for key, why in not_identified(summary["methods"]):
        out.append(
            Alert(
                f"**{NOT_IDENTIFIED}** ({name(key)}). "
                + (
                    why
                    or "The posterior of EI is essentially its prior: its intervals are not a measurement."
                )
            )
        )
    for key, m in summary["methods"].items():
        d = m.get("diagnostics") or {}
        if d.get("converged") is False:
            why = "; ".join(d.get("problems") or []) or "R-hat or ESS"
            out.append(
                Alert(
                    f"{name(key)} did not meet its convergence criteria ({why}): "
                    "its intervals are not to be trusted. See Diagnostics."
                )
            )
    for key, m in summary["methods"].items():
        for w in m.get("warnings") or []:
            out.append(Alert(f"{name(key)}: {w}"))
    for v in agreement(summary["methods"]):
        if v.agrees is False:
            out.append(Alert(v.sentence()))
    return out


def ei_table(summary: dict) -> list[Block]:
    truth = summary.get("truth")
    t_EI = truth.get("EI") if truth else None
    rows = []
    for key, m in summary["methods"].items():
        e = m["EI"]
        err = (
            fmt_pct(e["rel_error_pct"])
            if e.get("rel_error_pct") is not None
            else "n/a (truth unknown)"
        )
        flag = " (EI not identified)" if m.get("identified") is False else ""
        d = ei_decimals(e["ci90"][1] - e["ci90"][0])
        rows.append(
            (
                name(key) + flag,
                fmt_EI(e["mean"], d),
                fmt_EI_sd(e["sd"]),
                fmt_EI(e.get("median"), d),
                fmt_EI_interval(e["ci90"], d),
                fmt_EI_interval(e["ci95"], d),
                err,
                f"{covers(e['ci90'], t_EI)} / {covers(e['ci95'], t_EI)}",
            )
        )
    cap = (
        "Relative error = 100 (mean - truth) / truth; 'truth inside': whether the 90 % / 95 % "
        "interval contains the true EI."
        if truth
        else "Truth unknown (measured data): no relative errors."
    )
    return [
        Heading("Flexural rigidity EI"),
        table(
            (
                "method",
                "mean (GN m²)",
                "sd (GN m²)",
                "median",
                "90 % interval",
                "95 % interval",
                "rel. error",
                "truth inside 90 / 95 %",
            ),
            rows,
            cap,
        ),
    ]


def girder_section(result) -> list[Block]:
    """EI along the span (per segment, with the probability of damage), the supports' rotational stiffness
    and the load factor, for the methods that infer them (the modal reference of a real girder)."""
    s = result.summary
    truth = s.get("truth") or {}
    out: list[Block] = []
    for key, m in s["methods"].items():
        segs = m.get("EI_segments")
        if segs:
            t_seg = truth.get("EI_segments") or [None] * len(segs)
            nominal = m.get("EI_nominal")
            rows = [
                (
                    f"{e['x0']:.2f}-{e['x1']:.2f}",
                    fmt_EI(e["mean"]),
                    fmt_EI_interval(e["ci90"]),
                    fmt_EI(t_seg[i]) if t_seg[i] is not None else "n/a",
                    covers(e["ci90"], t_seg[i]),
                    f"{e['p_damaged']:.3f}",
                )
                for i, e in enumerate(segs)
            ]
            flagged = [i + 1 for i, e in enumerate(segs) if e["p_damaged"] >= DAMAGE_FLAG]
            out += [
                Heading(f"EI along the span: {name(key)}"),
                table(
                    (
                        "segment x (m)",
                        "mean (GN m²)",
                        "90 % interval",
                        "truth",
                        "truth inside 90 %",
                        "P(damaged)",
                    ),
                    rows,
                    "P(damaged): the posterior probability that the segment's EI is below 90 % of the "
                    f"nominal {fmt_EI(nominal)} GN m² (`[model] EI_nominal`). EI above is the span-averaged "
                    "flexibility's equivalent L / ∫ dx / EI.",
                ),
            ]
            if flagged:
                out.append(
                    Alert(
                        f"Segment(s) {', '.join(map(str, flagged))} of {len(segs)} are below 90 % of the "
                        f"nominal EI with probability {DAMAGE_FLAG:g} or more ({name(key)}).",
                        "warning",
                    )
                )
        ks = m.get("rotational_stiffness")
        if ks:
            t_k = truth.get("rotational_stiffness") or [None, None]
            out += [
                Heading(f"Support stiffness: {name(key)}", 3),
                table(
                    ("support", "mean (MN m/rad)", "90 % interval (MN m/rad)", "truth"),
                    [
                        (
                            side,
                            fmt(k["mean"] / 1e6),
                            fmt_interval(k["ci90"], 1e-6),
                            "n/a" if t_k[i] is None else fmt(t_k[i] / 1e6),
                        )
                        for i, (side, k) in enumerate(zip(("left", "right"), ks, strict=True))
                    ],
                    "Rotational springs at the bearings (0: a pin; a clamp is infinitely stiff).",
                ),
            ]
        lf = m.get("load_factor")
        if lf:
            post = result.posteriors.get(key)
            out += [Heading(f"Axle-load factor: {name(key)}", 3)]
            out.append(
                table(
                    ("", "mean", "90 % interval", "truth"),
                    [
                        (
                            "load factor",
                            fmt(lf["mean"], ".4f"),
                            fmt_interval(lf["ci90"], 1.0, ".4f"),
                            fmt(truth.get("load_factor"), ".4f"),
                        )
                    ],
                )
            )
            share = load_share(post)
            if share is not None:
                out.append(
                    Paragraph(
                        "EI is identified only up to the load: the quasi-static deflection scales as "
                        f"P / EI. Here the load factor explains {100 * share:.0f} % of the posterior "
                        "variance of log EI (the squared correlation of log EI with log load factor); "
                        f"with the load known exactly EI's interval would be about {100 * (1 - (1 - share) ** 0.5):.0f} % "
                        "narrower. Where the vibration resolves the first frequency (known mass), the "
                        "frequency pins EI whatever the load, and the share is small."
                    )
                )
        rho = m.get("noise_ar1")
        if rho:
            cfg = result.config
            sim = cfg.data.noise_ar1 if (cfg is not None and result.truth is not None) else None
            out += [
                Heading(f"Noise correlation: {name(key)}", 3),
                table(
                    ("", "mean", "90 % interval", "simulated"),
                    [
                        (
                            "AR(1) coefficient",
                            fmt(rho["mean"], ".3f"),
                            fmt_interval(rho["ci90"], 1.0, ".3f"),
                            fmt(sim, ".3f"),
                        )
                    ],
                    "The correlation of the noise between consecutive samples of one sensor "
                    '([model] noise = "ar1"); EI\'s interval accounts for it, and the fit check tests '
                    "the whitened residuals.",
                ),
            ]
    return out


#: a segment is flagged as damaged in the report when P(damaged) reaches this
DAMAGE_FLAG = 0.9


def load_share(post) -> float | None:
    """The share of log EI's posterior variance explained by the load factor (squared correlation of the
    draws' logs), or None without girder draws."""
    g = getattr(post, "girder", None)
    if g is None or g.load_factor is None:
        return None
    a = np.log(np.asarray(post.EI, float).ravel())
    b = np.log(np.asarray(g.load_factor, float).ravel())
    if a.std() == 0 or b.std() == 0:
        return None
    return float(np.corrcoef(a, b)[0, 1] ** 2)


def _scaled(v, f: float) -> float | None:
    return None if v is None else float(v) * f


def sigma_table(summary: dict) -> list[Block]:
    f, unit = sigma_unit(summary["case"])
    truth = summary.get("truth")
    ts = truth.get("sigma") if truth else None
    rows = []
    for key, m in summary["methods"].items():
        s = m["sigma"]
        mean, sd = _scaled(s.get("mean"), f), _scaled(s.get("sd"), f)
        err = f"{100 * (s['mean'] - ts) / ts:+.1f} %" if ts and mean is not None else "n/a"
        rows.append(
            (
                name(key),
                fmt(mean),
                fmt(sd, ".3g"),
                fmt_interval(s["ci90"], f),
                fmt_interval(s["ci95"], f),
                err,
            )
        )
    cap = (
        f"True σ = {ts * f:.4g} {unit}."
        if ts
        else "Clean data: the true σ is 0."
        if truth
        else "Truth unknown (measured data)."
    )
    return [
        Heading("Measurement noise σ"),
        table(
            (
                "method",
                f"mean ({unit})",
                f"sd ({unit})",
                f"90 % interval ({unit})",
                f"95 % interval ({unit})",
                "rel. error",
            ),
            rows,
            cap,
        ),
    ]


def comparison_section(summary: dict) -> list[Block]:
    methods = summary["methods"]
    verdicts = {v.method: v for v in agreement(methods)}
    out: list[Block] = [Heading("Methods side by side and agreement verdict")]
    rows = []
    for key, m in methods.items():
        e = m["EI"]
        width = e["ci90"][1] - e["ci90"][0]
        v = verdicts.get(key)
        if key == REFERENCE_KEY:
            d, r, lab = "0 (reference)", "1 (reference)", "reference"
        elif v is None:
            d, r, lab = "n/a", "n/a", "n/a"
        else:
            d = fmt(v.mean_diff_sd, "+.2f")
            r = fmt(v.sd_ratio, ".2f")
            lab = v.label
        rows.append(
            (
                name(key),
                fmt_EI(e["mean"], ei_decimals(width)),
                fmt_EI_interval(e["ci90"]),
                fmt_EI_sd(width),
                d,
                r,
                lab,
            )
        )
    lo, hi = SD_RATIO_RANGE
    out.append(
        table(
            (
                "method",
                "EI mean (GN m²)",
                "90 % interval",
                "90 % width",
                "Δmean / reference sd",
                "sd / reference sd",
                "verdict",
            ),
            rows,
            f"A PINN posterior is flagged when |Δmean| > {MEAN_TOL_SD:g} reference sd or its sd ratio "
            f"is outside [{lo:g}, {hi:g}].",
        )
    )
    if not verdicts:
        only = "Only the modal reference ran" if REFERENCE_KEY in methods else "No PINN method ran"
        out.append(Paragraph(f"{only}: no PINN posterior to check against the reference."))
    else:
        out.append(BulletList(tuple(v.sentence() for v in verdicts.values())))
    for c in caveats(methods):
        out.append(Alert(c, "info"))
    out += network_lines(methods, verdicts)
    for key, m in methods.items():
        if m.get("member_EI"):
            members = ", ".join(fmt_EI(v) for v in m["member_EI"])
            out.append(Paragraph(f"{name(key)} members' EI (GN m²): {members}."))
    return out


def network_lines(methods: dict, verdicts: dict) -> list[Block]:
    """How much of each PINN's fit its network carries beyond the enrichment (the reference's modal model),
    and where a disagreement with the reference comes from: the reference's model (its fit check says
    misfit) or the PINN."""
    ref_fc = ((methods.get(REFERENCE_KEY) or {}).get("fit_check") or {}).get("verdict")
    lines = []
    for key, m in methods.items():
        share = m.get("network_share")
        if share is None:
            continue
        line = (
            f"{name(key)}: its network carries {100 * share:.2g} % of the fitted response's energy beyond "
            "the enrichment (the reference's modal model)"
        )
        v = verdicts.get(key)
        if v is not None and v.agrees is False:
            line += (
                "; it disagrees with the reference, whose model the fit check finds at odds with the data: "
                "the reference's model is in question"
                if ref_fc == "misfit"
                else "; it disagrees with the reference, whose model fits the data: the disagreement comes "
                "from the PINN"
            )
        elif v is not None and v.agrees and ref_fc == "misfit":
            line += (
                "; it agrees with a reference whose model does not fit these data, so it shares the "
                "reference's error rather than correcting it"
            )
        lines.append(line + ".")
    return [BulletList(tuple(lines))] if lines else []


def figures_section(figures: list[FigureFile], notes: list[str]) -> list[Block]:
    out: list[Block] = [Heading("Figures")]
    out += [Figure(f.title, f.name, f.caption) for f in figures]
    if notes:
        out.append(BulletList(tuple(notes)))
    if not figures and not notes:
        out.append(Paragraph("No figure was drawn."))
    return out


def table5_section(table5s: list[dict], notes: list[str]) -> list[Block]:
    if not table5s and not notes:
        return []
    out: list[Block] = [Heading("Responses against the FE truth (paper Table 5 with uncertainty)")]
    if table5s:
        out.append(
            Paragraph(
                "Posterior predictive mean of the noise-free response against the finite-element truth at "
                f"{table5s[0]['n_points']} interior points of the span. RMSE in mm (deflection u) and kN m "
                "(moment M), with the 90 % interval of the RMSE of single posterior draws; CV = RMSE / "
                "mean|truth| x 100; NMB = sum(pred - truth) / sum(truth) x 100; 'band covers FE': share of "
                "the points where the 90 % credible band contains the truth."
            )
        )
    for t5 in table5s:
        out.append(table(T5_HEADER, table5_rows(t5), name(t5["method"])))
    if notes:
        out.append(BulletList(tuple(notes)))
    return out


def run_document(
    result,
    cfg: Config,
    figures: list[FigureFile] = (),
    figure_notes: list[str] = (),
    table5s: list[dict] = (),
    table5_notes: list[str] = (),
) -> list[Block]:
    """Every block of a run report, in order."""
    from .headline import cached_answer

    s = result.summary
    blocks: list[Block] = [Heading(title(s), 1)]
    if s["methods"]:
        blocks.append(cached_answer(result).block())  # the answer first, above every table
    blocks += alerts(s)
    if result.truth is None:
        blocks.append(Alert("Measured data: the truth and the SNR are unknown.", "info"))
    blocks += ei_table(s)
    blocks += girder_section(result)
    blocks += sigma_table(s)
    blocks += nuisance_section(s)
    blocks += comparison_section(s)
    blocks += figures_section(list(figures), list(figure_notes))
    blocks += diagnostics_section(s)
    blocks += table5_section(list(table5s), list(table5_notes))
    blocks += runtime_section(result)
    blocks += data_section(result, cfg)  # provenance at the end
    blocks += manifest_section(result.manifest, result.truth is not None)
    return blocks
