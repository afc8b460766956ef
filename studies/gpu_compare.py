"""Set a GPU coverage study beside the CPU studies of the same datasets.

    python studies/gpu_compare.py reports/gpu/ensemble-cuda-snr30.json [--many reports/gpu/many_networks.json]

The GPU study (`studies/gpu_check.sh`) and the committed CPU studies in reports/paper/coverage share
their datasets (same seed, SNR and replicate index). Against the modal reference of the same data it
reports the sd of z and the median sd ratio (`coverage.paired_with_reference`), and each one's ratio to the
CPU ensemble study's on the datasets both studies ran (a GPU study extended past the CPU study's replicates
is also set against the reference on all of its own); hits against the binomial 99 % region; with --many,
the many_networks rows. Writes <study>.compare.json beside the study and prints a Markdown summary.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bayespinn.provenance import commits  # noqa: E402
from bayespinn.uq.coverage import binomial_acceptance, paired_with_reference  # noqa: E402

#: the tolerance on sd of z and median sd ratio against the CPU study's
TOLERANCE = 0.2


def _only(doc: dict, indices: set[int]) -> dict:
    """The study with only the replicates of `indices`."""
    return dict(doc, records=[r for r in doc["records"] if r["index"] in indices])


def compare(study: dict, cpu_dir: Path) -> dict:
    snr = study["snr_db"]
    ref = json.loads((cpu_dir / f"modal_mcmc-snr{snr:g}.json").read_text())
    cpu = json.loads((cpu_dir / f"{study['method']}-snr{snr:g}.json").read_text())
    both = {r["index"] for r in study["records"]} & {r["index"] for r in cpu["records"]}
    gpu_all = paired_with_reference(study, ref)
    gpu_pair = paired_with_reference(_only(study, both), ref)
    cpu_pair = paired_with_reference(_only(cpu, both), ref)
    if gpu_all is None or gpu_pair is None or cpu_pair is None:
        raise SystemExit(
            "the studies do not share their datasets (seed, SNR, case, truth, seeding)"
        )
    lo, hi = binomial_acceptance(study["replicates"], study["level"])
    out = {
        "study": {k: study[k] for k in ("method", "snr_db", "replicates", "hits", "runtime_s")},
        "acceptance_99": [lo, hi],
        "hits_inside": lo <= study["hits"] <= hi,
        "shared_datasets": len(both),
        "gpu_vs_reference": gpu_pair,
        "cpu_vs_reference": cpu_pair,
        "gpu_all_vs_reference": gpu_all,
        "cpu_study_commits": commits(cpu.get("records") or []),
        "tolerance": TOLERANCE,
    }
    for k in ("sd_z", "median_sd_ratio"):
        r = gpu_pair[k] / cpu_pair[k]
        out[f"{k}_ratio_to_cpu"] = r
        out[f"{k}_within_tolerance"] = abs(r - 1) <= TOLERANCE
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("study", type=Path)
    ap.add_argument("--cpu", type=Path, default=ROOT / "reports" / "paper" / "coverage")
    ap.add_argument("--many", type=Path, help="many_networks.json from studies/gpu_check.sh")
    a = ap.parse_args(argv)
    study = json.loads(a.study.read_text())
    res = compare(study, a.cpu)
    if a.many:
        res["many_networks"] = json.loads(a.many.read_text())
    dest = a.study.with_name(a.study.name.removesuffix(".json") + ".compare.json")
    dest.write_text(json.dumps(res, indent=2) + "\n")
    g, c = res["gpu_vs_reference"], res["cpu_vs_reference"]
    print(f"On the {res['shared_datasets']} datasets both studies ran:\n")
    print("| | GPU | CPU study | GPU / CPU |\n|---|---|---|---|")
    print(f"| sd of z | {g['sd_z']:.2f} | {c['sd_z']:.2f} | {res['sd_z_ratio_to_cpu']:.2f} |")
    print(
        f"| median sd ratio | {g['median_sd_ratio']:.2f} | {c['median_sd_ratio']:.2f} | "
        f"{res['median_sd_ratio_ratio_to_cpu']:.2f} |"
    )
    print(
        f"| hits | {g['hits']} / {g['datasets']} | {c['hits']} / {c['datasets']} | "
        f"reference {c['reference_hits']} |"
    )
    a = res["gpu_all_vs_reference"]
    print(
        f"\nThe whole GPU study: {study['hits']} / {study['replicates']} hits (99 % region "
        f"{res['acceptance_99']}), sd of z {a['sd_z']:.2f}, median sd ratio {a['median_sd_ratio']:.2f}"
    )
    print(f"\nGPU study runtime {study['runtime_s']:.0f} s; written {dest}")
    for r in (res.get("many_networks") or {}).get("rows", []):
        print(r)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
