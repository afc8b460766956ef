"""Replay a committed run record with today's code and certify that its numbers still hold.

A record under reports/records/ keeps a run's summary.json and manifest.json. After a change that should
not move any number (a refactor), this script runs the record's command again (into a temporary folder,
or takes a run folder already made with `--rerun DIR`), compares every method's EI and sigma entries and
the agreement verdicts exactly, and writes `replay.json` beside the record. An identical replay vouches
for the record (`bayespinn.records.run_freshness`); any difference leaves it stale, and the script exits 1.

    python studies/replay_record.py reports/records/exeter-snr20-seed11
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
from pathlib import Path

import common as c

from bayespinn.errors import InputError
from bayespinn.records import REPLAY, command_without_out, replay_certificate, run_freshness

log = logging.getLogger("studies.replay_record")


def rerun(record: Path, folder: Path) -> None:
    """Run the record's command with today's code into `folder` (a process of its own, as a user runs it;
    paths in the command are relative to the repository root, where the records were made)."""
    import subprocess

    man = json.loads((record / "manifest.json").read_text(encoding="utf-8"))
    argv = command_without_out(man["command"])
    if not argv or argv[0] != "run":
        raise InputError("record", str(record), "a record of a `bayespinn run` command")
    log.info("replay: bayespinn %s", " ".join(argv))
    root = Path(__file__).resolve().parents[1]
    cmd = [sys.executable, "-m", "bayespinn", *argv, "--out", str(folder.resolve())]
    rc = subprocess.run(cmd, cwd=root).returncode
    if rc != 0:
        raise RuntimeError(f"the record's command exited {rc}")


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument(
        "records", nargs="+", type=Path, help="record folders (summary.json, manifest.json)"
    )
    p.add_argument(
        "--rerun", type=Path, default=None, help="a run folder of the same command already made"
    )
    p.add_argument(
        "--keep",
        type=Path,
        default=None,
        help="keep each rerun in KEEP/<record name> (default: a temporary folder, removed)",
    )
    p.add_argument("--quiet", action="store_true")
    args = p.parse_args(argv)
    c.setup_logging(args.quiet)
    if args.rerun is not None and len(args.records) != 1:
        raise InputError("--rerun", str(args.rerun), "one record to compare it with")
    failed = []
    for record in args.records:
        if args.rerun is not None:
            cert = replay_certificate(record, args.rerun)
        elif args.keep is not None:
            run = args.keep / record.name
            rerun(record, run)
            cert = replay_certificate(record, run)
        else:
            with tempfile.TemporaryDirectory(prefix="replay-") as tmp:
                rerun(record, Path(tmp) / "run")
                cert = replay_certificate(record, Path(tmp) / "run")
        c.write_json(record / REPLAY, cert)
        fresh, how = run_freshness(record)
        log.info(
            "replay: %s: %s (%s)", record, "identical" if cert["identical"] else "DIFFERENT", how
        )
        if not cert["identical"]:
            failed.append(str(record))
    if failed:
        log.error("replay: today's code does not reproduce %s", ", ".join(failed))
        return 1
    return 0


if __name__ == "__main__":
    c.entry(main)
