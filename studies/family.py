"""Honest on bridges it was never tuned on: each method against the reference posterior on a family of bridges.

Bridge i of the family (`bayespinn.family`: spans 10-40 m, first frequencies 60/L-180/L Hz, 1-5 axles,
speed parameter alpha = v / (2 f1 L) from 0.015 to 0.2) gets one synthetic dataset at the given SNR; the
modal reference and the PINN methods run on it; each PINN posterior is scored against the reference one
on the same data: z = (mean - reference mean) / reference sd, the sd ratio, sigma's z, R-hat/ESS, time.
Over the bridges: mean and sd of z, max |z|, the share of sd ratios in [0.67, 1.5] and of sigma within 2
reference sds, each against the family's bands, and the table split at alpha = 0.04 with the rank
correlation of z with alpha (a drift as the dynamics grow).

One study per case and SNR in <out>/family/<case>-snr<S>.json, rewritten atomically after every bridge: an
interrupted study resumes from it (each bridge's record names the commit that computed it), and
`--bridges` can grow a study over several sessions. <out>/family.md and family.json gather every study
there.

    python studies/family.py --bridges 24 --snr 30 --out reports/paper
    python studies/family.py --bridges 12 --snr 10 --out reports/paper
    python studies/family.py --bridges 6 --snr 30 --case strain --out reports/paper
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import sys
import time
from pathlib import Path

import common as c

from bayespinn import family, methods
from bayespinn.config import CASES, preset, snr_label
from bayespinn.errors import InputError
from bayespinn.options import int_at_least
from bayespinn.provenance import commits
from bayespinn.report.document import Alert, BulletList, Heading, Paragraph, table
from bayespinn.report.units import name

log = logging.getLogger("studies.family")

STUDY_SCHEMA = "bayespinn.studies.family-study/1"
SCHEMA = "bayespinn.studies.family/1"
#: the timing yardstick: the Exeter girder's run at 20 dB, seed 11 (deflection)
TIME_REFERENCE = {"case": "deflection", "snr_db": 20.0, "seed": 11}
TIME_RATIO_MAX = 2.0
#: the development and held-out families' seeds (`bayespinn.family`), re-exported for the other scripts
DEVELOPMENT_SEED, HELD_OUT_SEED = family.DEVELOPMENT_SEED, family.HELD_OUT_SEED


def family_name(seed: int) -> str:
    if seed == DEVELOPMENT_SEED:
        return "development family"
    if seed == HELD_OUT_SEED:
        return "held-out family"
    return f"family of seed {seed}"


def study_stem(case: str, snr: float, seed: int) -> str:
    """The study file's name: the development family's keep their names, other families' are prefixed."""
    stem = f"{case}-snr{snr_label(snr)}"
    if seed == DEVELOPMENT_SEED:
        return stem
    return ("heldout-" if seed == HELD_OUT_SEED else f"seed{seed}-") + stem


def fingerprint(args, snr, methods_run: list[str]) -> str:
    """What decides every bridge's numbers but the bridge itself and the code: case, SNR, seeds, options."""
    spec = {
        "case": args.case,
        "snr_db": snr,
        "family_seed": args.family_seed,
        "seed": args.seed,
        "profile": args.profile,
        "members": args.members,
        "noise_prior": args.noise_prior,
        "bpinn_variant": args.bpinn_variant,
        "device": args.device,
        "methods": methods_run,
    }
    return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:16]


def load_study(path: Path, key: str) -> dict:
    """The study at path when it is this study (same fingerprint), else a new empty one."""
    if path.is_file():
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as exc:
            log.warning("warning: %s is unreadable (%s): starting the study afresh", path, exc)
            doc = {}
        if doc.get("schema") == STUDY_SCHEMA and doc.get("fingerprint") == key:
            return doc
        if doc:
            log.warning("warning: %s is another study (options differ): starting afresh", path)
    return {"schema": STUDY_SCHEMA, "fingerprint": key, "records": [], "runs": []}


def run_time_reference(args, opts, names) -> dict:
    """The Exeter girder's 20 dB run (seed 11) with the same methods and options: the yardstick of time."""
    from bayespinn.data.synthetic import simulate
    from bayespinn.pipeline import analyse

    cfg = preset(TIME_REFERENCE["case"])
    t0 = time.perf_counter()
    data = simulate(cfg, TIME_REFERENCE["snr_db"], TIME_REFERENCE["seed"])
    res = analyse(
        data,
        cfg,
        methods=names,
        seed=TIME_REFERENCE["seed"],
        snr_db=TIME_REFERENCE["snr_db"],
        opts=dataclasses.replace(opts, snr_db=TIME_REFERENCE["snr_db"]),
    )
    return {
        **TIME_REFERENCE,
        "time_s": time.perf_counter() - t0,
        "runtime_s": {k: p.runtime_s for k, p in res.posteriors.items()},
        **c.replicate_provenance(),
    }


def study(args, argv, snr, names) -> dict:
    keys = [methods.get(n).key for n in names]
    path = Path(args.out) / "family" / f"{study_stem(args.case, snr, args.family_seed)}.json"
    key = fingerprint(args, snr, names)
    doc = load_study(path, key)
    have = {r["bridge"]["index"]: r for r in doc["records"]}
    opts = dataclasses.replace(c.run_options(args, snr), progress=not args.quiet)
    doc.update(
        case=args.case,
        snr_db=snr,
        family_seed=args.family_seed,
        seed=args.seed,
        profile=args.profile,
        methods=keys,
        reference=methods.reference_key(),
    )
    prov = c.provenance(__file__, argv, args, methods=keys, snr_db=snr)
    doc["runs"] = [*doc.get("runs", []), prov][-10:]
    tr = doc.get("time_reference")
    if args.time_reference and not tr:
        log.info("family: timing the Exeter girder's 20 dB run (seed 11) as the yardstick")
        doc["time_reference"] = run_time_reference(args, opts, names)
        c.write_json(path, doc)
    wanted = range(args.start, args.start + args.bridges)
    # the bridges asked for so far (a study grown over sessions asks for more): the page says partial
    # while fewer are done
    doc["planned"] = sorted(set(doc.get("planned") or []) | set(wanted))
    c.write_json(path, doc)
    for n_done, i in enumerate(wanted):
        if i in have:
            continue
        b = family.bridge(i, args.family_seed, args.case)
        log.info(
            "family: bridge %d (%d of %d): L %.1f m, f1 %.2f Hz, alpha %.3f, %d axles",
            i,
            n_done + 1,
            len(wanted),
            b.cfg.beam.length,
            b.f1_hz,
            b.alpha,
            len(b.cfg.vehicle.axles),
        )
        rec = family.run_bridge(b, snr, methods=names, seed=args.seed, opts=opts)
        have[i] = rec
        doc["records"] = [have[k] for k in sorted(have)]
        c.write_json(path, doc)  # atomic: an interruption loses at most the bridge under way
        log.info(
            "family: bridge %d done in %.0f s: %s",
            i,
            rec["time_s"],
            ", ".join(
                f"{k} z {r['z']:+.2f} sd ratio {r['sd_ratio']:.2f}"
                for k, r in rec["methods"].items()
                if "z" in r
            ),
        )
    doc["records"] = [have[k] for k in sorted(have)]
    c.write_json(path, doc)
    return doc


# ------------------------------------------------------------------------------------------ the page
def summarise(doc: dict) -> dict:
    """A study's criteria per PINN method, the commits its bridges were computed at, and its times."""
    ref = doc["reference"]
    keys = [k for k in doc["methods"] if k != ref]
    out = {
        k: {
            **family.criteria(
                [
                    {**r["methods"][k], "alpha": r["bridge"]["alpha"]}
                    for r in doc["records"]
                    if k in r["methods"]
                ]
            ),
        }
        for k in keys
        if any(k in r["methods"] for r in doc["records"])
    }
    tr = doc.get("time_reference")
    times = [r["time_s"] for r in doc["records"]]
    timing = {"max_s": max(times), "median_s": sorted(times)[len(times) // 2]}
    # the yardstick timed in this study (its commit and machine are the study's runs')
    if tr:
        timing["reference_s"] = tr["time_s"]
        timing["max_ratio"] = max(times) / tr["time_s"]
        timing["within"] = timing["max_ratio"] <= TIME_RATIO_MAX
    return {"criteria": out, "timing": timing, "commits": commits(doc["records"])}


def gather(out: Path) -> dict:
    studies = {}
    for p in sorted((out / "family").glob("*.json")):
        try:
            doc = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError):
            continue
        if doc.get("schema") != STUDY_SCHEMA or not doc.get("records"):
            continue
        studies[p.stem] = {**doc, **summarise(doc), "file": f"family/{p.name}"}
    return {"schema": SCHEMA, "family": family_ranges(), "studies": studies}


def family_ranges() -> dict:
    """The ranges the family draws its bridges from (`bayespinn.family`), for the page and its JSON."""
    return {
        "span_m": list(family.SPAN_M),
        "first_frequency_times_span_hz_m": list(family.F1_TIMES_L),
        "axles": list(family.AXLES),
        "axle_load_kn": [x / 1e3 for x in family.AXLE_LOAD_N],
        "speed_m_s": list(family.SPEED_M_S),
        "alpha": list(family.ALPHA),
        "deflection_points": list(family.N_POINTS),
    }


def _f(v, fmt="{:+.2f}") -> str:
    return "n/a" if v is None else fmt.format(v)


def _ok(text: str, ok: bool) -> str:
    return text if ok else f"**{text}** (fails)"


def blocks(page: dict) -> list:
    lo, hi = family.SD_RATIO_BAND
    r = page["family"]
    fl = r["first_frequency_times_span_hz_m"]
    out = [
        Heading(
            "A family of bridges: the PINN posteriors against the reference on bridges never tuned on",
            1,
        ),
        Paragraph(
            f"Each bridge of the family (`bayespinn.family`: spans {r['span_m'][0]:g}-{r['span_m'][1]:g} m, "
            f"first frequencies {fl[0]:g}/L-{fl[1]:g}/L Hz, {r['axles'][0]}-{r['axles'][1]} axles of "
            f"{r['axle_load_kn'][0]:g}-{r['axle_load_kn'][1]:g} kN, speed parameter alpha = v / (2 f1 L) "
            f"log-uniform on {r['alpha'][0]:g}-{r['alpha'][1]:g}) gets one "
            "synthetic dataset; the modal reference (emcee on the exact modal model) and each PINN method run "
            "on it. z = (mean - reference mean) / reference sd of EI; sd ratio = sd / reference sd; sigma z "
            "the same for the noise sd. Bands: mean z within "
            f"±{family.Z_MEAN_MAX}, sd of z at most {family.Z_SD_MAX}, |z| at most {family.Z_ABS_MAX} on every "
            f"bridge, sd ratio in [{lo}, {hi}] on at least {100 * family.SD_RATIO_SHARE:.0f} % of bridges, "
            f"sigma within {family.SIGMA_Z_MAX:g} reference sds on at least {100 * family.SIGMA_SHARE:.0f} %. "
            "Trend: Spearman's rank correlation of z with alpha (small p: z drifts with the dynamics; "
            f"p below {family.TREND_P_MIN:g} fails)."
        ),
    ]
    for s in page["studies"].values():
        out.append(
            Heading(
                f"{s['case']}, {c.snr_text(s['snr_db'])}: {len(s['records'])} bridges "
                f"({family_name(s['family_seed'])}: family seed {s['family_seed']}, data seed {s['seed']}, "
                f"profile {s['profile']})",
                2,
            )
        )
        if s.get("label"):
            out.append(Paragraph(f"**{s['label'][0].upper()}{s['label'][1:]}.**"))
        missing = sorted(set(s.get("planned") or []) - {r["bridge"]["index"] for r in s["records"]})
        if missing:
            out.append(
                Alert(
                    f"Partial: {len(s['records'])} of {len(s['planned'])} planned bridges so far (the same "
                    "command resumes the rest)."
                )
            )
        crit_rows = []
        for k, cr in s["criteria"].items():
            p = cr["pass"]
            trend = cr.get("trend")
            crit_rows.append(
                (
                    name(k),
                    str(cr["bridges"]),
                    _ok(_f(cr["mean_z"]), p["mean_z"]),
                    _ok(_f(cr["sd_z"], "{:.2f}"), p["sd_z"]),
                    _ok(_f(cr["max_abs_z"], "{:.2f}"), p["max_abs_z"]),
                    f"{cr['median_sd_ratio']:.2f}",
                    _ok(f"{100 * cr['sd_ratio_in_band']:.0f} %", p["sd_ratio_in_band"]),
                    _ok(f"{100 * cr['sigma_within']:.0f} %", p["sigma_within"]),
                    "n/a"
                    if not trend
                    else _ok(
                        f"{trend['spearman_rho']:+.2f} (p {trend['p_value']:.3f})",
                        p.get("no_trend", True),
                    ),
                )
            )
            if not all(p.values()):
                failed = ", ".join(n for n, ok in p.items() if not ok)
                out.append(Alert(f"{name(k)} misses the family's bands at this level: {failed}."))
        out.append(
            table(
                (
                    "method",
                    "bridges",
                    "mean z",
                    "sd of z",
                    "max abs z",
                    "median sd ratio",
                    "sd ratio in band",
                    "sigma within 2 sd",
                    "z vs alpha (rho)",
                ),
                crit_rows,
            )
        )
        split_rows = []
        for k, cr in s["criteria"].items():
            for label, g in cr["by_alpha"].items():
                split_rows.append(
                    (
                        name(k),
                        label,
                        str(g["bridges"]),
                        _f(g["mean_z"]),
                        _f(g["sd_z"], "{:.2f}"),
                        f"{g['median_sd_ratio']:.2f}",
                    )
                )
        out.append(
            Paragraph(
                "Split at alpha = 0.04 (the two girders every choice was tuned on have 0.021 and 0.027):"
            )
        )
        out.append(
            table(
                ("method", "alpha", "bridges", "mean z", "sd of z", "median sd ratio"), split_rows
            )
        )
        keys = [k for k in s["methods"] if k != s["reference"]]
        head = ["bridge", "alpha", "f1 (Hz)", "L (m)", "axles", "ref. sd / EI", "ref. R-hat / ESS"]
        for k in keys:
            head += [f"{name(k)} z", "sd ratio", "sigma z"]
        head += ["time (s)"]
        rows = []
        for r in s["records"]:
            b, m = r["bridge"], r["methods"]
            ref = m[s["reference"]]
            row = [
                str(b["index"]),
                f"{b['alpha']:.3f}",
                f"{b['f1_hz']:.2f}",
                f"{b['length_m']:.1f}",
                str(b["axles"]),
                f"{100 * ref['EI_sd'] / b['EI']:.3f} %",
                f"{_f(ref['rhat'], '{:.3f}')} / {_f(ref['ess_bulk'], '{:.0f}')}",
            ]
            for k in keys:
                q = m.get(k)
                row += [_f(q["z"]), f"{q['sd_ratio']:.2f}", _f(q["sigma_z"])] if q else ["n/a"] * 3
            row.append(f"{r['time_s']:.0f}")
            rows.append(tuple(row))
        out.append(table(tuple(head), rows))
        t = s["timing"]
        line = (
            f"Time per bridge (all methods): median {t['median_s']:.0f} s, max {t['max_s']:.0f} s"
        )
        if "reference_s" in t:
            line += (
                f"; the Exeter girder's 20 dB run took {t['reference_s']:.0f} s in the same study, so the "
                f"slowest bridge took {t['max_ratio']:.2f}× it (band: at most {TIME_RATIO_MAX:g}×)."
            )
        else:
            line += " (no timing yardstick in this study: `--time-reference`)."
        out.append(Paragraph(line))
        lines = []
        for prov in s.get("runs", []):
            m = prov["machine"]
            lines.append(
                f"`{prov['command']}`; {prov['date']}; {m['cpus']} CPU cores"
                + (f" ({m['cpu_model']})" if m.get("cpu_model") else "")
                + f", device {m['device']}; "
                f"bayespinn {prov['versions'].get('bayespinn')}, git {(prov.get('git_commit') or 'n/a')[:12]}"
                + (" (uncommitted changes)" if prov.get("git_dirty") else "")
                + (f"; note: {prov['note']}" if prov.get("note") else "")
            )
        out.append(
            Paragraph(
                f"Study file `{s['file']}`; its bridges {c.commits_sentence(s)}. Runs that computed them:"
            )
        )
        out.append(BulletList(lines))
    return out


def write_page(out: Path) -> dict:
    page = gather(out)
    c.write_json(out / "family.json", page)
    c.write_markdown(out / "family.md", blocks(page))
    log.info("wrote %s and %s", out / "family.md", out / "family.json")
    return page


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    p = c.parser("Each method against the modal reference on a seeded family of bridges.")
    p.add_argument(
        "--bridges", type=int_at_least("--bridges", 1), default=24, help="bridges (default 24)"
    )
    p.add_argument(
        "--start", type=int_at_least("--start", 0), default=0, help="first bridge index (default 0)"
    )
    p.add_argument(
        "--family-seed",
        dest="family_seed",
        type=int_at_least("--family-seed", 0),
        default=0,
        help=f"which family (default 0, the development family; {HELD_OUT_SEED}: the held-out family); "
        "bridge i of a family seed is always the same bridge",
    )
    p.add_argument("--snr", default="30", help="SNR in dB (default 30)")
    p.add_argument("--case", default="deflection", help="deflection (default) or strain")
    p.add_argument(
        "--time-reference",
        dest="time_reference",
        action="store_true",
        help="also time the Exeter girder's 20 dB run (seed 11), the yardstick of each bridge's time",
    )
    p.add_argument(
        "--report-only",
        action="store_true",
        help="run nothing: rebuild family.md/json from the study files in --out/family",
    )
    args = p.parse_args(argv)
    c.setup_logging(args.quiet)
    out = Path(args.out)
    if args.report_only:
        if not gather(out)["studies"]:
            raise InputError("--out", str(out), "a folder with family studies (family/*.json)")
        write_page(out)
        return 0
    if args.case not in CASES:
        raise InputError("--case", args.case, "one of " + ", ".join(CASES))
    levels = c.levels_of(args.snr)
    if len(levels) != 1 or levels[0] is None:
        raise InputError("--snr", args.snr, "one SNR level in dB")
    names = c.methods_of(args.methods)
    ref = methods.by_key(methods.reference_key()).name
    if ref not in names:
        names = [ref, *names]
    study(args, argv, levels[0], names)
    write_page(out)
    return 0


if __name__ == "__main__":
    c.entry(main)
