"""A study's finished replicates, kept across interruptions: the checkpoint an interrupted study resumes
from, and the records of a study file written earlier (a study carried over several sessions)."""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

log = logging.getLogger(__name__)


class Checkpoint:
    """Finished replicates of one study, one JSON line each after a header line with the study's fingerprint,
    appended and flushed as each replicate ends, so an interrupted study resumes where it stopped.

    Opening reads the file and writes nothing: the file is rewritten (the resumed replicates, without lines
    a crash cut short, or afresh when it belonged to another study) only when the first new replicate is
    added. A study refused or stopped before it finished any replicate therefore leaves the file exactly as
    it found it, and the next run resumes from the same replicates."""

    def __init__(self, path: str | Path, key: str, earlier: dict[int, dict] | None = None):
        self.path, self.key = Path(path), key
        self.done: dict[int, dict] = dict(earlier or {})
        self._rewritten = False
        if self.path.exists():
            lines = self.path.read_text(encoding="utf-8").splitlines()
            head = json.loads(lines[0]) if lines else {}
            if head.get("fingerprint") == key:
                for ln in lines[1:]:
                    try:
                        rec = json.loads(ln)
                    except json.JSONDecodeError:  # a line cut short by a crash
                        continue
                    self.done[int(rec["index"])] = rec
                log.info("resuming from %s: %d replicates already done", self.path, len(self.done))
            else:
                log.warning("%s belongs to a different study; starting afresh", self.path)

    def _rewrite(self) -> None:
        from .posterior import jsonable

        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_name(self.path.name + ".tmp")
        with tmp.open("w", encoding="utf-8") as fh:
            fh.write(json.dumps({"fingerprint": self.key}) + "\n")
            for rec in self.done.values():
                fh.write(json.dumps(jsonable(rec)) + "\n")
            fh.flush()
            os.fsync(fh.fileno())
        tmp.replace(self.path)  # never a half-written checkpoint
        self._rewritten = True

    def add(self, rec: dict) -> None:
        from .posterior import jsonable

        if not self._rewritten:
            self._rewrite()
        with self.path.open("a", encoding="utf-8") as fh:
            fh.write(json.dumps(jsonable(rec)) + "\n")
            fh.flush()
            os.fsync(fh.fileno())


def earlier_records(path: str | Path, key: str) -> dict[int, dict]:
    """The per-replicate records of a study file written earlier (`coverage_study`'s JSON) when it is the same
    study (same fingerprint), else none: a study carried over several sessions resumes from its committed
    file, where the checkpoint of an interrupted run is gone."""
    path = Path(path)
    if not path.is_file():
        return {}
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError):
        log.warning("%s is not a study file; nothing reused from it", path)
        return {}
    if doc.get("fingerprint") != key:
        log.info(
            "%s is another study (or predates study fingerprints); nothing reused from it", path
        )
        return {}
    return {int(r["index"]): r for r in doc.get("records", [])}
