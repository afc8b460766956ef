"""Does the fit check say what it should? Its verdict over independent synthetic datasets.

Replicate i of a study simulates the configuration's true girder (the Exeter preset, or `--config`: EI per
segment, springs, AR(1) noise, ...) at one of the study's SNR levels (level i mod the number of levels) with
its own seed, runs the modal reference with the configuration's analysis model, and records the fit check's
verdict and p-values, and whether each parameter's central 90 % interval holds its truth. Over the
replicates: the share of `fits` (data the model describes: at least 98 % expected) or of `misfit` (data it
cannot: at least 90 % expected) with its exact 95 % interval, per level too; and the coverage of the truth by
the 90 % intervals against the binomial 99 % region of a calibrated interval, which says how wrong the
intervals of a misspecified model are.

One study per configuration, case and SNR list in <out>/fitcheck/<name>-<case>-snr<levels>.json,
rewritten atomically after every replicate: an interrupted study resumes from it; replicates computed by
other code (the modal reference's or the fit check's) are run again. <out>/fitcheck.md and fitcheck.json
gather every study there.

    python studies/fitcheck.py --case deflection --snr 10,20,30,40 --replicates 200 --expect fits
    python studies/fitcheck.py --case strain --snr 10,20,30,40 --replicates 200 --expect fits
    python studies/fitcheck.py --config examples/bearings-as-pinned.toml --snr 30 --replicates 100 --expect misfit
    python studies/fitcheck.py --config examples/damaged-as-uniform.toml --case strain --snr 30 --replicates 100 --expect misfit
    python studies/fitcheck.py --config examples/ar1-strain.toml --case strain --snr 20 --replicates 100 --expect misfit
    python studies/fitcheck.py --config examples/ar1-strain-ar1.toml --case strain --snr 20 --replicates 100 --expect fits
"""

from __future__ import annotations

import hashlib
import json
import logging
import sys
import time
import zlib
from pathlib import Path

import common as c
import numpy as np
from girders import coverage_rows, parameters
from scipy import stats

from bayespinn.config import CASES, resolve, snr_label
from bayespinn.data.synthetic import simulate
from bayespinn.errors import InputError
from bayespinn.options import int_at_least
from bayespinn.pipeline import analyse, true_values_of
from bayespinn.report.document import Heading, Paragraph, table

log = logging.getLogger("studies.fitcheck")

STUDY_SCHEMA = "bayespinn.studies.fitcheck-study/1"
SCHEMA = "bayespinn.studies.fitcheck/1"
#: what is asked of the verdict: the share of replicates that must get the expected verdict
REQUIRED_SHARE = {"fits": 0.98, "misfit": 0.90}
EXPECTS = tuple(REQUIRED_SHARE)
#: the exact (Clopper-Pearson) interval's probability for a share of replicates
SHARE_CI = 0.95
LEVEL = 0.9
PRESET = "exeter"


def data_seed(seed: int, i: int) -> np.random.SeedSequence:
    """Replicate i's seed (data and analysis) in a study with root seed `seed`: independent of the
    girder studies' and of every other replicate's."""
    return np.random.SeedSequence(int(seed), spawn_key=(zlib.crc32(b"fitcheck"), int(i)))


def exact_interval(k: int, n: int, prob: float = SHARE_CI) -> list[float]:
    """The exact (Clopper-Pearson) interval of a binomial share k / n."""
    ci = stats.binomtest(int(k), int(n)).proportion_ci(confidence_level=prob, method="exact")
    return [float(ci.low), float(ci.high)]


def replicate(cfg, levels: list, seed: int, i: int, opts) -> dict:
    seq = data_seed(seed, i)
    snr = levels[i % len(levels)]
    t0 = time.perf_counter()
    data = simulate(cfg, snr, seq)
    truth = true_values_of(cfg, seq)
    # an integer seed for the analysis, so that the fit check's white-noise replicates differ per replicate
    run_seed = int(seq.generate_state(1)[0])
    res = analyse(data, cfg, methods=["modal"], seed=run_seed, snr_db=snr, opts=opts, truth=truth)
    m = res.summary["methods"]["modal_mcmc"]
    fc = m.get("fit_check") or {}
    return {
        "index": i,
        "snr_db": snr,
        "verdict": fc.get("verdict"),
        "p_value": fc.get("p_value"),
        "p_values": fc.get("p_values"),
        "residual_autocorr": fc.get("residual_autocorr"),
        "hits": {k: bool(ci[0] <= t <= ci[1]) for k, (ci, t) in parameters(m, truth).items()},
        "EI_rel_error_pct": m["EI"].get("rel_error_pct"),
        "converged": (m.get("diagnostics") or {}).get("converged"),
        "time_s": time.perf_counter() - t0,
        **c.replicate_provenance(),
    }


def _share(recs: list[dict], expect: str) -> dict:
    n = len(recs)
    k = sum(r["verdict"] == expect for r in recs)
    return {
        "replicates": n,
        "expected": int(k),
        "share": k / n if n else None,
        "share_ci95": exact_interval(k, n) if n else None,
        "unchecked": int(sum(r["verdict"] is None for r in recs)),
    }


def summarise(doc: dict) -> dict:
    recs, expect = doc["records"], doc["expect"]
    overall = _share(recs, expect)
    need = REQUIRED_SHARE[expect]
    levels = sorted({r["snr_db"] for r in recs}, key=c.snr_key)
    coverage = coverage_rows(recs)
    return {
        **overall,
        "required_share": need,
        "meets": bool(overall["share"] is not None and overall["share"] >= need),
        "by_snr": {
            snr_label(s): _share([r for r in recs if r["snr_db"] == s], expect) for s in levels
        },
        "median_residual_autocorr": float(
            np.median([r["residual_autocorr"] for r in recs if r["residual_autocorr"] is not None])
        )
        if recs
        else None,
        "coverage": coverage,
        "converged": int(sum(bool(r.get("converged")) for r in recs)),
        "median_time_s": float(np.median([r["time_s"] for r in recs])) if recs else None,
        "noise_model": ((doc.get("config_values") or {}).get("model") or {}).get("noise", "iid"),
    }


def study_name(config: Path | None, case: str, levels: list) -> str:
    stem = config.stem if config is not None else PRESET
    return f"{stem}-{case}-snr{'_'.join(snr_label(s) for s in levels)}"


def run_study(args, argv, levels) -> dict:
    cfg = resolve(args.case, args.config)
    key = hashlib.sha256(
        json.dumps(
            {
                "cfg": c.jsonable(cfg.identity()),
                "levels": levels,
                "seed": args.seed,
                "expect": args.expect,
            },
            sort_keys=True,
        ).encode()
    ).hexdigest()[:16]
    config = Path(args.config) if args.config else None
    path = Path(args.out) / "fitcheck" / f"{study_name(config, args.case, levels)}.json"
    doc = c.open_study(path, STUDY_SCHEMA, key)
    doc.update(
        config=str(config) if config else None,
        config_values=c.jsonable(cfg.to_dict()),
        case=args.case,
        snr_db=levels,
        seed=args.seed,
        expect=args.expect,
        level=LEVEL,
        provenance=c.provenance(__file__, argv, args, methods=["modal_mcmc"]),
    )
    opts = c.run_options(args)
    return c.run_replicates(
        doc,
        path,
        args.replicates,
        lambda i: replicate(cfg, levels, args.seed, i, opts),
        summarise,
        "fitcheck",
    )


def gather(out: Path) -> dict:
    """Every fit-check study under <out>/fitcheck, summarised, with the commits its replicates ran at."""
    studies = c.gather_studies(out / "fitcheck", STUDY_SCHEMA, summarise)
    return {"schema": SCHEMA, "studies": studies}


def _pct(x) -> str:
    return "n/a" if x is None else f"{100 * x:.1f} %"


def blocks(page: dict) -> list:
    out = [
        Heading("Does the model fit? The fit check over independent datasets", 1),
        Paragraph(
            "Each study: independent synthetic datasets of one girder (the truth) analysed by the modal "
            "reference with one model (the configuration's `[model]`); the fit check's verdict on each "
            "(`bayespinn.uq.fitcheck`: the residuals at the posterior mean prediction against white noise, "
            "misfit when the Bonferroni-combined p-value is below 0.01). Data the model describes should get "
            f"`fits` in at least {100 * REQUIRED_SHARE['fits']:.0f} % of replicates, data it cannot `misfit` in "
            f"at least {100 * REQUIRED_SHARE['misfit']:.0f} %; the share is given with its exact "
            f"{100 * SHARE_CI:.0f} % interval. Beside it, how often each 90 % interval held its truth (binomial "
            "99 % region of a calibrated interval): what trusting a misfit model's intervals would cost. "
            "Command: `python studies/fitcheck.py [--config FILE] --case C --snr LEVELS --replicates N "
            "--expect fits|misfit` (resumable)."
        ),
    ]
    for name, d in page["studies"].items():
        s = d["summary"]
        rows = [
            (
                "all",
                f"{s['expected']} / {s['replicates']}",
                _pct(s["share"]),
                f"[{_pct(s['share_ci95'][0])}, {_pct(s['share_ci95'][1])}]",
            )
        ] + [
            (
                f"{lvl} dB",
                f"{v['expected']} / {v['replicates']}",
                _pct(v["share"]),
                f"[{_pct(v['share_ci95'][0])}, {_pct(v['share_ci95'][1])}]",
            )
            for lvl, v in s["by_snr"].items()
            if len(s["by_snr"]) > 1
        ]
        cov = [
            (
                k,
                f"{v['hits']} / {v['replicates']}",
                f"[{v['region'][0]}, {v['region'][1]}]",
                "yes" if v["inside"] else "**no**",
                f"{v['power_vs_80pct']:.2f}",
            )
            for k, v in s["coverage"].items()
        ]
        verdict = "meets" if s["meets"] else "**does not meet**"
        out += [
            Heading(
                f"{name}: {d['config'] or 'Exeter preset'}, {d['case']}, SNR "
                f"{', '.join(snr_label(x) for x in d['snr_db'])} dB, expected `{d['expect']}`",
                2,
            ),
            table(("SNR", f"`{d['expect']}`", "share", "exact 95 % interval"), rows),
            Paragraph(
                f"{s['replicates']} replicates "
                f"({c.commits_sentence(d)}), "
                f"{s['converged']} converged, {s['unchecked']} without a verdict; {_pct(s['share'])} "
                f"`{d['expect']}` {verdict} the required {_pct(s['required_share'])}; median lag-1 "
                f"autocorrelation of the residuals{_whitened(d)} {s['median_residual_autocorr']:+.3f}; "
                "median time "
                f"{s['median_time_s']:.1f} s per replicate. Command: `{d['provenance']['command']}`."
            ),
            table(
                (
                    "parameter",
                    "90 % interval held the truth",
                    "99 % region",
                    "inside",
                    "power vs 80 %",
                ),
                cov,
            ),
        ]
    return out


def _whitened(d: dict) -> str:
    """' (whitened)' when the study's analysis model has AR(1) noise: the check tests its innovations."""
    return " (whitened by the AR(1) model)" if d["summary"].get("noise_model") == "ar1" else ""


def write_page(out: Path) -> dict:
    page = gather(out)
    c.write_json(out / "fitcheck.json", page)
    c.write_markdown(out / "fitcheck.md", blocks(page))
    return page


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    p = c.parser("The fit check's verdict over independent datasets.")
    p.add_argument(
        "--config",
        default=None,
        help="a TOML of the truth and the analysis model (default: Exeter)",
    )
    p.add_argument(
        "--replicates", type=int_at_least("--replicates", 1), default=200, help="datasets (200)"
    )
    p.add_argument("--snr", default="10,20,30,40", help="SNR levels in dB, used in turn")
    p.add_argument("--case", default="deflection", help="deflection (default) or strain")
    p.add_argument(
        "--expect", default="fits", help="the verdict the data call for: fits (default) or misfit"
    )
    args = p.parse_args(argv)
    c.setup_logging(args.quiet)
    if args.case not in CASES:
        raise InputError("--case", args.case, "one of " + ", ".join(CASES))
    if args.expect not in EXPECTS:
        raise InputError("--expect", args.expect, "one of " + ", ".join(EXPECTS))
    levels = c.levels_of(args.snr)
    if not levels or any(s is None for s in levels):
        raise InputError("--snr", args.snr, "a comma list of SNR levels in dB (not clean)")
    run_study(args, argv, levels)
    write_page(Path(args.out))
    return 0


if __name__ == "__main__":
    c.entry(main)
