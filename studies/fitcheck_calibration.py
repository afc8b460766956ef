"""How often does the fit check cry wolf? Its false-alarm rate per method, case and SNR on well-specified data.

Replicate i of a cell (method, case, SNR) simulates the Exeter girder (the preset of the case, or
`--config`) at that SNR with its own seed, analyses it with the same model by the method, and records the
fit check's verdict, combined p-value and reasons. Every dataset is one the model describes, so every
`misfit` is a false alarm: the count over n replicates should be Binomial(n, FALSE_ALARM). Each cell's
count is compared with the binomial acceptance region at `--false-failure` (two-sided; default 0.01, i.e.
a calibrated check falls outside it in 1 % of studies).

Cells run in turn, replicate by replicate (replicate 0 of every cell, then 1, ...), so a study stopped by
`--max-minutes` holds about the same number of replicates in every cell; each cell's JSON under <out> is
rewritten atomically after every replicate, and a rerun with the same settings resumes from it. The
records carry the command, the seed, the git commit, package versions and the machine.

    python studies/fitcheck_calibration.py --methods modal --case deflection,strain --snr 10,40 \\
        --replicates 200 --out reports/paper/fitcheck

The PINN methods (`--methods ensemble,bpinn`) take minutes a replicate: run them where that is affordable.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import platform
import subprocess
import sys
import time
import zlib
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path

import numpy as np
from scipy import stats

from bayespinn import seeding
from bayespinn.config import CASES, resolve
from bayespinn.data.measurements import atomic_write_text
from bayespinn.data.synthetic import simulate
from bayespinn.errors import InputError
from bayespinn.options import RunOptions
from bayespinn.pipeline import analyse
from bayespinn.uq import fitcheck
from bayespinn.uq.sampler import MCMCSettings

SCHEMA = "bayespinn.studies.fitcheck-calibration/1"
METHODS = ("modal", "ensemble", "bpinn")
PACKAGES = ("numpy", "scipy", "torch", "emcee")
REPO = Path(__file__).resolve().parents[1]


def provenance(argv: list[str], seed: int) -> dict:
    """Command, seed, git commit (and whether the code had uncommitted changes), versions, machine."""

    def git(*a):
        try:
            r = subprocess.run(["git", *a], cwd=REPO, capture_output=True, text=True, timeout=5)
        except (OSError, subprocess.SubprocessError):
            return None
        return r.stdout.strip() if r.returncode == 0 else None

    versions = {"python": platform.python_version()}
    for pkg in ("bayespinn", *PACKAGES):
        try:
            versions[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            versions[pkg] = None
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    dirty = git("status", "--porcelain", "--untracked-files=no", "--", "bayespinn", "studies")
    return {
        "command": ["python", "studies/fitcheck_calibration.py", *argv],
        "seed": seed,
        "git_commit": git("rev-parse", "HEAD"),
        "git_dirty": None if dirty is None else bool(dirty),
        "versions": versions,
        "machine": {"cpus": os.cpu_count(), "cpu_model": cpu, "platform": platform.platform()},
        "started": datetime.now(UTC).isoformat(timespec="seconds"),
    }


def region(n: int, rate: float, false_failure: float) -> list[int]:
    """The two-sided binomial acceptance region of a count of n trials at `rate`."""
    lo = int(stats.binom.ppf(false_failure / 2, n, rate))
    hi = int(stats.binom.isf(false_failure / 2, n, rate))
    return [lo, hi]


def summarise(records: list[dict], false_failure: float) -> dict:
    n = len(records)
    k = sum(r["verdict"] == "misfit" for r in records)
    rate = fitcheck.FALSE_ALARM
    lo, hi = region(n, rate, false_failure) if n else (0, 0)
    reasons: dict[str, int] = {}
    for r in records:
        for x in r["reasons"] or []:
            reasons[x.split(":")[0]] = reasons.get(x.split(":")[0], 0) + 1
    return {
        "replicates": n,
        "false_alarms": int(k),
        "rate": k / n if n else None,
        "stated_rate": rate,
        "region": [lo, hi],
        "false_failure": false_failure,
        "inside": bool(lo <= k <= hi) if n else None,
        "unchecked": int(sum(r["verdict"] is None for r in records)),
        "reasons": reasons,
        "median_time_s": float(np.median([r["time_s"] for r in records])) if n else None,
    }


class Cell:
    """One (method, case, SNR): its configuration, record file and replicates so far."""

    def __init__(self, method, case, snr, args, argv):
        self.method, self.case, self.snr = method, case, snr
        self.cfg = resolve(case, args.config)
        stem = Path(args.config).stem if args.config else "exeter"
        name = f"calibration-{method}-{stem}-{case}-snr{snr:g}"
        self.path = Path(args.out) / f"{name}.json"
        key = hashlib.sha256(
            json.dumps(
                [self.cfg.to_dict(), method, snr, args.seed, args.mcmc], sort_keys=True, default=str
            ).encode()
        ).hexdigest()[:16]
        self.doc = {
            "schema": SCHEMA,
            "name": name,
            "key": key,
            "method": method,
            "case": case,
            "snr_db": snr,
            "config": args.config,
            "mcmc": args.mcmc if method == "modal" else None,
            "provenance": provenance(argv, args.seed),
            "records": [],
        }
        if self.path.exists():
            old = json.loads(self.path.read_text())
            if old.get("key") == key:
                self.doc["records"] = old["records"]
                self.doc["provenance_earlier"] = old.get("provenance")
        self.seed, self.false_failure = args.seed, args.false_failure
        mcmc = MCMCSettings.for_coverage() if args.mcmc == "coverage" else None
        self.opts = RunOptions(snr_db=snr, mcmc=mcmc if method == "modal" else None)

    def done(self) -> set[int]:
        return {r["index"] for r in self.doc["records"]}

    def run(self, i: int) -> dict:
        tag = zlib.crc32(f"{self.method}/{self.case}/{self.snr:g}".encode())
        seq = np.random.SeedSequence(
            self.seed, spawn_key=(zlib.crc32(b"fitcheck-calibration"), tag, int(i))
        )
        t0 = time.perf_counter()
        data = simulate(self.cfg, self.snr, seq)
        res = analyse(
            data,
            self.cfg,
            methods=[self.method],
            seed=seeding.int_seed(seq) % (2**31),
            snr_db=self.snr,
            opts=dataclasses.replace(self.opts),
        )
        (m,) = res.summary["methods"].values()
        fc = m.get("fit_check") or {}
        rec = {
            "index": i,
            "verdict": fc.get("verdict"),
            "p_value": fc.get("p_value"),
            "p_values": fc.get("p_values"),
            "reasons": fc.get("reasons"),
            "residual_autocorr": fc.get("residual_autocorr"),
            "time_s": time.perf_counter() - t0,
            "git_commit": self.doc["provenance"]["git_commit"],
        }
        self.doc["records"].append(rec)
        self.doc["records"].sort(key=lambda r: r["index"])
        self.doc["summary"] = summarise(self.doc["records"], self.false_failure)
        atomic_write_text(self.path, json.dumps(self.doc, indent=1) + "\n")
        return rec


def write_table(out: Path) -> None:
    """<out>/calibration.md: one row per cell recorded under <out>."""
    rows = []
    for f in sorted(out.glob("calibration-*.json")):
        doc = json.loads(f.read_text())
        if doc.get("schema") != SCHEMA or not doc.get("records"):
            continue
        s, prov = doc["summary"], doc["provenance"]
        rows.append(
            f"| {doc['method']} | {doc['case']} | {doc['snr_db']:g} | {s['false_alarms']} / "
            f"{s['replicates']} | [{s['region'][0]}, {s['region'][1]}] | "
            f"{'yes' if s['inside'] else '**no**'} | {s['median_time_s']:.0f} s | "
            f"{(prov.get('git_commit') or 'n/a')[:10]} |"
        )
    if not rows:
        return
    text = (
        "# The fit check's false alarms on well-specified data\n\n"
        "Each row: datasets the model describes, analysed by the method; every `misfit` is a false "
        f"alarm, stated rate {fitcheck.FALSE_ALARM:g}; the two-sided binomial acceptance region at the "
        "false-failure rate in each record (default 0.01). Command: `python "
        "studies/fitcheck_calibration.py --methods M --case C --snr LEVELS --replicates N`.\n\n"
        "| method | case | SNR (dB) | false alarms | region | inside | median time | commit |\n"
        "|---|---|---|---|---|---|---|---|\n" + "\n".join(rows) + "\n"
    )
    atomic_write_text(out / "calibration.md", text)


def _list(text: str, allowed: tuple, flag: str) -> list[str]:
    out = [x.strip() for x in text.split(",") if x.strip()]
    bad = [x for x in out if x not in allowed]
    if not out or bad:
        raise InputError(flag, text, "a comma list of " + ", ".join(allowed))
    return out


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--methods", default="modal", help="comma list of methods (modal)")
    p.add_argument("--case", default="deflection,strain", help="comma list of cases")
    p.add_argument("--snr", default="10,40", help="comma list of SNR levels in dB (10,40)")
    p.add_argument("--config", default=None, help="a TOML of the girder (default: the preset)")
    p.add_argument("--replicates", type=int, default=200, help="datasets per cell (200)")
    p.add_argument("--seed", type=int, default=0, help="root seed (0)")
    p.add_argument("--false-failure", type=float, default=0.01, help="of the acceptance region")
    p.add_argument(
        "--mcmc", default="coverage", help="the modal reference's sampler: coverage|profile"
    )
    p.add_argument("--max-minutes", type=float, default=None, help="stop (resumably) after this")
    p.add_argument("--out", default="reports/paper/fitcheck", help="folder of the records")
    p.add_argument("--quiet", action="store_true")
    args = p.parse_args(argv)
    try:
        methods = _list(args.methods, METHODS, "--methods")
        cases = _list(args.case, CASES, "--case")
        try:
            levels = [float(s) for s in args.snr.split(",")]
        except ValueError:
            raise InputError("--snr", args.snr, "a comma list of SNR levels in dB") from None
        if args.replicates < 1:
            raise InputError("--replicates", args.replicates, "an integer >= 1")
        if not 0 < args.false_failure < 1:
            raise InputError("--false-failure", args.false_failure, "a number in (0, 1)")
        if args.mcmc not in ("coverage", "profile"):
            raise InputError("--mcmc", args.mcmc, "coverage or profile")
        cells = [Cell(m, c, s, args, argv) for m in methods for c in cases for s in levels]
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    t_end = None if args.max_minutes is None else time.monotonic() + 60 * args.max_minutes
    for i in range(args.replicates):
        for cell in cells:
            if i in cell.done():
                continue
            if t_end is not None and time.monotonic() > t_end:
                break
            rec = cell.run(i)
            if not args.quiet:
                print(
                    f"{cell.doc['name']} #{i}: {rec['verdict']} p={rec['p_value']:.3g} "
                    f"{rec['reasons']} {rec['time_s']:.1f}s",
                    flush=True,
                )
    write_table(Path(args.out))
    for cell in cells:
        s = cell.doc.get("summary") or summarise(cell.doc["records"], args.false_failure)
        print(
            f"{cell.doc['name']}: {s['false_alarms']}/{s['replicates']} false alarms, region "
            f"{s['region']} at false-failure {s['false_failure']:g}: "
            f"{'inside' if s['inside'] else 'OUTSIDE'}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
