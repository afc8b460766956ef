"""Re-run every study the results page cites, with today's code, then regenerate the pages.

Each job is one command that rewrites one committed record (a coverage study, a family of bridges, a girder
or fit-check study, one of the paper's tables, a run folder under reports/records). Before starting, each
job's expected time is printed: the time its record took when it was computed, on the machine the record
names. The re-run is resumable: `reports/.rerun-state.json` remembers the jobs finished, and a job stopped
half-way goes on from its study's checkpoint or file when the same command is given again. A study that
resumes from its own file is started afresh once (its old file removed: the old figures stay in git
history), so that every replicate of the new record is today's. At the end the study pages
(`studies/render.py`) and docs/results.md (`studies/results_page.py`) are regenerated.

    python studies/rerun.py --dry-run            # list the jobs and their expected times
    python studies/rerun.py --only family-deflection-snr30
    python studies/rerun.py                      # everything (many hours on a 2-core CPU)
    python studies/rerun.py --restart            # forget which jobs finished
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
STATE = ROOT / "reports" / ".rerun-state.json"
PAPER = "reports/paper"
PY = sys.executable


@dataclass(frozen=True)
class Job:
    """One command that rewrites `record` (only its entry `key`, when given); `fresh`: files removed before
    its first start."""

    name: str
    command: tuple[str, ...]
    record: str
    fresh: tuple[str, ...] = field(default=())
    key: str | None = None


def _load(rel: str) -> dict:
    return json.loads((ROOT / rel).read_text(encoding="utf-8"))


def _coverage_jobs() -> list[Job]:
    """One per row of each coverage table (the Exeter deflection one, and one per other girder or case), at
    its replicate count, started afresh (no --resume)."""
    from bayespinn import methods

    out = []
    for page in sorted((ROOT / PAPER).glob("coverage*.json")):
        doc = _load(f"{PAPER}/{page.name}")
        which = ("--config", doc["config"], "--case", doc["case"]) if doc.get("config") else ()
        tag = page.stem.removeprefix("coverage")
        for row in doc["rows"]:
            name = methods.by_key(row["method"]).name
            snr = f"{row['snr_db']:g}"
            study = f"{PAPER}/{row['file']}"
            out.append(
                Job(
                    f"coverage{tag}-{name}-snr{snr}",
                    (PY, "studies/coverage.py", *which, "--methods", name, "--snr", snr,
                     "--replicates", f"{name}={row['replicates']}", "--out", PAPER, "--quiet"),
                    study,
                    (study + ".partial.jsonl",),
                )
            )  # fmt: skip
    return out


#: the family studies the page cites: (case, SNR, bridges)
FAMILY = (("deflection", "30", 24), ("deflection", "10", 12), ("strain", "30", 6))
#: the held-out family's studies: (case, SNR, bridges)
HELD_OUT = (("deflection", "30", 24), ("strain", "30", 12))
#: the girder studies: (config, case, SNR, replicates)
GIRDERS = (
    ("bearings", "deflection", "30", 100),
    ("damaged-girder", "deflection", "30", 100),
    ("damaged-girder", "strain", "30", 100),
    ("uncertain-load", "deflection", "40", 100),
    ("smooth-loss", "deflection", "30", 20),
    ("smooth-loss", "strain", "30", 10),
)
#: the fit-check studies: (config or None for the Exeter preset, case, SNR levels, replicates, expect)
FITCHECK = (
    (None, "deflection", "10,20,30,40", 200, "fits"),
    (None, "strain", "10,20,30,40", 200, "fits"),
    ("bearings-as-pinned", "deflection", "30", 100, "misfit"),
    ("damaged-as-uniform", "strain", "30", 100, "misfit"),
    ("ar1-strain", "strain", "20", 100, "misfit"),
    ("ar1-strain-ar1", "strain", "20", 100, "fits"),
)
#: records the page cites that no job rewrites, and why: they document another machine or older code
#: beside a record that is re-run
KEPT = {
    "reports/records/exeter-snr10-seed0-xeon/summary.json": "the quick start on another processor",
    "reports/records/exeter-snr10-seed0-xeon/manifest.json": "the quick start on another processor",
    "reports/records/exeter-snr20-seed11-amd/summary.json": "the 20 dB run on another processor",
    "reports/records/exeter-snr20-seed11-amd/manifest.json": "the 20 dB run on another processor",
    "reports/records/exeter-snr10-seed0-before-halving/summary.json": "the quick start of older code",
    "reports/records/exeter-snr10-seed0-before-halving/manifest.json": "the quick start of older code",
}


def _study_jobs() -> list[Job]:
    out = []
    from family import DEVELOPMENT_SEED, HELD_OUT_SEED, study_stem

    # the development family's studies time the Exeter yardstick; the held-out family's name their seed
    families = [(DEVELOPMENT_SEED, ("--time-reference",), *f) for f in FAMILY]
    families += [(HELD_OUT_SEED, ("--family-seed", str(HELD_OUT_SEED)), *f) for f in HELD_OUT]
    for seed, extra, case, snr, n in families:
        stem = study_stem(case, float(snr), seed)
        study = f"{PAPER}/family/{stem}.json"
        out.append(
            Job(
                f"family-{stem}",
                (PY, "studies/family.py", "--bridges", str(n), "--snr", snr, "--case", case,
                 *extra, "--out", PAPER, "--quiet"),
                study,
                (study,),
            )
        )  # fmt: skip
    for cfg, case, snr, n in GIRDERS:
        study = f"{PAPER}/girders/{cfg}-{case}-snr{snr}.json"
        out.append(
            Job(
                f"girders-{cfg}-{case}-snr{snr}",
                (PY, "studies/girders.py", "--config", f"examples/{cfg}.toml", "--case", case,
                 "--snr", snr, "--replicates", str(n), "--out", PAPER, "--quiet"),
                study,
                (study,),
            )
        )  # fmt: skip
    study = f"{PAPER}/girder_pinns/damaged-girder-deflection-snr30.json"
    out.append(
        Job(
            "girder-pinns-damaged-girder",
            (PY, "studies/girder_pinns.py", "--config", "examples/damaged-girder.toml", "--snr", "30",
             "--replicates", "20", "--out", PAPER, "--quiet"),
            study,
            (study,),
        )
    )  # fmt: skip
    # the PINN methods on a smooth stiffness loss: the reference and the deep ensemble (the B-PINN's NUTS
    # costs five times the ensemble's time per dataset on the field)
    for case, n in (("deflection", 10), ("strain", 10)):
        study = f"{PAPER}/girder_pinns/smooth-loss-{case}-snr30.json"
        out.append(
            Job(
                f"girder-pinns-smooth-loss-{case}",
                (PY, "studies/girder_pinns.py", "--config", "examples/smooth-loss.toml", "--case", case,
                 "--methods", "modal,ensemble", "--snr", "30", "--replicates", str(n), "--out", PAPER,
                 "--quiet"),
                study,
                (study,),
            )
        )  # fmt: skip
    for cfg, case, levels, n, expect in FITCHECK:
        stem = f"{cfg or 'exeter'}-{case}-snr{levels.replace(',', '_')}"
        study = f"{PAPER}/fitcheck/{stem}.json"
        config = ("--config", f"examples/{cfg}.toml") if cfg else ()
        out.append(
            Job(
                f"fitcheck-{stem}",
                (PY, "studies/fitcheck.py", "--methods", "modal", *config, "--case", case,
                 "--snr", levels, "--replicates", str(n), "--expect", expect, "--out", PAPER,
                 "--quiet"),
                study,
                (study,),
            )
        )  # fmt: skip
    for page in sorted((ROOT / PAPER / "fitcheck").glob("calibration-*.json")):
        doc = _load(f"{PAPER}/fitcheck/{page.name}")
        study = f"{PAPER}/fitcheck/{page.name}"
        config = ("--config", doc["config"]) if doc.get("config") else ()
        out.append(
            Job(
                page.stem,
                (PY, "studies/fitcheck_calibration.py", "--methods", doc["method"], *config,
                 "--case", doc["case"], "--snr", f"{doc['snr_db']:g}", "--replicates", "200",
                 "--out", f"{PAPER}/fitcheck", "--quiet"),
                study,
                (study,),
            )
        )  # fmt: skip
    crossings = [f"{PAPER}/crossings/g{g}-c{k}.json" for g in range(3) for k in range(10)]
    out.append(
        Job(
            "crossings",
            (PY, "studies/crossings.py", "--girders", "3", "--crossings", "10", "--out", PAPER),
            f"{PAPER}/crossings/study.json",
            (f"{PAPER}/crossings/study.json", *crossings),
        )
    )  # fmt: skip
    # after it (it starts study.json afresh): the joint analyses and the Exeter check, entries of that file
    study = f"{PAPER}/crossings/study.json"
    crossing = (PY, "studies/crossings.py", "--girders", "3", "--crossings", "10", "--skip-family")
    for g in range(3):
        # the study's own naming, crossings.joint_key (not imported here: that module loads torch)
        key = "joint" if g == 0 else f"joint_g{g}"
        joint = ("--joint", "10", "--joint-girder", str(g), "--out", PAPER)
        out.append(Job(f"crossings-joint-g{g}", (*crossing, *joint), study, key=key))
    out.append(
        Job("crossings-exeter-check", (*crossing, "--exeter-check", "--out", PAPER), study, key="exeter_check")
    )  # fmt: skip
    for t in ("table4", "table6", "table5"):  # table5 reads table4's run folders
        out.append(
            Job(
                t,
                (
                    PY,
                    f"studies/{t}.py",
                    "--methods",
                    "modal,ensemble,bpinn",
                    "--out",
                    PAPER,
                    "--quiet",
                ),
                f"{PAPER}/{t}.json",
            )
        )
    return out


def _run_jobs() -> list[Job]:
    """The run folders under reports/records, each by the command its manifest recorded."""
    import results_page

    out = []
    for name, _, _ in results_page.RUNS:
        summary = f"reports/records/{name}/summary.json"
        if summary in KEPT:
            continue
        argv = list(_load(f"reports/records/{name}/manifest.json")["command"])[1:]
        keep, skip = [], False
        for (
            a
        ) in argv:  # the recorded --out was wherever the run was made; the record's folder is here
            if skip:
                skip = False
            elif a == "--out":
                skip = True
            elif not a.startswith("--out="):
                keep.append(a)
        out.append(
            Job(
                f"run-{name}",
                (PY, "-m", "bayespinn", *keep, "--out", f"reports/records/{name}"),
                summary,
            )
        )
    return out


def jobs() -> list[Job]:
    """Every job, cheapest kinds first."""
    return _run_jobs() + _study_jobs() + _coverage_jobs()


def expected_seconds(job: Job) -> tuple[float | None, str]:
    """(seconds, how): the time `job`'s record took, from the record itself."""
    if not (ROOT / job.record).is_file():
        return None, "its record is not there (a re-run started it afresh)"
    doc = _load(job.record)
    if job.key is not None:
        entry = doc.get(job.key) or {}
        if entry.get("runtime_s") is None:
            return None, f"not recorded (its entry {job.key} has no run time)"
        return float(entry["runtime_s"]), "its run time"
    if job.record.endswith("summary.json"):
        man = _load(job.record.replace("summary.json", "manifest.json"))
        return float(man["timings_s"]["total_s"]), "its analysis time"
    if doc.get("schema") == "bayespinn.coverage/1":
        n, resumed = int(doc["replicates"]), int(doc.get("resumed_replicates") or 0)
        if resumed and resumed < n:
            return doc["runtime_s"] * n / (
                n - resumed
            ), "its last session's rate over every replicate"
        return float(doc["runtime_s"]), "its run time"
    calibration = doc.get("schema", "").startswith("bayespinn.studies.fitcheck-calibration/")
    if calibration and doc["records"]:
        times = [float(r.get("time_s") or 0.0) for r in doc["records"]]
        asked = _asked(job.command)
        if len(times) < asked:  # a partial study: its rate over the replicates the job asks for
            rate = sum(times) / len(times)
            return rate * asked, "its replicates' mean time, times those asked for"
        return sum(times), "the sum of its replicates' times"
    if isinstance(doc.get("records"), list) and doc["records"]:
        recs = doc["records"]
        folder = (
            ROOT / job.record
        ).parent  # a study that names its records: one file each beside it
        ids = [
            r if isinstance(r, str) else r.get("id") if isinstance(r, dict) else None for r in recs
        ]
        recs = [
            _load(str((folder / f"{i}.json").relative_to(ROOT)))
            if i and (folder / f"{i}.json").is_file()
            else r
            for i, r in zip(ids, recs, strict=True)
        ]
        t = sum(
            float(r.get("time_s") or 0.0)  # a crossing record: its simulation and both analyses
            + float(r.get("simulate_s") or 0.0)
            + sum(float((r.get(a) or {}).get("runtime_s") or 0.0) for a in ("declared", "today"))
            for r in recs
            if isinstance(r, dict)
        )
        t += float((doc.get("time_reference") or {}).get("time_s") or 0.0)
        return t, "the sum of its replicates' times"
    if doc.get("records") == []:  # a study file its job has just started afresh
        return None, "no replicate recorded yet (a re-run has started it afresh)"
    if isinstance(doc.get("rows"), list) and any("folder" in r for r in doc["rows"]):
        return sum(
            float(r.get("runtime_s") or 0.0) for r in doc["rows"]
        ), "the sum of its rows' times"
    return None, "not recorded (it reuses other runs' posteriors)"


def _asked(command: tuple[str, ...]) -> int:
    """The replicate count a job's command asks for (`--replicates N`), 0 when it names none."""
    for a, b in zip(command, command[1:], strict=False):
        if a == "--replicates":
            return int(b)
    return 0


def _hms(s: float | None) -> str:
    if s is None:
        return "n/a"
    s = int(round(s))
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


def _machine(job: Job) -> str:
    from bayespinn.records import provenance_of

    if not (ROOT / job.record).is_file():
        return "n/a"
    doc = _load(job.record)
    key = (
        "methods"
        if job.record.endswith("summary.json")
        else "rows[0].method"
        if doc.get("rows")
        else next(iter(doc))
    )
    return provenance_of(job.record, key, ROOT)["machine"]


def _state() -> dict:
    if STATE.is_file():
        return json.loads(STATE.read_text(encoding="utf-8"))
    return {"started": [], "done": []}


def _save(state: dict) -> None:
    from bayespinn.data.measurements import atomic_write_text

    atomic_write_text(STATE, json.dumps(state, indent=1) + "\n")


def regenerate() -> None:
    """The study pages and docs/results.md from the records now on disk."""
    subprocess.run([PY, "studies/render.py", "--out", PAPER], cwd=ROOT, check=True)
    subprocess.run([PY, "studies/results_page.py"], cwd=ROOT, check=True)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--dry-run", action="store_true", help="list the jobs and their expected times")
    p.add_argument("--only", action="append", default=[], metavar="NAME",
                   help="run only this job (repeatable, or a comma list)")  # fmt: skip
    p.add_argument("--restart", action="store_true", help="forget which jobs finished")
    args = p.parse_args(sys.argv[1:] if argv is None else argv)
    todo = jobs()
    names = [n.strip() for o in args.only for n in o.split(",") if n.strip()]
    unknown = sorted(set(names) - {j.name for j in todo})
    if unknown:
        print(f"rerun.py: error: --only: got {', '.join(unknown)}, expected job names "
              "(python studies/rerun.py --dry-run lists them)", file=sys.stderr)  # fmt: skip
        return 2
    if names:
        todo = [j for j in todo if j.name in names]
    state = {"started": [], "done": []} if args.restart else _state()
    total = 0.0
    for j in todo:
        sec, how = expected_seconds(j)
        total += sec or 0.0
        mark = " (done)" if j.name in state["done"] else ""
        print(f"{j.name}{mark}: expected {_hms(sec)} ({how}, on {_machine(j)})")
        print(f"    {' '.join(['python' if a == PY else a for a in j.command])}")
    print(f"{len(todo)} jobs, expected {_hms(total)} in all")
    if args.dry_run:
        return 0
    if args.restart:
        _save(state)
    for j in todo:
        if j.name in state["done"]:
            continue
        sec, _ = expected_seconds(j)
        print(f"== {j.name}: starting, expected {_hms(sec)}", flush=True)
        if j.name not in state["started"]:
            for f in j.fresh:
                (ROOT / f).unlink(missing_ok=True)
            state["started"].append(j.name)
            _save(state)
        r = subprocess.run(list(j.command), cwd=ROOT, check=False)
        if r.returncode != 0:
            print(f"== {j.name}: exit {r.returncode}; the same command resumes it", file=sys.stderr)
            return r.returncode
        state["done"].append(j.name)
        _save(state)
    regenerate()
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    sys.exit(main())
