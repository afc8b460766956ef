"""report.md: the credible-interval report a person reads (display units: GN m^2, mm, microstrain)."""

from __future__ import annotations

from pathlib import Path

from ..config import Config, snr_label

NAMES = {"modal_mcmc": "Modal reference (emcee)", "ensemble": "Deep ensemble", "bpinn": "B-PINN"}


def fmt_EI(v: float) -> str:
    """EI in GN m^2 with 4 significant digits."""
    return f"{v / 1e9:.4f}"


def sigma_unit(case: str) -> tuple[float, str]:
    return (1e3, "mm") if case == "deflection" else (1e6, "µε")


def ei_table(summary: dict) -> list[str]:
    rows = [
        "| method | mean EI (GN m²) | sd (GN m²) | 90 % interval | 95 % interval | rel. error |",
        "|---|---|---|---|---|---|",
    ]
    for key, m in summary["methods"].items():
        e = m["EI"]
        err = f"{e['rel_error_pct']:+.2f} %" if "rel_error_pct" in e else "n/a (truth unknown)"
        rows.append(
            f"| {NAMES.get(key, key)} | {fmt_EI(e['mean'])} | {fmt_EI(e['sd'])} | "
            f"[{fmt_EI(e['ci90'][0])}, {fmt_EI(e['ci90'][1])}] | [{fmt_EI(e['ci95'][0])}, {fmt_EI(e['ci95'][1])}] | {err} |"
        )
    return rows


def sigma_table(summary: dict) -> list[str]:
    f, unit = sigma_unit(summary["case"])
    rows = [f"| method | mean σ ({unit}) | sd ({unit}) | 90 % interval ({unit}) |", "|---|---|---|---|"]
    for key, m in summary["methods"].items():
        s = m["sigma"]
        rows.append(
            f"| {NAMES.get(key, key)} | {s['mean'] * f:.4g} | {s['sd'] * f:.3g} | "
            f"[{s['ci90'][0] * f:.4g}, {s['ci90'][1] * f:.4g}] |"
        )
    return rows


def markdown(result, cfg: Config, figures: list[tuple[str, str]] = (), extra: list[str] = ()) -> str:
    s = result.summary
    truth = s["truth"]
    lines = [f"# bayespinn report: {s['case']} case, SNR {snr_label(s['snr_db']) if truth else 'unknown (measured data)'}", ""]
    if truth is None:
        lines += ["Measured data: the true EI and the SNR are unknown, so no errors are reported.", ""]
    else:
        f, unit = sigma_unit(s["case"])
        lines += [
            f"Synthetic data from the finite-element reference: true EI = {fmt_EI(truth['EI'])} GN m², "
            f"true noise sd σ = {truth['sigma'] * f:.4g} {unit}, seed {s['seed']}, profile `{s['profile']}`.",
            "",
        ]
    lines += ["## Flexural rigidity EI", "", *ei_table(s), "", "## Measurement noise σ", "", *sigma_table(s), ""]
    lines += list(extra)
    diag = [(k, m["diagnostics"]) for k, m in s["methods"].items() if m.get("diagnostics")]
    if diag:
        lines += ["## Diagnostics", "", "| method | R-hat | bulk ESS | tail ESS | converged |", "|---|---|---|---|---|"]
        for k, d in diag:
            def g(name):
                v = d.get(name)
                return "n/a" if v is None else (f"{v:.4f}" if name == "rhat" else f"{v:.0f}")

            lines.append(f"| {NAMES.get(k, k)} | {g('rhat')} | {g('ess_bulk')} | {g('ess_tail')} | {d.get('converged', 'n/a')} |")
        lines.append("")
    lines += ["## Run times", "", "| method | seconds |", "|---|---|"]
    lines += [f"| {NAMES.get(k, k)} | {m['runtime_s']:.1f} |" for k, m in s["methods"].items()]
    lines.append("")
    for title, name in figures:
        lines += [f"### {title}", "", f"![{title}]({name})", ""]
    lines += ["## Configuration", "", "See `manifest.json` for the resolved configuration, seed, versions and timings.", ""]
    return "\n".join(lines)


def write_reports(result, cfg: Config, folder: Path) -> None:
    """Write report.md into the folder."""
    (Path(folder) / "report.md").write_text(markdown(result, cfg), encoding="utf-8")
