"""docs/results.md, generated from the committed records: every figure the project states, with its source.

Each figure is a named field of a named record: a committed JSON file and a key path into it (see
`bayespinn.records`), printed at a stated precision, beside the commit, date and machine of the run
that computed it. Nothing is typed by hand: the page is this script's output, and
`tests/test_records.py` regenerates it and compares. A record computed by older code is shown as it is,
with its commit and date. `python studies/rerun.py` re-runs every study the page cites.

    python studies/results_page.py            # writes docs/results.md
    python studies/results_page.py --check    # exit 1 when docs/results.md is not what it would write
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path

from crossings import SD_RATIO_TARGET
from family import HELD_OUT_SEED

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "results.md"
HEADER = ("figure", "value", "record", "key path", "commit", "date", "machine")

NAMES = {"modal_mcmc": "modal reference", "ensemble": "deep ensemble", "bpinn": "B-PINN"}
PINNS = ("ensemble", "bpinn")
KEYS = ("modal_mcmc", *PINNS)


@dataclass(frozen=True)
class Entry:
    """One figure: its name, the record (path from the repository root), the key path and the format."""

    figure: str
    record: str
    key: str
    fmt: str = ".4g"


@dataclass(frozen=True)
class Section:
    title: str
    text: str
    entries: tuple[Entry, ...]


def show(value, fmt: str) -> str:
    """A value as the page prints it: numbers by `fmt`, booleans yes/no, None n/a, text as it is."""
    if value is None:
        return "n/a"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int | float):
        return format(value, fmt)
    return str(value)


# ------------------------------------------------------------------------------------ the figures
COV = "reports/paper/coverage.json"


def _coverage() -> Section:
    out = []
    for k in KEYS:
        for snr in (10, 30):
            row = f"rows[method={k},snr_db={snr}]"
            tag = f"{NAMES[k]}, {snr} dB"
            out += [
                Entry(f"{tag}: datasets", COV, f"{row}.replicates", "d"),
                Entry(f"{tag}: 90 % intervals holding the truth", COV, f"{row}.hits", "d"),
                Entry(f"{tag}: 99 % acceptance region, low", COV, f"{row}.acceptance_99[0]", "d"),
                Entry(f"{tag}: 99 % acceptance region, high", COV, f"{row}.acceptance_99[1]", "d"),
                Entry(f"{tag}: power against 80 % coverage", COV, f"{row}.power_vs_80", ".2f"),
                Entry(f"{tag}: rank-uniformity p", COV, f"{row}.rank_uniformity_p", ".3f"),
                Entry(f"{tag}: converged share", COV, f"{row}.converged_fraction", ".2f"),
                Entry(
                    f"{tag}: hits in the study file",
                    f"reports/paper/coverage/{k}-snr{snr}.json",
                    "hits",
                    "d",
                ),
            ]
            if k == "modal_mcmc":
                continue
            p = f"{row}.paired_reference"
            out += [
                Entry(f"{tag}: reference's hits, same datasets", COV, f"{p}.reference_hits", "d"),
                Entry(f"{tag}: datasets missed by both", COV, f"{p}.misses_of_both", "d"),
                Entry(f"{tag}: mean z against the reference", COV, f"{p}.mean_z", "+.2f"),
                Entry(f"{tag}: sd of z", COV, f"{p}.sd_z", ".2f"),
                Entry(f"{tag}: largest abs z", COV, f"{p}.max_abs_z", ".2f"),
                Entry(f"{tag}: median sd ratio", COV, f"{p}.median_sd_ratio", ".2f"),
                Entry(f"{tag}: smallest sd ratio", COV, f"{p}.sd_ratio_range[0]", ".2f"),
                Entry(f"{tag}: largest sd ratio", COV, f"{p}.sd_ratio_range[1]", ".2f"),
                Entry(
                    f"{tag}: reference's rank-uniformity p, same datasets",
                    COV,
                    f"{p}.reference_rank_uniformity_p",
                    ".3f",
                ),
            ]
    out += _ar1_coverage()
    return Section(
        "Coverage of the true EI",
        "Independent synthetic datasets of the Exeter girder (deflection case); a calibrated 90 % "
        "interval holds the truth in about 90 % of them, inside the binomial 99 % acceptance region. "
        "z = (mean - reference mean) / reference sd on the same dataset; sd ratio = sd / reference sd. "
        "Page: `reports/paper/coverage.md`."
        + (
            " Rows named AR(1) noise: strain records whose noise is AR(1) with coefficient 0.8 at 200 Hz "
            "(`examples/ar1-strain-ar1.toml`), analysed with the AR(1) likelihood, the coefficient's "
            "interval scored beside EI's; page `reports/paper/coverage-ar1-strain-ar1-strain.md`."
            if any(e.record == AR1_COV for e in out)
            else ""
        ),
        tuple(out),
    )


#: coverage under AR(1) noise: the strain case of examples/ar1-strain-ar1.toml, analysed with the AR(1) model
AR1_COV = "reports/paper/coverage-ar1-strain-ar1-strain.json"
#: replicates each AR(1) coverage row is planned with; a row with fewer is labelled partial
AR1_PLANNED = 100


def _ar1_coverage() -> list[Entry]:
    """The AR(1) coverage table's rows, for the methods it has: EI's and the coefficient's hits."""
    try:
        rows = json.loads((ROOT / AR1_COV).read_text(encoding="utf-8"))["rows"]
    except (OSError, ValueError, KeyError):
        return []
    out = []
    for r in rows:
        k, snr = r["method"], f"{r['snr_db']:g}"
        row = f"rows[method={k},snr_db={snr}]"
        tag = f"AR(1) noise (strain, coefficient 0.8), {NAMES[k]}, {snr} dB"
        if r["replicates"] < AR1_PLANNED:  # a study stopped early and written as it stood
            tag += f" (partial: {r['replicates']} of the {AR1_PLANNED} planned datasets)"
        out += [
            Entry(f"{tag}: datasets", AR1_COV, f"{row}.replicates", "d"),
            Entry(f"{tag}: EI intervals holding the truth", AR1_COV, f"{row}.hits", "d"),
            Entry(f"{tag}: 99 % region, low", AR1_COV, f"{row}.acceptance_99[0]", "d"),
            Entry(f"{tag}: 99 % region, high", AR1_COV, f"{row}.acceptance_99[1]", "d"),
            Entry(
                f"{tag}: coefficient intervals holding the truth",
                AR1_COV,
                f"{row}.noise_ar1.hits",
                "d",
            ),
            Entry(
                f"{tag}: coefficient's rank-uniformity p",
                AR1_COV,
                f"{row}.noise_ar1.rank_uniformity_p",
                ".3f",
            ),
        ]
    return out


FAM = "reports/paper/family.json"


def _family_studies() -> list[tuple[str, str, bool]]:
    """(study, label, timed): the development family's studies, then the held-out family's committed ones."""
    dev = [
        ("deflection-snr30", "deflection, 30 dB", True),
        ("deflection-snr10", "deflection, 10 dB", True),
        ("strain-snr30", "strain, 30 dB", True),
    ]
    try:
        have = json.loads((ROOT / FAM).read_text(encoding="utf-8"))["studies"]
    except (OSError, ValueError, KeyError):
        have = {}
    held = [
        (f"heldout-{case}-snr30", f"held-out family, {case}, 30 dB", False)
        for case in ("deflection", "strain")
        if f"heldout-{case}-snr30" in have
    ]
    return dev + held


def _family() -> Section:
    out = []
    for study, label, timed in _family_studies():
        s = f"studies.{study}"
        for k in PINNS:
            c = f"{s}.criteria.{k}"
            tag = f"{label}, {NAMES[k]}"
            out += [
                Entry(f"{tag}: bridges", FAM, f"{c}.bridges", "d"),
                Entry(f"{tag}: mean z", FAM, f"{c}.mean_z", "+.2f"),
                Entry(f"{tag}: sd of z", FAM, f"{c}.sd_z", ".2f"),
                Entry(f"{tag}: largest abs z", FAM, f"{c}.max_abs_z", ".2f"),
                Entry(f"{tag}: median sd ratio", FAM, f"{c}.median_sd_ratio", ".2f"),
                Entry(f"{tag}: share of sd ratios in band", FAM, f"{c}.sd_ratio_in_band", ".2f"),
                Entry(
                    f"{tag}: z against alpha, Spearman rho", FAM, f"{c}.trend.spearman_rho", "+.2f"
                ),
                Entry(f"{tag}: z against alpha, p", FAM, f"{c}.trend.p_value", ".3f"),
            ]
        if not timed:
            continue
        out.append(
            Entry(
                f"{label}: slowest bridge against the Exeter 20 dB run",
                FAM,
                f"{s}.timing.max_ratio",
                ".2f",
            )
        )
    return Section(
        "A family of bridges",
        "Seeded girders of 10-40 m with 1-5 axles (`bayespinn.family`), one dataset each; each PINN "
        "posterior against the reference on the same data. Bands: |mean z| <= 0.35, sd of z <= 1.3, "
        "|z| <= 3, sd ratio in [0.67, 1.5] on at least 85 % of bridges. Rows without a family named are "
        "the development family (seed 0), on which the methods' choices were made and re-run; the "
        f"held-out family (seed {HELD_OUT_SEED}, drawn once) was never used to choose anything, and is what a "
        "claim about unseen bridges rests on. Page: `reports/paper/family.md`.",
        tuple(out),
    )


def _girders() -> Section:
    out = []
    studies = {
        "damaged-girder-deflection-snr30": [f'"EI_segments[{i}]"' for i in range(5)] + ["EI"],
        "damaged-girder-strain-snr30": [f'"EI_segments[{i}]"' for i in range(5)] + ["EI"],
        "bearings-deflection-snr30": [
            "EI",
            '"rotational_stiffness[0]"',
            '"rotational_stiffness[1]"',
        ],
        "uncertain-load-deflection-snr40": ["EI", "load_factor"],
    }
    for study, params in studies.items():
        rec = f"reports/paper/girders/{study}.json"
        out.append(Entry(f"{study}: datasets", rec, "summary.replicates", "d"))
        out.append(Entry(f"{study}: converged", rec, "summary.converged", "d"))
        for p in params:
            name = p.strip('"')
            out.append(
                Entry(f"{study}: {name} held its truth", rec, f"summary.coverage.{p}.hits", "d")
            )
        if "damaged" in study:
            out.append(
                Entry(
                    f"{study}: smallest P(damaged) of the damaged segment",
                    rec,
                    "summary.p_damaged_min[3]",
                    ".3f",
                )
            )
    for case in ("deflection", "strain"):
        rec = f"reports/paper/girders/smooth-loss-{case}-snr30.json"
        study = f"smooth loss, {case}"
        out += [
            Entry(f"{study}: datasets", rec, "summary.replicates", "d"),
            Entry(f"{study}: converged", rec, "summary.converged", "d"),
            Entry(
                f"{study}: span-equivalent EI held its truth", rec, "summary.coverage.EI.hits", "d"
            ),
            Entry(
                f"{study}: EI(x) band held the truth over 90 % of the span",
                rec,
                "summary.field.band_holds",
                "d",
            ),
            Entry(
                f"{study}: share of the span held, median",
                rec,
                "summary.field.coverage_median",
                ".2f",
            ),
            Entry(f"{study}: deepest point within 1 m", rec, "summary.field.deepest_within", "d"),
            Entry(
                f"{study}: deepest point's offset, median [m]",
                rec,
                "summary.field.offset_median_m",
                ".2f",
            ),
            Entry(f"{study}: fit check said fits", rec, "summary.fit_check.fits", "d"),
            Entry(f"{study}: median time per dataset [s]", rec, "summary.median_time_s", ".0f"),
        ]
    rec = "reports/paper/girder_pinns/damaged-girder-deflection-snr30.json"
    out.append(Entry("damaged girder, PINN study: datasets", rec, "summary.replicates", "d"))
    for k in KEYS:
        m = f"summary.methods.{k}"
        for i in range(5):
            out.append(
                Entry(
                    f"damaged girder, {NAMES[k]}: segment {i + 1} held its truth",
                    rec,
                    f'{m}.coverage."EI_segments[{i}]".hits',
                    "d",
                )
            )
        out.append(Entry(f"damaged girder, {NAMES[k]}: converged", rec, f"{m}.converged", "d"))
        if k == "modal_mcmc":
            continue
        for i in range(5):
            out.append(
                Entry(
                    f"damaged girder, {NAMES[k]}: segment {i + 1}, largest abs z",
                    rec,
                    f"{m}.z_max_abs[{i}]",
                    ".2f",
                )
            )
        out.append(
            Entry(
                f"damaged girder, {NAMES[k]}: damaged segment's median sd ratio",
                rec,
                f"{m}.sd_ratio_median[3]",
                ".2f",
            )
        )
        out.append(
            Entry(
                f"damaged girder, {NAMES[k]}: median time per dataset [s]",
                rec,
                f"{m}.median_time_s",
                ".0f",
            )
        )
    for case in (
        "deflection",
        "strain",
    ):  # the deep ensemble beside the reference on the smooth loss
        rec = f"reports/paper/girder_pinns/smooth-loss-{case}-snr30.json"
        study = f"smooth loss, {case}, PINN study"
        out += [
            Entry(f"{study}: datasets", rec, "summary.replicates", "d"),
            Entry(f"{study}: datasets planned", rec, "replicates_asked", "d"),
        ]
        for k in ("modal_mcmc", "ensemble"):
            m = f"summary.methods.{k}"
            who = f"{study}, {NAMES[k]}"
            out += [
                Entry(
                    f"{who}: EI(x) band held the truth over 90 % of the span",
                    rec,
                    f"{m}.field.band_holds",
                    "d",
                ),
                Entry(f"{who}: deepest point within 1 m", rec, f"{m}.field.deepest_within", "d"),
                Entry(
                    f"{who}: span-equivalent EI held its truth", rec, f"{m}.coverage.EI.hits", "d"
                ),
                Entry(f"{who}: median time per dataset [s]", rec, f"{m}.median_time_s", ".0f"),
            ]
        out.append(
            Entry(
                f"{study}, {NAMES['ensemble']}: network share, median",
                rec,
                "summary.methods.ensemble.network_share_median",
                ".2g",
            )
        )
    return Section(
        "Real girders: EI per segment, bearings, uncertain loads, a smooth loss",
        "Coverage over independent datasets of the girders in `examples/` (the reference, and the PINN "
        "methods beside it on the damaged girder); the damaged segment is the fourth of five. The smooth "
        "loss (30 % deep, 1.5 m wide at 6.1 m, on no segment edge; the finite-element simulator's 200 "
        "segments) is analysed as a smooth EI field: its band of EI(x) against the true EI(x), by the "
        "reference and, in the PINN study, by the deep ensemble beside it on the same datasets (a PINN "
        "study with fewer datasets than planned is partial). Pages: "
        "`reports/paper/girders.md`, `reports/paper/girder_pinns.md`.",
        tuple(out),
    )


def _fitcheck() -> Section:
    out = []
    for study in (
        "exeter-deflection-snr10_20_30_40",
        "exeter-strain-snr10_20_30_40",
        "bearings-as-pinned-deflection-snr30",
        "damaged-as-uniform-strain-snr30",
        "ar1-strain-strain-snr20",
        "ar1-strain-ar1-strain-snr20",
    ):
        rec = f"reports/paper/fitcheck/{study}.json"
        out += [
            Entry(f"{study}: datasets", rec, "summary.replicates", "d"),
            Entry(f"{study}: expected verdict", rec, "expect", ""),
            Entry(f"{study}: datasets given the expected verdict", rec, "summary.expected", "d"),
            Entry(
                f"{study}: 90 % EI intervals holding the truth",
                rec,
                "summary.coverage.EI.hits",
                "d",
            ),
        ]
    for rec in _calibrations():
        name = Path(rec).stem
        out += [
            Entry(f"{name}: well-specified datasets", rec, "summary.replicates", "d"),
            Entry(f"{name}: false alarms", rec, "summary.false_alarms", "d"),
            Entry(f"{name}: binomial region, lower", rec, "summary.region[0]", "d"),
            Entry(f"{name}: binomial region, upper", rec, "summary.region[1]", "d"),
            Entry(f"{name}: inside the region", rec, "summary.inside", ""),
        ]
    return Section(
        "The fit check",
        "The modal reference's fit check over independent datasets: 'fits' expected on data the model "
        "describes, 'misfit' on data it does not (stiff bearings analysed as pinned, a damaged segment "
        "analysed as uniform, AR(1) noise analysed as white). Then its false alarms per method, case and "
        "SNR on datasets the model describes (`studies/fitcheck_calibration.py`), against the two-sided "
        "binomial region of the stated rate at the record's false-failure rate; a record with fewer "
        "datasets than asked for is a partial run. Pages: `reports/paper/fitcheck.md`, "
        "`reports/paper/fitcheck/calibration.md`.",
        tuple(out),
    )


def _calibrations() -> list[str]:
    """The fit check's false-alarm records (`studies/fitcheck_calibration.py`), sorted by name."""
    folder = ROOT / "reports" / "paper" / "fitcheck"
    return [str(p.relative_to(ROOT)) for p in sorted(folder.glob("calibration-*.json"))]


CROSSINGS = "reports/paper/crossings/study.json"


def _crossings() -> Section:
    """The realistic-crossings study (`studies/crossings.py`): the modal reference against the truth on
    crossings by the independent simulator, with the uncertain quantities declared and under today's
    model."""
    doc = json.loads((ROOT / CROSSINGS).read_text(encoding="utf-8"))
    out = [
        Entry("crossings planned", CROSSINGS, "summary.planned", "d"),
        Entry("crossings analysed", CROSSINGS, "summary.done", "d"),
    ]
    for a, label in (("declared", "declared"), ("today", "today's model")):
        k = f"summary.{a}"
        out += [
            Entry(f"{label}: 90 % EI intervals holding the truth", CROSSINGS, f"{k}.hits", "d"),
            Entry(f"{label}: 99 % acceptance region, low", CROSSINGS, f"{k}.region[0]", "d"),
            Entry(f"{label}: 99 % acceptance region, high", CROSSINGS, f"{k}.region[1]", "d"),
            Entry(f"{label}: fit check says fits", CROSSINGS, f"{k}.fits", "d"),
            Entry(f"{label}: fit check says misfit", CROSSINGS, f"{k}.misfit", "d"),
            Entry(f"{label}: mean z against the truth", CROSSINGS, f"{k}.z.mean", "+.2f"),
            Entry(f"{label}: sd of z", CROSSINGS, f"{k}.z.sd", ".2f"),
            Entry(f"{label}: converged", CROSSINGS, f"{k}.converged", "d"),
            Entry(f"{label}: median time [s]", CROSSINGS, f"{k}.runtime_s.median", ".0f"),
        ]
    if "importance_sampled" in doc["summary"].get("declared", {}):
        out.append(
            Entry(
                "declared: exact posterior importance-sampled (linearisation rejected)",
                CROSSINGS,
                "summary.declared.importance_sampled",
                "d",
            )
        )
    if (doc["summary"].get("declared_nuisances") or {}).get("n", 0) >= 2:
        k = "summary.declared_nuisances"
        out += [
            Entry("declared: rms z of EI", CROSSINGS, f"{k}.rms_z.EI", ".2f"),
            Entry("declared: rms z of the speed", CROSSINGS, f"{k}.rms_z.speed", ".2f"),
            Entry("declared: rms z of the entry time", CROSSINGS, f"{k}.rms_z.entry_time", ".2f"),
            Entry(
                "declared: correlation of EI's z with the speed's",
                CROSSINGS,
                f"{k}.corr_EI_speed",
                "+.2f",
            ),  # fmt: skip
            Entry(
                "declared: crossings whose speed holds the truth within 2 sd",
                CROSSINGS,
                f"{k}.speed_within",
                "d",
            ),  # fmt: skip
            Entry(
                "declared: rms z of EI on those crossings",
                CROSSINGS,
                f"{k}.EI_rms_z_speed_within",
                ".2f",
            ),  # fmt: skip
            Entry(
                "declared: rms z of EI on the others",
                CROSSINGS,
                f"{k}.EI_rms_z_speed_beyond",
                ".2f",
            ),  # fmt: skip
        ]
    if doc.get("exeter_check"):
        out += [
            Entry(
                "nothing declared: exeter-snr20-seed11's modal EI shift [record sd]",
                CROSSINGS,
                "exeter_check.shift_in_record_sd",
                "+.3f",
            ),
            Entry("nothing declared: within 0.3 record sd", CROSSINGS, "exeter_check.within", ""),
        ]
    for key in sorted(k for k in doc if k.startswith("joint") and doc[k]):
        who = f"joint analysis, girder {doc[key].get('girder', 0)}"
        out += [
            Entry(f"{who}: crossings", CROSSINGS, f"{key}.crossings", "d"),
            Entry(f"{who}: EI sd / one crossing's", CROSSINGS, f"{key}.sd_ratio", ".3f"),
            Entry(
                f"{who}: at most {SD_RATIO_TARGET:g}", CROSSINGS, f"{key}.sd_ratio_target_met", ""
            ),
            Entry(f"{who}: interval holds the truth", CROSSINGS, f"{key}.hit", ""),
            Entry(f"{who}: z against the truth", CROSSINGS, f"{key}.z", "+.2f"),
            Entry(f"{who}: converged", CROSSINGS, f"{key}.converged", ""),
            Entry(f"{who}: time [s]", CROSSINGS, f"{key}.runtime_s", ".0f"),
        ]
    return Section(
        "Realistic crossings",
        "Crossings by the independent simulator (`bayespinn.vbi`: each axle of the strain case's truck a "
        "sprung mass, ISO 8608 class A and B roads, beam damping, the recording starting before the "
        "entry; the Exeter girder and two bridges of a family, 30 dB on the four gauges), analysed by the "
        "modal reference: declared (speed and entry time stated within +-1.5 % and +-0.1 s with their "
        "sds, damping inferred, fluctuating axle forces on a sprung vehicle model) and under today's "
        "model (nothing declared). A calibrated 90 % interval holds the truth inside the binomial 99 % "
        "region. Page: `reports/paper/crossings.md`.",
        tuple(out),
    )


def _tables() -> Section:
    out = []
    levels = (("null", "clean"), ("10", "10 dB"), ("20", "20 dB"), ("30", "30 dB"), ("40", "40 dB"))
    for k in KEYS:
        for snr, label in levels:
            row = f"rows[method={k},snr_db={snr}]"
            tag = f"Table 4, {NAMES[k]}, {label}"
            out += [
                Entry(
                    f"{tag}: EI mean [N m^2]", "reports/paper/table4.json", f"{row}.EI.mean", ".5g"
                ),
                Entry(f"{tag}: 90 % low", "reports/paper/table4.json", f"{row}.EI.ci90[0]", ".5g"),
                Entry(f"{tag}: 90 % high", "reports/paper/table4.json", f"{row}.EI.ci90[1]", ".5g"),
                Entry(
                    f"{tag}: error [%]",
                    "reports/paper/table4.json",
                    f"{row}.EI.rel_error_pct",
                    "+.2f",
                ),
            ]
    for k in KEYS:
        for snr, label in levels:
            row = f"rows[method={k},snr_db={snr}]"
            out.append(
                Entry(
                    f"Table 5, {NAMES[k]}, {label}: deflection band coverage",
                    "reports/paper/table5.json",
                    f"{row}.band_coverage_mean.deflection",
                    ".3f",
                )
            )
    for scen, label in (("data", "gauge S2 data"), ("none", "no data")):
        for k in KEYS:
            row = f"rows[scenario={scen},method={k}]"
            tag = f"Table 6, {label}, {NAMES[k]}"
            out += [
                Entry(
                    f"{tag}: EI mean [N m^2]", "reports/paper/table6.json", f"{row}.EI.mean", ".5g"
                ),
                Entry(f"{tag}: 90 % low", "reports/paper/table6.json", f"{row}.EI.ci90[0]", ".5g"),
                Entry(f"{tag}: 90 % high", "reports/paper/table6.json", f"{row}.EI.ci90[1]", ".5g"),
            ]
    return Section(
        "The paper's tables with intervals",
        "Tables 4-6 of the Exeter study re-done with posteriors: EI at each SNR (deflection), the "
        "posterior bands' coverage of the true deflection, and the strain case with and without gauge "
        "data. Pages: `reports/paper/table4.md`, `table5.md`, `table6.md`.",
        tuple(out),
    )


#: the single runs: (record folder, what it shows, extra (figure, key path, format) beyond each method's EI)
RUNS = (
    ("exeter-snr10-seed0", "the quick start, `bayespinn run --snr 10`", ()),
    ("exeter-snr10-seed0-xeon", "the quick start on another processor", ()),
    (
        "exeter-snr10-seed0-before-halving",
        "the quick start before the fast profile was shortened",
        (),
    ),
    ("exeter-snr20-seed11", "the Exeter girder at 20 dB", ()),
    ("exeter-snr20-seed11-amd", "the same command on another processor", ()),
    ("exeter-snr10-seed5-modal", "the modal reference's span profiles (README figure)", ()),
    ("girder20m-snr30-seed11", "a 20 m girder under a two-axle vehicle", ()),
    (
        "damaged-girder-snr30-seed0",
        "a damaged girder, reference",
        (
            ("damaged segment, 90 % low", "methods.modal_mcmc.EI_segments[3].ci90[0]", ".4g"),
            ("damaged segment, 90 % high", "methods.modal_mcmc.EI_segments[3].ci90[1]", ".4g"),
            ("damaged segment, P(damaged)", "methods.modal_mcmc.EI_segments[3].p_damaged", ".2f"),
        ),
    ),
    (
        "damaged-girder-strain-snr30-seed0",
        "a damaged girder seen by four strain gauges",
        (
            ("damaged segment, 90 % low", "methods.modal_mcmc.EI_segments[3].ci90[0]", ".4g"),
            ("damaged segment, 90 % high", "methods.modal_mcmc.EI_segments[3].ci90[1]", ".4g"),
            (
                "ungauged first segment, P(damaged)",
                "methods.modal_mcmc.EI_segments[0].p_damaged",
                ".3f",
            ),
        ),
    ),
    (
        "damaged-girder-all-snr30-seed0",
        "a damaged girder, every method",
        tuple(
            (
                f"{NAMES[k]}: damaged segment, 90 % {w}",
                f"methods.{k}.EI_segments[3].ci90[{i}]",
                ".4g",
            )
            for k in KEYS
            for i, w in ((0, "low"), (1, "high"))
        )
        + (("B-PINN: divergent transitions", "methods.bpinn.diagnostics.divergences", "d"),),
    ),
    (
        "bearings-snr30-seed0",
        "bearings with rotational springs, reference",
        (
            (
                "left spring, 90 % low [N m/rad]",
                "methods.modal_mcmc.rotational_stiffness[0].ci90[0]",
                ".4g",
            ),
            (
                "left spring, 90 % high [N m/rad]",
                "methods.modal_mcmc.rotational_stiffness[0].ci90[1]",
                ".4g",
            ),
        ),
    ),
    ("bearings-all-snr30-seed0", "bearings with rotational springs, every method", ()),
    ("bearings-as-pinned-snr30-seed0", "the same bearings analysed as pinned", ()),
    ("bearings-as-pinned-all-snr30-seed0", "the same, every method", ()),
    ("damaged-as-uniform-strain-snr30-seed0", "a damaged girder analysed as uniform", ()),
    (
        "uncertain-load-snr40-seed0",
        "axle loads known to 5 %",
        (
            ("load factor, 90 % low", "methods.modal_mcmc.load_factor.ci90[0]", ".4f"),
            ("load factor, 90 % high", "methods.modal_mcmc.load_factor.ci90[1]", ".4f"),
            ("true load factor", "truth.load_factor", ".4f"),
        ),
    ),
    (
        "ar1-strain-snr20-seed0",
        "AR(1) noise analysed with the AR(1) likelihood",
        (
            ("AR(1) coefficient, 90 % low", "methods.modal_mcmc.noise_ar1.ci90[0]", ".3f"),
            ("AR(1) coefficient, 90 % high", "methods.modal_mcmc.noise_ar1.ci90[1]", ".3f"),
        ),
    ),
    ("ar1-strain-iid-snr20-seed0", "the same data analysed as white noise", ()),
    ("ar1-strain-all-snr20-seed0", "AR(1) noise, every method", ()),
    (
        "damaged-girder-ar1-snr20-seed0",
        "a damaged girder under AR(1) gauge noise, the reference and the deep ensemble",
        tuple(
            (f"{NAMES[k]}: {what}, 90 % {w}", f"methods.{k}.{key}.ci90[{i}]", fmt)
            for k in ("modal_mcmc", "ensemble")
            for what, key, fmt in (
                ("AR(1) coefficient", "noise_ar1", ".3f"),
                ("damaged segment [N m^2]", "EI_segments[3]", ".4g"),
            )
            for i, w in ((0, "low"), (1, "high"))
        ),
    ),
    (
        "bpinn-two-points-smoke",
        "a dataset built to make NUTS struggle",
        (
            ("B-PINN: divergent transitions", "methods.bpinn.diagnostics.divergences", "d"),
            ("B-PINN: R-hat", "methods.bpinn.diagnostics.rhat", ".2f"),
            ("B-PINN: bulk ESS", "methods.bpinn.diagnostics.ess_bulk", ".0f"),
            ("B-PINN: converged", "methods.bpinn.diagnostics.converged", ""),
        ),
    ),
)


def _runs() -> Section:
    out = []
    for name, _, extra in RUNS:
        rec = f"reports/records/{name}/summary.json"
        summary = json.loads((ROOT / rec).read_text(encoding="utf-8"))
        for k in [k for k in KEYS if k in summary["methods"]]:
            m = f"methods.{k}"
            out += [
                Entry(f"{name}, {NAMES[k]}: EI mean [N m^2]", rec, f"{m}.EI.mean", ".5g"),
                Entry(f"{name}, {NAMES[k]}: EI 90 % low", rec, f"{m}.EI.ci90[0]", ".5g"),
                Entry(f"{name}, {NAMES[k]}: EI 90 % high", rec, f"{m}.EI.ci90[1]", ".5g"),
                Entry(f"{name}, {NAMES[k]}: time [s]", rec, f"{m}.runtime_s", ".1f"),
            ]
            if "fit_check" in summary["methods"][k]:  # runs older than the fit check have none
                out.append(
                    Entry(f"{name}, {NAMES[k]}: fit check", rec, f"{m}.fit_check.verdict", "")
                )
            if k in (summary.get("agreement") or {}):
                a = f"agreement.{k}"
                out += [
                    Entry(
                        f"{name}, {NAMES[k]}: mean - reference [ref. sd]",
                        rec,
                        f"{a}.mean_diff_sd",
                        "+.2f",
                    ),
                    Entry(f"{name}, {NAMES[k]}: sd / reference sd", rec, f"{a}.sd_ratio", ".2f"),
                ]
        out += [Entry(f"{name}: {fig}", rec, key, fmt) for fig, key, fmt in extra]
        out.append(
            Entry(
                f"{name}: analysis time [s]",
                f"reports/records/{name}/manifest.json",
                "timings_s.total_s",
                ".1f",
            )
        )
    return Section(
        "Single runs",
        "Run folders kept under `reports/records/` (their summary.json and manifest.json): "
        + "; ".join(f"`{n}`: {what}" for n, what, _ in RUNS)
        + ". A PINN method's agreement is judged against the reference of the same run.",
        tuple(out),
    )


def sections() -> list[Section]:
    """Every section of the page, in order."""
    return [_coverage(), _family(), _girders(), _crossings(), _fitcheck(), _tables(), _runs()]


def entries() -> list[Entry]:
    return [e for s in sections() for e in s.entries]


def records() -> list[str]:
    """Every record the page cites (paths from the repository root), in order of first citation."""
    return list(dict.fromkeys(e.record for e in entries()))


# ------------------------------------------------------------------------------------ the page
INTRO = (
    "# Results\n\n"
    "Generated by `python studies/results_page.py` from the committed records; do not edit by hand. "
    "Each figure is one field of one record: a JSON file under `reports/` and the key path to the field "
    "(`a.b[0]` indexes a list, `rows[method=ensemble,snr_db=30]` picks the one row with those fields, a "
    "quoted step is one field name). Commit, date and machine are those of the run that computed the "
    "record (for older run folders, which did not record a date, the date of their commit). A figure "
    "computed by older code stays as it was measured: its commit says which code. "
    "`python studies/rerun.py` re-runs every study cited here and regenerates this page; "
    "`python studies/rerun.py --dry-run` lists them with their expected times.\n"
)


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def row_of(e: Entry, root: Path = ROOT) -> tuple[str, ...]:
    """The page's row of one figure: its value read from the record, and the record's provenance."""
    from bayespinn.records import get, load, provenance_of

    value = show(get(load(root / e.record), e.key), e.fmt)
    prov = provenance_of(e.record, e.key, root)
    commit = prov["commit"] + (f"; replicates: {prov['replicates']}" if prov["replicates"] else "")
    return (e.figure, value, f"`{e.record}`", f"`{e.key}`", commit, prov["date"], prov["machine"])


def render(secs: list[Section] | None = None, root: Path = ROOT) -> str:
    """The page's text (deterministic: a function of the records and of git's commit dates)."""
    parts = [INTRO]
    for s in secs if secs is not None else sections():
        parts.append(f"\n## {s.title}\n\n{s.text}\n\n")
        parts.append("| " + " | ".join(HEADER) + " |\n")
        parts.append("|" + "---|" * len(HEADER) + "\n")
        for e in s.entries:
            parts.append("| " + " | ".join(_cell(c) for c in row_of(e, root)) + " |\n")
    return "".join(parts)


def table_rows(text: str) -> list[tuple[str, ...]]:
    """The figure rows of a page's tables (header and rule rows left out), cells unescaped."""
    out = []
    for line in text.splitlines():
        if not line.startswith("| ") or line.startswith("| figure |"):
            continue
        cells = [c.strip().replace("\\|", "|") for c in line.strip()[2:-2].split(" | ")]
        out.append(tuple(cells))
    return out


def problems(text: str, secs: list[Section] | None = None, root: Path = ROOT) -> list[str]:
    """What is wrong with a page's figures, row by row: a figure the spec does not name, a record or key
    path other than the spec's, or a value other than the record's field at the spec's precision."""
    spec = {e.figure: e for s in (secs if secs is not None else sections()) for e in s.entries}
    out, seen = [], set()
    for cells in table_rows(text):
        figure, value, record, key = cells[0], cells[1], cells[2].strip("`"), cells[3].strip("`")
        e = spec.get(figure)
        if e is None:
            out.append(f"{figure}: not a figure of the page's spec")
            continue
        seen.add(figure)
        if (record, key) != (e.record, e.key):
            out.append(f"{figure}: cites {record} :: {key}, the spec {e.record} :: {e.key}")
            continue
        want = row_of(e, root)[1]
        if value != want:
            out.append(f"{figure}: shows {value}, {e.record} :: {e.key} holds {want}")
    out += [f"{f}: missing from the page" for f in spec if f not in seen]
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=str(PAGE), help="the page to write (default docs/results.md)")
    p.add_argument(
        "--check",
        action="store_true",
        help="write nothing: exit 1 (naming each figure) when the page differs from what would be written",
    )
    args = p.parse_args(sys.argv[1:] if argv is None else argv)
    out = Path(args.out)
    text = render()
    if args.check:
        have = out.read_text(encoding="utf-8") if out.is_file() else ""
        bad = problems(have) if have != text else []
        for b in bad:
            print(b, file=sys.stderr)
        if have != text:
            print(f"{out} is not what `python studies/results_page.py` writes", file=sys.stderr)
            return 1
        return 0
    out.parent.mkdir(parents=True, exist_ok=True)
    from bayespinn.data.measurements import atomic_write_text

    atomic_write_text(out, text)
    print(f"wrote {out} ({len(table_rows(text))} figures)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
