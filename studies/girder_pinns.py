"""Real girders, the PINN methods beside the reference: on each of a study's independent synthetic datasets,
the modal reference, the deep ensemble and the B-PINN; per method and inferred parameter, the replicates whose
central 90 % interval holds the truth (against the binomial 99 % acceptance region of a calibrated interval,
with its power against 80 % coverage), and per PINN method and segment its distance from the reference's
mean in reference sds and its sd ratio, the damaged segment's P(damaged), convergence and time.

Replicate i uses the same dataset as replicate i of `studies/girders.py` (the reference's coverage study) for
the same configuration, case, SNR and seed. One study per configuration, case and SNR in
<out>/girder_pinns/<name>-<case>-snr<S>.json, rewritten atomically after every replicate: an interrupted
study resumes from it, and each replicate records the commit that computed it. <out>/girder_pinns.md and
girder_pinns.json gather every study there.

    python studies/girder_pinns.py --config examples/damaged-girder.toml --snr 30 --replicates 20
"""

from __future__ import annotations

import hashlib
import json
import logging
import sys
import time
from pathlib import Path

import common as c
import numpy as np
from girders import (
    FIELD_OFFSET_M,
    FIELD_SPAN,
    LEVEL,
    POWER_AGAINST,
    REGION,
    coverage_rows,
    data_seed,
    field_metrics,
    field_rows,
    parameters,
)

from bayespinn.config import CASES, parse_snr, resolve, snr_label
from bayespinn.data.synthetic import simulate
from bayespinn.errors import InputError
from bayespinn.options import int_at_least
from bayespinn.pipeline import analyse, true_values_of
from bayespinn.report.document import Heading, Paragraph, table

log = logging.getLogger("studies.girder_pinns")

STUDY_SCHEMA = "bayespinn.studies.girder-pinns-study/1"
SCHEMA = "bayespinn.studies.girder-pinns/1"
METHODS = ("modal", "ensemble", "bpinn")
KEYS = ("modal_mcmc", "ensemble", "bpinn")
#: the CLI name of each summary key
METHOD_OF = dict(zip(KEYS, METHODS, strict=True))


def _segments(m: dict) -> tuple[np.ndarray, np.ndarray]:
    """(mean, sd) of each segment's EI [N m^2] in a summary entry."""
    segs = m.get("EI_segments") or [m["EI"]]
    return np.array([e["mean"] for e in segs]), np.array([e["sd"] for e in segs])


def replicate(cfg, snr: float | None, seed: int, i: int, opts, methods=METHODS) -> dict:
    seq = data_seed(seed, i)
    t0 = time.perf_counter()
    data = simulate(cfg, snr, seq)
    truth = true_values_of(cfg, seq)
    res = analyse(data, cfg, methods=list(methods), seed=seq, snr_db=snr, opts=opts, truth=truth)
    ms = res.summary["methods"]
    ref_mean, ref_sd = _segments(ms["modal_mcmc"])
    out = {
        "index": i,
        "methods": {},
        "time_s": time.perf_counter() - t0,
        **c.replicate_provenance(),
    }
    for k in (k for k in KEYS if METHOD_OF[k] in methods):
        m = ms[k]
        mean, sd = _segments(m)
        d = m.get("diagnostics", {})
        out["methods"][k] = {
            "hits": {kk: bool(ci[0] <= t <= ci[1]) for kk, (ci, t) in parameters(m, truth).items()},
            "p_damaged": [e["p_damaged"] for e in m.get("EI_segments") or []],
            "z": ((mean - ref_mean) / ref_sd).tolist(),
            "sd_ratio": (sd / ref_sd).tolist(),
            "converged": d.get("converged"),
            "rhat": d.get("rhat"),
            "ess_bulk": d.get("ess_bulk"),
            "fit": (m.get("fit_check") or {}).get("verdict"),
            "time_s": m.get("runtime_s"),
            "network_share": m.get("network_share"),
            **field_metrics(m, truth),
        }
    return out


def summarise(doc: dict) -> dict:
    recs = doc["records"]
    out = {"replicates": len(recs), "methods": {}}
    for k in KEYS:
        rs = [r["methods"][k] for r in recs if k in r.get("methods", {})]
        if not rs:
            continue
        z = np.array([r["z"] for r in rs], float)
        ratio = np.array([r["sd_ratio"] for r in rs], float)
        pd = np.array([r["p_damaged"] for r in rs if r["p_damaged"]], float)
        out["methods"][k] = {
            "coverage": coverage_rows(rs),
            "z_median_abs": np.median(np.abs(z), axis=0).tolist(),
            "z_max_abs": np.max(np.abs(z), axis=0).tolist(),
            "sd_ratio_median": np.median(ratio, axis=0).tolist(),
            "sd_ratio_range": [ratio.min(axis=0).tolist(), ratio.max(axis=0).tolist()],
            "p_damaged_min": pd.min(axis=0).tolist() if pd.size else None,
            "converged": int(sum(bool(r.get("converged")) for r in rs)),
            "fits": int(sum(r.get("fit") == "fits" for r in rs)),
            "median_time_s": float(np.median([r["time_s"] or np.nan for r in rs])),
            **_share(rs),
            **field_rows(rs),
        }
    return out


def _share(rs: list[dict]) -> dict:
    """The median `network_share` of a PINN method's replicates (recorded since the smooth field's study)."""
    v = [r["network_share"] for r in rs if r.get("network_share") is not None]
    return {"network_share_median": float(np.median(v))} if v else {}


def study_path(out: Path, config: Path, case: str, snr: float | None) -> Path:
    return out / "girder_pinns" / f"{config.stem}-{case}-snr{snr_label(snr)}.json"


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
                "members": args.members,
                # a subset of the methods is a study of its own (all three keep the key they had)
                **({} if list(args.chosen) == list(METHODS) else {"methods": list(args.chosen)}),
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
        replicates_asked=max(args.replicates, int(doc.get("replicates_asked") or 0)),
        provenance=c.provenance(
            __file__, argv, args, methods=[k for k in KEYS if METHOD_OF[k] in args.chosen]
        ),
    )
    opts = c.run_options(args, snr)
    return c.run_replicates(
        doc,
        path,
        args.replicates,
        lambda i: replicate(cfg, snr, args.seed, i, opts, args.chosen),
        summarise,
        "girder-pinns",
    )


def gather(out: Path) -> dict:
    folder = out / "girder_pinns"
    studies = c.gather_studies(folder, STUDY_SCHEMA, summarise)
    return {"schema": SCHEMA, "studies": studies}


def _fmt(xs, f="{:.2f}") -> str:
    return ", ".join(f.format(x) for x in xs)


def blocks(page: dict) -> list:
    out = [
        Heading("Real girders: the PINN methods beside the reference", 1),
        Paragraph(
            "Each study: independent synthetic datasets of one girder configuration (the same datasets as the "
            "reference's study in girders.md), the modal reference and the deep ensemble, the B-PINN or both on "
            "each. "
            f"Per method and parameter the replicates whose central {100 * LEVEL:.0f} % interval holds the "
            f"truth against the binomial {100 * REGION:.0f} % acceptance region of a calibrated interval, with "
            f"the power of that check to reject {100 * POWER_AGAINST:.0f} % coverage; per PINN method and "
            "segment, |mean - reference mean| in reference sds (median and largest) and the sd ratio (median "
            "and range). Command: `python studies/girder_pinns.py --config FILE --snr S --replicates N` "
            "(resumable)."
        ),
    ]
    names = {"modal_mcmc": "modal reference", "ensemble": "deep ensemble", "bpinn": "B-PINN"}
    for name, d in page["studies"].items():
        s = d["summary"]
        rows = []
        for k, v in s["methods"].items():
            for p, row in v["coverage"].items():
                rows.append(
                    (
                        names[k],
                        p,
                        f"{row['hits']} / {row['replicates']}",
                        f"[{row['region'][0]}, {row['region'][1]}]",
                        "yes" if row["inside"] else "**no**",
                        f"{row['power_vs_80pct']:.2f}",
                    )
                )
        text = []
        for k in ("ensemble", "bpinn"):
            v = s["methods"].get(k)
            if not v:
                continue
            text.append(
                f"{names[k]}: |z| median {_fmt(v['z_median_abs'])}, largest {_fmt(v['z_max_abs'])}; "
                f"sd ratio median {_fmt(v['sd_ratio_median'])}, from {_fmt(v['sd_ratio_range'][0])} to "
                f"{_fmt(v['sd_ratio_range'][1])}; "
                + (
                    f"smallest P(damaged) {_fmt(v['p_damaged_min'], '{:.3f}')}; "
                    if v["p_damaged_min"]
                    else ""
                )
                + f"{v['converged']} of {s['replicates']} "
                f"converged, {v['fits']} fit; median {v['median_time_s']:.0f} s"
                + (
                    f"; the network carries a median {v['network_share_median']:.2g} of the fitted "
                    "response's energy beyond the enrichment."
                    if "network_share_median" in v
                    else "."
                )
            )
        for k, v in s["methods"].items():
            f = v.get("field")
            if f:
                text.append(
                    f"Smooth EI field, {names[k]}: the 90 % band holds the true EI(x) over at least "
                    f"{100 * FIELD_SPAN:.0f} % of the span on {f['band_holds']} of {f['replicates']} "
                    f"(median share {f['coverage_median']:.2f}, smallest {f['coverage_min']:.2f}); the "
                    f"posterior mean's deepest point within {FIELD_OFFSET_M:g} m of the truth's on "
                    f"{f['deepest_within']} (median offset {f['offset_median_m']:.2f} m)."
                )
        fresh = c.commits_sentence(d)
        asked = d.get("replicates_asked") or s["replicates"]
        if s["replicates"] < asked:
            fresh += f"; partial: {s['replicates']} of the {asked} planned datasets"
        out += [
            Heading(f"{name}: {d['config']}, {d['case']}, SNR {snr_label(d['snr_db'])}", 2),
            table(("method", "parameter", "hits", "99 % region", "inside", "power vs 80 %"), rows),
            Paragraph(
                f"{s['replicates']} replicates ({fresh}). Per segment (a smooth field: its span-equivalent EI), "
                "left to right: " + " ".join(text) + f" Command: `{d['provenance']['command']}`."
            ),
        ]
    return out


def write_page(out: Path) -> dict:
    page = gather(out)
    c.write_json(out / "girder_pinns.json", page)
    c.write_markdown(out / "girder_pinns.md", blocks(page))
    return page


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    p = c.parser("Real girders: the PINN methods beside the reference, over independent datasets.")
    p.add_argument(
        "--config", required=True, help="a girder TOML ([beam] EI per segment, [model], ...)"
    )
    p.add_argument(
        "--replicates", type=int_at_least("--replicates", 1), default=20, help="datasets (20)"
    )
    p.add_argument("--snr", default="30", help="SNR in dB (default 30)")
    p.add_argument("--case", default="deflection", help="deflection (default) or strain")
    args = p.parse_args(argv)
    c.setup_logging(args.quiet)
    if args.case not in CASES:
        raise InputError("--case", args.case, "one of " + ", ".join(CASES))
    args.chosen = c.methods_of(args.methods)
    if "modal" not in args.chosen or len(args.chosen) < 2 or set(args.chosen) - set(METHODS):
        raise InputError(
            "--methods",
            args.methods,
            "the reference and one or both PINN methods (modal,ensemble,bpinn; modal,ensemble; modal,bpinn)",
        )
    snr = parse_snr(args.snr)
    run_study(args, argv, snr)
    write_page(Path(args.out))
    return 0


if __name__ == "__main__":
    c.entry(main)
