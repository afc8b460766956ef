"""The back of a run report: diagnostics, run times, the data's provenance and the manifest (what
produced the report). The answer and the results come first (`content.run_document`); these close it."""

from __future__ import annotations

import json

import numpy as np

from ..config import Config, snr_label
from ..uq.posterior import jsonable
from .document import Block, BulletList, Code, Heading, Paragraph, table
from .units import DISPLAY, fmt, fmt_EI, name, sigma_unit

#: diagnostics with a column of their own
_DIAG_COLUMNS = (
    "rhat",
    "ess_bulk",
    "ess_tail",
    "converged",
    "divergences",
    "tree_depth_saturated",
    "tree_depth_saturated_fraction",
    "max_tree_depth",
)


def _other_diag(d: dict) -> str:
    parts = []
    for k, v in d.items():
        if k in _DIAG_COLUMNS or isinstance(v, dict | list):
            continue
        parts.append(
            f"{k} = {fmt(v) if isinstance(v, int | float) and not isinstance(v, bool) else v}"
        )
    return "; ".join(parts) or "-"


def diagnostics_section(summary: dict) -> list[Block]:
    from ..uq.ensemble_pool import MAX_SCATTER_RATIO  # noqa: PLC0415 - torch only when a report is made

    rows = []
    for key, m in summary["methods"].items():
        d = m.get("diagnostics") or {}
        rows.append(
            (
                name(key),
                fmt(d.get("rhat"), ".4f"),
                fmt(d.get("ess_bulk"), ".0f"),
                fmt(d.get("ess_tail"), ".0f"),
                str(d["divergences"]) if "divergences" in d else "n/a",
                (
                    f"{d['tree_depth_saturated']} (max depth {d.get('max_tree_depth')})"
                    if "tree_depth_saturated" in d
                    else "n/a"
                ),
                str(d.get("converged", "n/a")),
                _other_diag(d),
            )
        )
    out: list[Block] = [
        Heading("Diagnostics"),
        table(
            (
                "method",
                "R-hat",
                "bulk ESS",
                "tail ESS",
                "divergences",
                "trajectories cut at max tree depth",
                "converged",
                "other",
            ),
            rows,
            "R-hat and ESS from ArviZ (rank-normalised split R-hat); divergences and tree depths from NUTS; "
            "converged: R-hat <= 1.01, bulk and tail ESS >= 400, and (NUTS) no divergence and no trajectory "
            "cut at the maximum depth; for the deep ensemble, its members' means within "
            f"{MAX_SCATTER_RATIO:g} x their own widths, a last-layer marginal for every member and no noise "
            "grid cutting off its posterior. n/a where a method has none.",
        ),
    ]
    for key, m in summary["methods"].items():
        d = m.get("diagnostics") or {}
        if d.get("problems"):
            out.append(Paragraph(f"{name(key)} did not converge: {'; '.join(d['problems'])}."))
        for w in d.get("sampler_warnings") or []:
            out.append(Paragraph(f"{name(key)} sampler warning: {w}"))
    for key, m in summary["methods"].items():
        if m.get("variant"):
            out.append(Paragraph(f"{name(key)} variant: {m['variant']}."))
        if m.get("network"):  # the PINN on a real girder (`uq.girder_pinn`)
            out.append(Paragraph(f"{name(key)} network: {m['network']}."))
    return out


def runtime_section(result) -> list[Block]:
    s = result.summary
    rows = [(name(k), f"{m['runtime_s']:.1f}") for k, m in s["methods"].items()]
    total = (result.manifest.get("timings_s") or {}).get("total_s")
    if total is not None:
        rows.append(("whole run (data, all methods)", f"{total:.1f}"))
    return [Heading("Run times"), table(("method", "seconds"), rows)]


def data_section(result, cfg: Config) -> list[Block]:
    s, data, truth = result.summary, result.data, result.truth
    unit_q = "deflection" if s["case"] == "deflection" else "strain"
    f, unit = DISPLAY[unit_q]
    v = np.asarray(data.value, float)
    rows = [
        ("source", result.manifest.get("data", "n/a")),
        ("case", s["case"]),
        ("observations", f"{len(data)} ({', '.join(sorted(set(data.kind.tolist())))})"),
        ("positions x", f"{data.x.min():.3f} to {data.x.max():.3f} m (span {cfg.beam.length:g} m)"),
        (
            "times t",
            f"{data.t.min():.3f} to {data.t.max():.3f} s (crossing T = {cfg.duration:.3f} s)",
        ),
        (
            f"values ({unit})",
            f"min {v.min() * f:.4g}, max {v.max() * f:.4g}, rms {np.sqrt(np.mean(v**2)) * f:.4g}",
        ),
    ]
    if data.is_strain.any():
        names, counts = np.unique(data.sensor[data.is_strain], return_counts=True)
        rows.append(
            (
                "gauges",
                ", ".join(f"{n or 'unnamed'} ({c})" for n, c in zip(names, counts, strict=True)),
            )
        )
    fs, su = sigma_unit(s["case"])
    if truth is None:
        rows += [("true EI", "unknown (measured data)"), ("SNR", "unknown (measured data)")]
    else:
        rows += [
            (
                "nominal SNR",
                "clean (σ = 0)" if s.get("snr_db") is None else f"{snr_label(s['snr_db'])} dB",
            ),
            (
                "realised SNR",
                f"{s['realised_snr_db']:.2f} dB" if s.get("realised_snr_db") is not None else "n/a",
            ),
            ("true EI", f"{fmt_EI(truth['EI'])} GN m²"),
            (
                "true noise sd σ",
                f"{truth['sigma'] * fs:.4g} {su}" if truth.get("sigma") is not None else "n/a",
            ),
        ]
    rows += [("seed", str(s["seed"])), ("profile", f"`{s['profile']}`")]
    out: list[Block] = [Heading("Data"), table(("item", "value"), rows)]
    if truth is None:
        out.append(
            Paragraph(
                "Measured data: **the truth (EI) and the SNR are unknown**, so no errors against "
                "the truth and no truth lines are reported; the intervals are the result."
            )
        )
    return out


def manifest_section(manifest: dict, truth_known: bool = True) -> list[Block]:
    cmd = manifest.get("command")
    cmd_s = " ".join(map(str, cmd)) if isinstance(cmd, list | tuple) else str(cmd)
    items = [
        f"command: `{cmd_s}`",
        f"seed: {manifest.get('seed')}",
        f"SNR: {snr_label(manifest.get('snr_db')) + ('' if manifest.get('snr_db') is None else ' dB') if truth_known else 'unknown (measured data)'}",
        f"data: {manifest.get('data')}",
        f"methods: {', '.join(manifest.get('methods', []))}",
        f"options: {', '.join(f'{k} = {v}' for k, v in (manifest.get('options') or {}).items())}",
        f"device: {manifest.get('device')}",
        f"git commit: {manifest.get('git_commit') or 'n/a'}",
    ]
    versions = manifest.get("versions") or {}
    timings = manifest.get("timings_s") or {}
    out: list[Block] = [
        Heading("Manifest"),
        Paragraph("The same as `manifest.json`: what produced this report."),
        BulletList(tuple(items)),
        Heading("Versions", 3),
        table(("package", "version"), [(k, v or "not installed") for k, v in versions.items()]),
    ]
    if timings:
        out += [
            Heading("Timings", 3),
            table(("step", "seconds"), [(k, fmt(v, ".2f")) for k, v in timings.items()]),
        ]
    out += [
        Heading("Resolved configuration (SI units)", 3),
        Code(json.dumps(jsonable(manifest.get("config", {})), indent=2), "json"),
    ]
    return out
