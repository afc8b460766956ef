"""Do the credible intervals mean what they say? Coverage of the true EI over independent datasets.

For each method and SNR level (default 10 and 30 dB, deflection case), `bayespinn.uq.coverage.
coverage_study` draws --replicates datasets (fresh sample points and noise, seeded by replicate), runs
the method on each and counts the replicates whose central 90 % interval holds the true EI. The table
gives the hits, the coverage with its exact 95 % confidence interval, the 99 % binomial acceptance
region of the hits for a calibrated method (`binomial_acceptance`: outside it, the intervals are
miscalibrated at a 1 % false-alarm rate), the rank-uniformity p value, the mean relative error, the
mean posterior sd and the run time. Each study's full JSON (the `bayespinn coverage` schema, with the
per-replicate records) goes into <out>/coverage/<method>-snr<S>.json.

All methods see the same datasets (replicate i of a seed and SNR), so each PINN study is also set
beside the modal reference posterior dataset by dataset (`paired_with_reference`): hits on the truth of
a few dozen datasets are a coarse test; the PINN posterior against the exact one on the same data is a
sharp one. `--report-only` rebuilds the page from the study files already there; `--resume` reuses the
replicates of a study file already there when it is the same study (a PINN study spread over sessions).

    python studies/coverage.py --methods modal --out reports/paper
"""

from __future__ import annotations

import json
import logging
import sys
from dataclasses import replace
from pathlib import Path

import common as c
import numpy as np

from bayespinn.config import CASES, preset, resolve, snr_label
from bayespinn.errors import InputError
from bayespinn.executor import Executor
from bayespinn.provenance import commits, commits_text
from bayespinn.report.document import Alert, BulletList, Figure, Heading, Paragraph, table
from bayespinn.report.units import fmt_pct, name
from bayespinn.uq.coverage import (
    POWER_AGAINST,
    SEEDING,
    binomial_acceptance,
    coverage_study,
    paired_with_reference,
    power,
    verdict,
)

log = logging.getLogger("studies.coverage")

SCHEMA = "bayespinn.studies.coverage/1"
LEVELS = "10,30"
#: replicates per method by default: the modal reference is cheap, PINN methods are not
REPLICATES = {"modal": 200, "ensemble": 30, "bpinn": 20}
#: false-failure rate of the acceptance region
FALSE_FAILURE = 0.01
#: the rank ECDF figure: simultaneous band probability
ECDF_BAND = 0.99


#: entries a table row copies from its study file: a row whose entries differ is not that file's
ROW_MATCHES_STUDY = ("replicates", "hits", "fingerprint", "runtime_s")


def code(row: dict, out: Path | None = None) -> str:
    """The `code` column: the commits the row's replicates were computed at (from its study file's
    records), or the commit of the run that wrote the row where the replicates predate recording theirs;
    a note when the study file no longer holds the row's numbers."""
    study = None
    if out is not None and row.get("file") and (out / row["file"]).is_file():
        study = json.loads((out / row["file"]).read_text(encoding="utf-8"))
        if any(study.get(k) != row.get(k) for k in ROW_MATCHES_STUDY):
            # the study file was rewritten (e.g. by a run stopped before it merged its row)
            return f"the row's numbers are not those of {row['file']}; re-run its study"
    recs = (study or {}).get("records") or []
    counts = commits(recs) if recs else row.get("commits") or {}
    if counts and set(counts) != {"unrecorded"}:
        return "replicates at " + commits_text(counts)
    return "not recorded per replicate (older records; see the run's commit)"


def datasets(row: dict) -> str:
    return "independent" if row.get("seeding") == SEEDING else "paired across SNR (older seeding)"


def replicates_of(text: str | None, methods: list[str]) -> dict[str, int]:
    """'4' (every method) or 'modal=200,ensemble=30' (the rest keep their defaults)."""
    out = {m: REPLICATES[m] for m in methods}
    if not text:
        return out
    for part in text.split(","):
        k, _, v = part.strip().rpartition("=")
        try:
            n = int(v)
        except ValueError:
            raise InputError(
                "--replicates", text, "an integer, or method=N pairs such as modal=200,ensemble=30"
            ) from None
        if n < 1:
            raise InputError("--replicates", text, "replicate counts >= 1")
        if k:
            if k not in REPLICATES:
                raise InputError("--replicates", text, "method names among modal, ensemble, bpinn")
            if k in out:
                out[k] = n
        else:
            out = dict.fromkeys(out, n)
    return out


def sort_key(r: dict) -> tuple:
    return (c.method_key(r["method"]), c.snr_key(r["snr_db"]))


def blocks(doc: dict) -> list:
    body, alerts = [], []
    for r in doc["rows"]:
        lo, hi = r["acceptance_99"]
        ok = lo <= r["hits"] <= hi
        if not ok:
            alerts.append(
                Alert(
                    f"{name(r['method'])} at {c.snr_text(r['snr_db'])}: {r['hits']} hits of {r['replicates']} lie "
                    f"outside the 99 % acceptance region [{lo}, {hi}]: its {100 * r['level']:.0f} % intervals are "
                    "**miscalibrated**"
                    + (" (too narrow: overconfident)." if r["hits"] < lo else " (too wide).")
                )
            )
        conv = r.get("converged_fraction")
        v = verdict(r["hits"], r["replicates"], r["level"], FALSE_FAILURE)
        body.append(
            (
                name(r["method"]),
                c.snr_text(r["snr_db"]),
                str(r["replicates"]),
                str(r["hits"]),
                f"{r['coverage']:.3f}",
                f"[{r['coverage_ci95'][0]:.3f}, {r['coverage_ci95'][1]:.3f}]",
                f"[{lo}, {hi}]",
                v if ok else f"**{v}**",
                f"{power(r['replicates'], r['level'], POWER_AGAINST, FALSE_FAILURE):.2f}",
                "n/a" if r["rank_uniformity_p"] is None else f"{r['rank_uniformity_p']:.3f}",
                fmt_pct(r["mean_rel_error_pct"]),
                f"{r['mean_sd_rel_pct']:.3f} %",
                "n/a" if conv is None else f"{100 * conv:.0f} %",
                f"{r['runtime_s']:.0f}"
                + (
                    f" (+{r['resumed_replicates']} replicates resumed from an earlier run)"
                    if r.get("resumed_replicates")
                    else ""
                ),
                datasets(r),
                r.get("code") or code(r),
                c.run_cell(doc, r),
            )
        )
    out = [
        Heading(
            "Coverage of the true EI by the credible intervals"
            + (f": {doc['config']}, {doc['case']} case" if doc.get("config") else ""),
            1,
        ),
        Paragraph(
            (
                f"The girder and analysis model of `{doc['config']}`, {doc['case']} case. "
                if doc.get("config")
                else "Deflection case (case study 1). "
            )
            + "For each method and SNR: synthetic datasets (fresh random sample "
            "points and noise per replicate, the true EI fixed); 'hits': replicates whose central interval "
            "contains the true EI. A calibrated method's hits follow Binomial(n, level); the acceptance region "
            f"holds them with probability {100 * (1 - FALSE_FAILURE):.0f} %, and the verdict says whether the "
            "hits are consistent with the nominal level (not that the method is calibrated: a few dozen "
            f"replicates cannot show that). Power: the probability that a method whose intervals hold the "
            f"truth only {100 * POWER_AGAINST:.0f} % of the time falls outside the region at this replicate "
            "count. Coverage CI: exact (Clopper-Pearson) 95 %, from scipy. Rank uniformity: Kolmogorov-Smirnov "
            "p value of the truth's rank among the posterior draws (small p: the posterior is biased or "
            "mis-sized even if the hits pass). Mean sd: the posterior sd of EI relative to the truth, "
            "averaged. Datasets: 'independent' rows draw their replicates from the seed, the SNR and the "
            "index, so two SNR rows are two experiments; 'paired' rows (older seeding) reused the same sample "
            "points and standard-normal draws at every SNR, so such rows are one experiment seen twice and "
            "must not be pooled. Code: the commits the replicates were computed at (each replicate records its "
            "own; a study resumed over several sessions may have several); run: the run that wrote the row "
            "and its commit (Provenance below)."
        ),
        *alerts,
        table(
            (
                "method",
                "SNR",
                "replicates",
                "hits",
                "coverage",
                "coverage 95 % CI",
                "99 % acceptance (hits)",
                "verdict",
                f"power vs {100 * POWER_AGAINST:.0f} %",
                "rank-uniformity p",
                "mean rel. error",
                "mean sd / EI",
                "converged",
                "runtime (s)",
                "datasets",
                "code",
                "run",
            ),
            body,
            f"Credible level {100 * doc['rows'][0]['level']:.0f} %." if doc["rows"] else "",
        ),
    ]
    if any(r["method"] == "modal_mcmc" for r in doc["rows"]):
        out.append(
            Paragraph(
                "The modal reference runs each replicate with the coverage sampler settings of "
                "`MCMCSettings.for_coverage()` (the same for every profile)."
            )
        )
    if doc.get("rank_figure"):
        out.append(
            Figure(
                "Ranks of the true EI among the posterior draws",
                doc["rank_figure"],
                "ECDF of the truth's rank minus the uniform CDF, per study, with the simultaneous "
                f"{100 * ECDF_BAND:.0f} % band of a calibrated posterior (ArviZ `plot_ecdf`). A curve leaving the "
                "band: the posterior is biased (an S-shape tilted to one side) or mis-sized (a hump: too "
                "wide; a trough: too narrow).",
            )
        )
    out += paired_blocks(doc)
    out += coefficient_blocks(doc)
    out += c.not_run_yet(doc)
    out += [
        Heading("Files"),
        BulletList(
            (
                f"`{page_name(doc)}.json`: these rows (SI units);",
                f"`coverage/{study_prefix(doc)}<method>-snr<S>.json`: each study in the `bayespinn "
                "coverage` schema, with the per-replicate records (interval, rank, relative error).",
            )
        ),
        Heading("Provenance"),
        BulletList(tuple(c.provenance_lines(doc["runs"], list(doc["runs"])))),
    ]
    return out


def page_name(doc: dict) -> str:
    """The table's file stem: `coverage` for the Exeter deflection study, else with the config and case."""
    return "coverage" + (f"-{Path(doc['config']).stem}-{doc['case']}" if doc.get("config") else "")


def study_prefix(doc: dict) -> str:
    return f"{Path(doc['config']).stem}-{doc['case']}-" if doc.get("config") else ""


def coefficient_blocks(doc: dict) -> list:
    """The AR(1) coefficient's coverage, for rows whose analysis inferred it."""
    rows = [r for r in doc["rows"] if r.get("noise_ar1")]
    if not rows:
        return []
    body = []
    for r in rows:
        q = r["noise_ar1"]
        lo, hi = q["acceptance_99"]
        ok = lo <= q["hits"] <= hi
        body.append(
            (
                name(r["method"]),
                c.snr_text(r["snr_db"]),
                f"{q['true']:g}",
                str(q["replicates"]),
                str(q["hits"]),
                f"[{lo}, {hi}]",
                q["verdict"] if ok else f"**{q['verdict']}**",
                "n/a" if q["rank_uniformity_p"] is None else f"{q['rank_uniformity_p']:.3f}",
                f"{q['mean']:.3f}",
                f"{q['mean_sd']:.3f}",
            )
        )
    return [
        Heading("Coverage of the noise's AR(1) coefficient"),
        Paragraph(
            "The same replicates: the analysis infers the coefficient of the AR(1) noise beside EI; hits: "
            "replicates whose central interval holds the coefficient the data were simulated with."
        ),
        table(
            (
                "method",
                "SNR",
                "true coefficient",
                "replicates",
                "hits",
                "99 % acceptance (hits)",
                "verdict",
                "rank-uniformity p",
                "mean of means",
                "mean sd",
            ),
            body,
        ),
    ]


def add_paired(doc: dict, out: Path) -> None:
    """Give each PINN row its dataset-by-dataset comparison with the modal reference of the same SNR
    (`paired_with_reference`), where both studies' files are there and share their datasets."""
    ref = {c.snr_key(r["snr_db"]): r for r in doc["rows"] if r["method"] == "modal_mcmc"}
    for r in doc["rows"]:
        r.pop("paired_reference", None)
        q = ref.get(c.snr_key(r["snr_db"]))
        if r["method"] == "modal_mcmc" or q is None:
            continue
        files = [out / r["file"], out / q["file"]] if r.get("file") and q.get("file") else []
        if files and all(f.exists() for f in files):
            study, reference = (json.loads(f.read_text(encoding="utf-8")) for f in files)
            pr = paired_with_reference(study, reference)
            if pr is not None:
                pr.update(rank_uniformity_on_shared(study, reference))
                r["paired_reference"] = pr


def rank_uniformity_on_shared(study: dict, reference: dict) -> dict:
    """Kolmogorov-Smirnov p of the truth's ranks of both studies on the datasets they share: a small p of the
    method's alone points at the method, a small p of both at the datasets (ranks are scored against the
    truth, so a few dozen datasets can place it off-centre for any posterior)."""
    from scipy import stats

    ref = {q["index"]: q["rank"] for q in reference["records"]}
    pairs = [(r["rank"], ref[r["index"]]) for r in study["records"] if r["index"] in ref]
    if len(pairs) < 2:
        return {}
    mine, theirs = zip(*pairs, strict=True)
    return {
        "rank_uniformity_p": float(stats.kstest(mine, "uniform").pvalue),
        "reference_rank_uniformity_p": float(stats.kstest(theirs, "uniform").pvalue),
    }


def paired_blocks(doc: dict) -> list:
    rows = [r for r in doc["rows"] if r.get("paired_reference")]
    if not rows:
        return []
    lo, hi = rows[0]["paired_reference"]["sd_ratio_band"]
    body = []
    for r in rows:
        p = r["paired_reference"]
        body.append(
            (
                name(r["method"]),
                c.snr_text(r["snr_db"]),
                str(p["datasets"]),
                f"{p['mean_z']:+.2f}",
                "n/a" if p["sd_z"] is None else f"{p['sd_z']:.2f}",
                f"{p['max_abs_z']:.2f}",
                f"{p['median_sd_ratio']:.2f}",
                f"[{p['sd_ratio_range'][0]:.2f}, {p['sd_ratio_range'][1]:.2f}]",
                f"{100 * p['sd_ratio_in_band']:.0f} %",
                f"{p['hits']} / {p['reference_hits']} / {p['misses_of_both']}",
                _rank_ps(p),
            )
        )
    return [
        Heading("Against the reference posterior, dataset by dataset"),
        Paragraph(
            "The studies share their datasets (same seed, SNR and replicate index), so each PINN posterior can "
            "be set beside the modal reference posterior of the very same data. z: (PINN mean - reference "
            "mean) / reference sd; sd ratio: PINN sd / reference sd. A faithful approximate posterior has z "
            f"near 0 and sd ratios near 1 (the band is [{lo}, {hi}]). Hits: PINN / reference / "
            "datasets missed by both (a miss of both is an extreme dataset, not a fault of the method). "
            "Rank-uniformity p: of the truth's ranks on these datasets, the PINN's and the reference's (small "
            "for both: the datasets place the truth off-centre; small for the PINN alone: the PINN)."
        ),
        table(
            (
                "method",
                "SNR",
                "datasets",
                "mean z",
                "sd of z",
                "max abs z",
                "median sd ratio",
                "sd ratio range",
                "sd ratio in band",
                "hits (PINN / ref / both missed)",
                "rank-uniformity p (PINN / ref)",
            ),
            body,
        ),
    ]


def _rank_ps(p: dict) -> str:
    if "reference_rank_uniformity_p" not in p:
        return "n/a"
    return f"{p['rank_uniformity_p']:.3f} / {p['reference_rank_uniformity_p']:.3f}"


def rank_figure(doc: dict, out: Path) -> str | None:
    """coverage_ranks.png: per study, the rank ECDF with its simultaneous band beside the hit count and its
    acceptance region (`bayespinn.report.coverage`); the path relative to `out`, or None when no study
    file is there."""
    from bayespinn.report.coverage import rank_ecdf_figure

    studies = []
    for r in doc["rows"]:
        f = out / r["file"] if r.get("file") else None
        if f is not None and f.exists():
            recs = json.loads(f.read_text(encoding="utf-8"))["records"]
            studies.append((r, np.array([q["rank"] for q in recs])))
    if not studies:
        return None
    label = lambda r: f"{name(r['method'])}, {c.snr_text(r['snr_db'])}"  # noqa: E731
    path = rank_ecdf_figure(
        studies, out / f"{page_name(doc)}_ranks.png", ECDF_BAND, FALSE_FAILURE, label
    )
    return path.name


def refresh(doc: dict, out: Path, figure: bool = True) -> None:
    """Bring the doc's derived entries up to date: paired comparisons, each row's verdict, power, datasets
    and commits, and (with `figure`) the rank figure."""
    add_paired(doc, out)
    for r in doc["rows"]:
        r["verdict"] = verdict(r["hits"], r["replicates"], r["level"], FALSE_FAILURE)
        r["power_vs_80"] = power(r["replicates"], r["level"], POWER_AGAINST, FALSE_FAILURE)
        r["code"] = code(r, out)
        r["datasets"] = datasets(r)
        r["acceptance_probability"] = 1 - FALSE_FAILURE
        r["power_against"] = POWER_AGAINST
    if figure:
        doc["rank_figure"] = rank_figure(doc, out)
    elif (out / f"{page_name(doc)}_ranks.png").exists():
        doc["rank_figure"] = f"{page_name(doc)}_ranks.png"


def write_page(doc: dict, out: Path) -> None:
    """coverage.json, coverage.md and the rank figure of the table doc, with the paired comparisons and each
    row's verdict, power and commits brought up to date."""
    refresh(doc, out)
    stem = page_name(doc)
    c.write_json(out / f"{stem}.json", doc)
    c.write_markdown(out / f"{stem}.md", blocks(doc))
    log.info("wrote %s and %s", out / f"{stem}.md", out / f"{stem}.json")


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    p = c.parser("Coverage of the true EI by each method's credible intervals (deflection case).")
    p.add_argument("--snr", default=LEVELS, help=f"comma list of levels in dB (default {LEVELS})")
    p.add_argument(
        "--replicates",
        default=None,
        help="N for every method, or method=N pairs (default modal=200, ensemble=30, bpinn=20)",
    )
    p.add_argument("--level", type=float, default=0.9, help="credible level (default 0.9)")
    p.add_argument(
        "--config",
        default=None,
        help="a TOML of the truth and the analysis model (default: the Exeter girder); its study goes to "
        "coverage-<name>-<case>.md/json",
    )
    p.add_argument("--case", default="deflection", help="deflection (default) or strain")
    p.add_argument(
        "--workers", type=int, default=None, help="local worker processes (default one per core)"
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="reuse the replicates of each study file already in --out/coverage when it is the same "
        "study (a study carried over several sessions)",
    )
    p.add_argument(
        "--report-only",
        action="store_true",
        help="run nothing: rebuild coverage.md/json from the study files already in --out",
    )
    args = p.parse_args(argv)
    c.setup_logging(args.quiet)
    out = Path(args.out)
    if args.case not in CASES:
        raise InputError("--case", args.case, "one of " + ", ".join(CASES))
    # the Exeter deflection study keeps its page, coverage.md; any other girder or case gets its own
    custom = args.config or args.case != "deflection"
    which = {"config": args.config or "exeter", "case": args.case} if custom else {}
    if args.report_only:
        doc = c.load_table(out / f"{page_name(which)}.json", SCHEMA)
        if not doc["rows"]:
            raise InputError(
                "--out", str(out), "a folder with a coverage.json from an earlier study"
            )
        write_page(doc, out)
        return 0
    methods = c.methods_of(args.methods)
    levels = c.levels_of(args.snr)
    if any(v is None for v in levels):
        raise InputError("--snr", args.snr, "levels in dB (clean data have no noise to cover)")
    if not 0.0 < args.level < 1.0:
        raise InputError("--level", args.level, "a credible level in (0, 1)")
    reps = replicates_of(args.replicates, methods)
    cfg = resolve(args.case, args.config) if args.config else preset(args.case)
    keys = [c.key_of(m) for m in methods]
    executor = Executor("local", args.workers)
    prov = c.provenance(
        __file__,
        argv,
        args,
        methods=keys,
        levels=levels,
        replicates=reps,
        workers=args.workers or c.cpu_count(),
    )
    for m, key in zip(methods, keys, strict=True):
        for snr in levels:
            log.info("coverage: %s at %s dB, %d replicates", key, snr_label(snr), reps[m])
            # finished replicates survive an interruption; the same command resumes from them
            study = out / "coverage" / f"{study_prefix(which)}{key}-snr{snr_label(snr)}.json"
            partial = study.with_name(study.name + ".partial.jsonl")
            res = coverage_study(
                m,
                cfg,
                snr,
                replicates=reps[m],
                level=args.level,
                seed=args.seed,
                opts=replace(c.run_options(args, snr), progress=False),
                executor=executor,
                progress=not args.quiet,
                checkpoint=partial,
                resume_from=study if args.resume else None,
            )
            c.write_json(study, res)
            partial.unlink(missing_ok=True)
            row = {k: v for k, v in res.items() if k not in ("records", "config", "provenance")}
            row["acceptance_99"] = list(
                binomial_acceptance(res["replicates"], args.level, FALSE_FAILURE)
            )
            row["file"] = str(study.relative_to(out))
            # merged at once: a run stopped in a later level keeps this level's row
            doc = c.load_table(out / f"{page_name(which)}.json", SCHEMA)
            doc.update(case=cfg.case, truth={"EI": cfg.beam.EI})
            doc.update(which)
            if cfg.model.noise == "ar1":
                doc["truth"]["noise_ar1"] = cfg.data.noise_ar1
            c.merge(doc, [row], prov, ("snr_db", "method"), sort_key)
            write_page(doc, out)
            log.info(
                "coverage: %s at %s dB: %d / %d hits (acceptance [%d, %d]), %.0f s",
                key,
                snr_label(snr),
                row["hits"],
                row["replicates"],
                *row["acceptance_99"],
                row["runtime_s"],
            )
    return 0


if __name__ == "__main__":
    c.entry(main)
