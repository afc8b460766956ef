"""Real girders: does the reference posterior of EI per segment, the support springs and the load factor mean
what it says? Coverage of every inferred parameter over independent synthetic datasets.

Replicate i of a study simulates the configuration's true girder (`[beam] EI` per segment, its springs, a
crossing's load factor drawn with `vehicle.load_rel_sd`) at the SNR with its own seed, runs the modal
reference (`--method modal`: the girder posterior whenever `[model]` asks for more than a uniform pinned
girder), and records, for each parameter with a known truth, whether its central 90 % interval holds it;
and each segment's P(damaged); for a smooth EI field (`[model] EI_field = "smooth"`) the share of the
span over which the 90 % band of EI(x) holds the true EI(x), and how far the posterior mean's deepest point
lies from the truth's. Over the replicates: hits per parameter against the binomial 99 % acceptance
region of a calibrated interval, with the power of that check against 80 % coverage stated beside it.

One study per configuration, case and SNR in <out>/girders/<name>-<case>-snr<S>.json, rewritten atomically
after every replicate: an interrupted study resumes from it; replicates computed by other code are run
again. <out>/girders.md and girders.json gather every study there.

    python studies/girders.py --config examples/damaged-girder.toml --snr 30 --replicates 100
    python studies/girders.py --config examples/damaged-girder.toml --case strain --snr 30 --replicates 100
    python studies/girders.py --config examples/smooth-loss.toml --snr 30 --replicates 20
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
from scipy import stats

from bayespinn.config import CASES, parse_snr, resolve, snr_label
from bayespinn.data.synthetic import simulate
from bayespinn.errors import InputError
from bayespinn.options import int_at_least
from bayespinn.pipeline import analyse, true_values_of
from bayespinn.report.document import Heading, Paragraph, table

log = logging.getLogger("studies.girders")

STUDY_SCHEMA = "bayespinn.studies.girders-study/1"
SCHEMA = "bayespinn.studies.girders/1"
LEVEL = 0.9
#: the acceptance region's probability, and the miscalibrated coverage its power is stated against
REGION, POWER_AGAINST = 0.99, 0.8
#: a smooth field's criteria: the share of the span its 90 % band must hold the true EI(x) over, and how
#: far the posterior mean's deepest point may lie from the truth's
FIELD_SPAN, FIELD_OFFSET_M = 0.9, 1.0


def data_seed(seed: int, i: int) -> np.random.SeedSequence:
    """Replicate i's seed (data and analysis) in a study with root seed `seed`."""
    return np.random.SeedSequence(int(seed), spawn_key=(zlib.crc32(b"girders"), int(i)))


def region(n: int, level: float = LEVEL) -> tuple[int, int]:
    """The central binomial acceptance region of hits for a calibrated interval over n replicates."""
    lo, hi = stats.binom.ppf([(1 - REGION) / 2, 1 - (1 - REGION) / 2], n, level)
    return int(lo), int(hi)


def power(n: int, level: float = LEVEL, against: float = POWER_AGAINST) -> float:
    """P(hits outside the region) when the interval's true coverage is `against`."""
    lo, hi = region(n, level)
    return float(stats.binom.cdf(lo - 1, n, against) + stats.binom.sf(hi, n, against))


def parameters(summary_method: dict, truth: dict) -> dict[str, tuple[list, float]]:
    """{parameter: (ci90, truth)} of every inferred parameter whose truth is known and finite."""
    out = {"EI": (summary_method["EI"]["ci90"], truth["EI"])}
    for i, e in enumerate(summary_method.get("EI_segments") or []):
        out[f"EI_segments[{i}]"] = (e["ci90"], (truth.get("EI_segments") or [None] * 99)[i])
    for i, k in enumerate(summary_method.get("rotational_stiffness") or []):
        t = (truth.get("rotational_stiffness") or [None, None])[i]
        out[f"rotational_stiffness[{i}]"] = (k["ci90"], t)
    if summary_method.get("load_factor"):
        out["load_factor"] = (summary_method["load_factor"]["ci90"], truth.get("load_factor"))
    return {k: v for k, v in out.items() if v[1] is not None and np.isfinite(v[1])}


def field_metrics(summary_method: dict, truth: dict) -> dict:
    """A smooth field's band and deepest point against the truth: the share of the span where the 90 % band
    holds the true EI(x), and how far the posterior mean's deepest point lies from the truth's [m]; {} for a
    girder without a field."""
    m = summary_method
    if "EI_x" not in m or "EI_x" not in truth:
        return {}
    x, mean = np.asarray(m["EI_x"]["x"]), np.asarray(m["EI_x"]["mean"])
    true = np.asarray(truth["EI_x"]["EI"])
    return {
        "EI_x_coverage": m["EI_x"]["coverage"],
        "deepest_offset_m": float(abs(x[np.argmin(mean)] - x[np.argmin(true)])),
    }


def replicate(cfg, snr: float | None, seed: int, i: int, opts) -> dict:
    seq = data_seed(seed, i)
    t0 = time.perf_counter()
    data = simulate(cfg, snr, seq)
    truth = true_values_of(cfg, seq)
    res = analyse(data, cfg, methods=["modal"], seed=seq, snr_db=snr, opts=opts, truth=truth)
    m = res.summary["methods"]["modal_mcmc"]
    hits = {k: bool(ci[0] <= t <= ci[1]) for k, (ci, t) in parameters(m, truth).items()}
    field = field_metrics(m, truth)
    return {
        "index": i,
        "hits": hits,
        "p_damaged": [e["p_damaged"] for e in m.get("EI_segments") or []],
        "EI_mean": m["EI"]["mean"],
        "EI_sd": m["EI"]["sd"],
        "rhat": m.get("diagnostics", {}).get("rhat"),
        "converged": m.get("diagnostics", {}).get("converged"),
        "fit_check": (m.get("fit_check") or {}).get("verdict"),
        "time_s": time.perf_counter() - t0,
        **field,
        **c.replicate_provenance(),
    }


def coverage_rows(recs: list[dict]) -> dict:
    """Per parameter over the records' `hits`: hits, replicates, the 99 % region, inside or not, power."""
    rows = {}
    for k in sorted({k for r in recs for k in r["hits"]}):
        h = [r["hits"][k] for r in recs if k in r["hits"]]
        lo, hi = region(len(h))
        rows[k] = {
            "replicates": len(h),
            "hits": int(sum(h)),
            "region": [lo, hi],
            "inside": bool(lo <= sum(h) <= hi),
            "power_vs_80pct": power(len(h)),
        }
    return rows


def summarise(doc: dict) -> dict:
    recs = doc["records"]
    n = len(recs)
    rows = coverage_rows(recs)
    pd = np.array([r["p_damaged"] for r in recs if r["p_damaged"]], float)
    return {
        "replicates": n,
        "coverage": rows,
        "p_damaged_median": np.median(pd, axis=0).tolist() if pd.size else None,
        "p_damaged_min": pd.min(axis=0).tolist() if pd.size else None,
        "converged": int(sum(bool(r.get("converged")) for r in recs)),
        # the modal reference's fit check per replicate (recorded since the smooth field's strain study)
        "fit_check": {
            v: int(sum(r.get("fit_check") == v for r in recs)) for v in ("fits", "misfit")
        },
        "median_time_s": float(np.median([r["time_s"] for r in recs])) if recs else None,
        **field_rows(recs),
    }


def field_rows(recs: list[dict]) -> dict:
    """For a smooth field: replicates whose 90 % band holds the true EI(x) over at least FIELD_SPAN of the
    span, and whose posterior mean's deepest point lies within FIELD_OFFSET_M of the truth's."""
    f = [r for r in recs if "EI_x_coverage" in r]
    if not f:
        return {}
    cov = np.array([r["EI_x_coverage"] for r in f])
    off = np.array([r["deepest_offset_m"] for r in f])
    return {
        "field": {
            "replicates": len(f),
            "band_holds": int(np.sum(cov >= FIELD_SPAN)),
            "deepest_within": int(np.sum(off <= FIELD_OFFSET_M)),
            "coverage_min": float(cov.min()),
            "coverage_median": float(np.median(cov)),
            "offset_median_m": float(np.median(off)),
            "offset_max_m": float(off.max()),
        }
    }


def study_path(out: Path, config: Path, case: str, snr: float | None) -> Path:
    return out / "girders" / f"{config.stem}-{case}-snr{snr_label(snr)}.json"


def run_study(args, argv, snr) -> dict:
    cfg = resolve(args.case, args.config)
    if cfg.ideal and cfg.beam.ideal:
        raise InputError(
            "--config", str(args.config), "a real girder (EI per segment, springs or load)"
        )
    key = hashlib.sha256(
        json.dumps(
            {
                "cfg": c.jsonable(cfg.identity()),
                "snr": snr,
                "seed": args.seed,
                "profile": args.profile,
            },
            sort_keys=True,
        ).encode()
    ).hexdigest()[:16]
    path = study_path(Path(args.out), Path(args.config), args.case, snr)
    doc = c.open_study(path, STUDY_SCHEMA, key)
    doc.update(
        config=str(args.config),
        config_values=c.jsonable(cfg.to_dict()),
        case=args.case,
        snr_db=snr,
        seed=args.seed,
        level=LEVEL,
        provenance=c.provenance(__file__, argv, args, methods=["modal_mcmc"]),
    )
    opts = c.run_options(args, snr)
    return c.run_replicates(
        doc,
        path,
        args.replicates,
        lambda i: replicate(cfg, snr, args.seed, i, opts),
        summarise,
        "girders",
    )


def gather(out: Path) -> dict:
    """Every girder study under <out>/girders, summarised, with the commits its replicates ran at."""
    studies = c.gather_studies(out / "girders", STUDY_SCHEMA, summarise)
    return {"schema": SCHEMA, "studies": studies}


def blocks(page: dict) -> list:
    out = [
        Heading("Real girders: coverage of the reference posterior", 1),
        Paragraph(
            "Each study: independent synthetic datasets of one girder configuration (the truth: EI per "
            "segment, springs at the supports, the crossing's load factor), the modal reference on each; per "
            f"parameter the replicates whose central {100 * LEVEL:.0f} % interval holds the truth, against the "
            f"binomial {100 * REGION:.0f} % acceptance region of a calibrated interval, and the power of that "
            f"check to reject {100 * POWER_AGAINST:.0f} % coverage. Command: `python studies/girders.py "
            "--config FILE --snr S --replicates N` (resumable)."
        ),
    ]
    for name, d in page["studies"].items():
        s = d["summary"]
        rows = [
            (
                k,
                f"{v['hits']} / {v['replicates']}",
                f"[{v['region'][0]}, {v['region'][1]}]",
                "yes" if v["inside"] else "**no**",
                f"{v['power_vs_80pct']:.2f}",
            )
            for k, v in s["coverage"].items()
        ]
        pd_med = ", ".join(f"{p:.3f}" for p in (s["p_damaged_median"] or []))
        pd_min = ", ".join(f"{p:.3f}" for p in (s["p_damaged_min"] or []))
        out += [
            Heading(f"{name}: {d['config']}, {d['case']}, SNR {snr_label(d['snr_db'])}", 2),
            table(("parameter", "hits", "99 % region", "inside", "power vs 80 %"), rows),
            Paragraph(
                f"{s['replicates']} replicates ({c.commits_sentence(d)}), "
                f"{s['converged']} converged; median time {s['median_time_s']:.1f} s per replicate"
                + (
                    f"; P(damaged) per segment, median {pd_med}, smallest {pd_min}"
                    if pd_med
                    else ""
                )
                + f". Command: `{d['provenance']['command']}`."
            ),
        ]
        if s.get("field"):
            f = s["field"]
            out.append(
                Paragraph(
                    f"Smooth EI field: the 90 % band of EI(x) holds the truth over at least "
                    f"{100 * FIELD_SPAN:.0f} % of the span on {f['band_holds']} of {f['replicates']} "
                    f"replicates (share of the span held: median {f['coverage_median']:.2f}, smallest "
                    f"{f['coverage_min']:.2f}); the posterior mean's deepest point within "
                    f"{FIELD_OFFSET_M:g} m of the truth's on {f['deepest_within']} (offset median "
                    f"{f['offset_median_m']:.2f} m, largest {f['offset_max_m']:.2f} m)."
                )
            )
    return out


def write_page(out: Path) -> dict:
    page = gather(out)
    c.write_json(out / "girders.json", page)
    c.write_markdown(out / "girders.md", blocks(page))
    return page


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    p = c.parser(
        "Coverage of the reference posterior of real girders (EI per segment, springs, load)."
    )
    p.add_argument(
        "--config", required=True, help="a girder TOML ([beam] EI per segment, [model], ...)"
    )
    p.add_argument(
        "--replicates", type=int_at_least("--replicates", 1), default=100, help="datasets (100)"
    )
    p.add_argument("--snr", default="30", help="SNR in dB (default 30)")
    p.add_argument("--case", default="deflection", help="deflection (default) or strain")
    args = p.parse_args(argv)
    c.setup_logging(args.quiet)
    if args.case not in CASES:
        raise InputError("--case", args.case, "one of " + ", ".join(CASES))
    snr = parse_snr(args.snr)
    run_study(args, argv, snr)
    write_page(Path(args.out))
    return 0


if __name__ == "__main__":
    c.entry(main)
