"""Where a result came from: the commit, the packages, the machine and the date it was computed on.

Every record the toolkit writes (a run's manifest.json, a study's JSON, each replicate of a study) keeps
this provenance beside its numbers. A record is never declared out of date by it: a figure computed by
older code stays what it was, and its commit and date say which code and when, so a reader can set two
records side by side or re-run one (`git checkout <commit>`).
"""

from __future__ import annotations

import datetime as _dt
import functools
import os
import platform
import subprocess
from collections import Counter
from importlib import metadata
from pathlib import Path

from .version import __version__

#: the packages whose versions a record keeps (their arithmetic decides the numbers)
PACKAGES = ("numpy", "scipy", "torch", "pyro-ppl", "emcee", "arviz", "matplotlib")
#: the paths whose uncommitted changes make a result's commit an incomplete description of its code
CODE_PATHS = ("bayespinn", "studies", "pyproject.toml")

_HERE = Path(__file__).resolve().parent


def versions() -> dict:
    """Python's, bayespinn's and the numerical packages' versions (None for one not installed)."""
    out = {"python": platform.python_version(), "bayespinn": __version__}
    for pkg in PACKAGES:
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = None
    return out


def cpu_model() -> str:
    """The processor's model name (/proc/cpuinfo on Linux, else what `platform` knows)."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return cpu


def machine(device: str = "cpu") -> dict:
    """Where a result was computed: cores, CPU model, torch threads, device, platform."""
    try:
        import torch

        threads = int(torch.get_num_threads())
    except Exception:  # noqa: BLE001 - never lose a record for it
        threads = None
    return {
        "cpus": os.cpu_count(),
        "cpu_model": cpu_model(),
        "torch_threads": threads,
        "device": device,
        "platform": platform.platform(),
    }


def _git(*args: str) -> str | None:
    try:
        r = subprocess.run(
            ["git", *args], cwd=_HERE, capture_output=True, text=True, timeout=5, check=False
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return r.stdout.strip() if r.returncode == 0 else None


def git_commit() -> str | None:
    """The commit checked out where bayespinn is installed from (None outside a git checkout)."""
    return _git("rev-parse", "HEAD") or None


def git_dirty() -> bool | None:
    """Whether the code (`CODE_PATHS`) has uncommitted changes (None outside a git checkout): then the
    commit alone does not say which code computed a result."""
    top = _git("rev-parse", "--show-toplevel")
    if top is None:
        return None
    out = _git("-C", top, "status", "--porcelain", "--untracked-files=no", "--", *CODE_PATHS)
    return None if out is None else bool(out)


@functools.cache
def code_commit() -> dict:
    """{"commit", "dirty"} of this process's code, read once: the code a process runs is the code it
    imported when it started, whatever is committed while it runs."""
    return {"commit": git_commit(), "dirty": git_dirty()}


def now() -> str:
    """The current UTC time, ISO 8601 to the second."""
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


def provenance(device: str = "cpu") -> dict:
    """The provenance block every record carries: date, git commit and dirty flag of the code this process
    imported (`code_commit`: a commit or an edit made while a long study runs is not the code that
    computed its records), package versions and machine. Command, seed and configuration are the
    caller's to add (they belong to the record)."""
    code = code_commit()
    return {
        "date": now(),
        "git_commit": code["commit"],
        "git_dirty": code["dirty"],
        "versions": versions(),
        "machine": machine(device),
    }


def record_commit() -> dict:
    """The `git_commit` and `git_dirty` entries each replicate of a study records (`code_commit`)."""
    cc = code_commit()
    return {"git_commit": cc["commit"], "git_dirty": cc["dirty"]}


def short_commit(sha: str | None, dirty: bool | None = None) -> str:
    """A commit as pages show it: 12 hex digits, "+dirty" when the code had uncommitted changes."""
    if not sha:
        return "unrecorded"
    return sha[:12] + ("+dirty" if dirty else "")


def commits(records: list[dict]) -> dict[str, int]:
    """How many records (a study's replicates) each commit computed, by `short_commit`; "unrecorded"
    counts records written before records carried their commit."""
    out: Counter = Counter(short_commit(r.get("git_commit"), r.get("git_dirty")) for r in records)
    return dict(sorted(out.items()))


def commits_text(counts: dict[str, int]) -> str:
    """`commits` as a page prints it: "0d1940b5c2a1 (58), unrecorded (42)"."""
    return ", ".join(f"{k} ({v})" for k, v in counts.items()) or "none"


# read when the package is imported, before a long run's first record: the code a process computes with
# is the code it imported, whatever is committed or edited while it runs
code_commit()
