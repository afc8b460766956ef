"""Committed run records (a run folder's summary.json and manifest.json) and their replays.

A record is fresh when the code versions in its manifest are today's (`codeversion`). When the code
has changed in a way that should not touch the numbers (a refactor), the record's command is run again
with today's code and the two summaries are compared (numbers to 1e-12 relative: `REPLAY_RTOL`) (`replay_certificate`): an identical replay,
kept beside the record as `replay.json`, vouches for it (`run_freshness`). Timings are not compared (a
machine's load changes them); the record's own timings stay the measured ones.
"""

from __future__ import annotations

import json
from pathlib import Path

from .errors import InputError

#: what a replay compares in each method's summary entry
COMPARED = ("EI", "sigma")
REPLAY = "replay.json"
#: relative difference within which a replayed number counts as the same: a replay under another thread
#: count reorders floating-point sums (the reference's sigma on the Exeter girder at 20 dB came out different
#: in its 16th digit on one core), while every figure a record shows has at most 6 digits
REPLAY_RTOL = 1e-12
#: absolute tolerance of diagnostics in nats (keys ending "_nats"): an interpolant's largest error against
#: the exact log likelihood is a difference of numbers of order 1e3, so reordered sums move it by rounding-
#: sized amounts that are large relative to it (measured: 2.2e-14 nats on 3.9e-4, 6e-11 of its value);
#: 1e-9 nats is far below the 1e-3 nats it is checked against
NATS_ATOL = 1e-9


def _close(a, b, rtol: float = REPLAY_RTOL, atol: float = 0.0) -> bool:
    """a and b equal, numbers within rtol relative (or atol; `NATS_ATOL` under keys ending "_nats"),
    recursively through dicts and lists."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(
            _close(a[k], b[k], rtol, NATS_ATOL if str(k).endswith("_nats") else atol) for k in a
        )
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        return len(a) == len(b) and all(_close(x, y, rtol, atol) for x, y in zip(a, b, strict=True))
    if isinstance(a, bool) or isinstance(b, bool):
        return a == b
    if isinstance(a, int | float) and isinstance(b, int | float):
        return a == b or abs(a - b) <= max(rtol * max(abs(a), abs(b)), atol)
    return a == b


def _load(folder: Path, name: str) -> dict:
    p = Path(folder) / name
    try:
        return json.loads(p.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError("record", str(p), f"a readable {name} ({type(exc).__name__})") from None


def today_versions(keys) -> dict[str, str]:
    """Today's code version of each method (summary keys)."""
    from . import methods
    from .codeversion import method_version

    out = {}
    for k in keys:
        cls = methods.by_key(k)
        out[k] = method_version(cls.name) if cls is not None else None
    return out


def command_without_out(command: list[str]) -> list[str]:
    """A run's command line without the program path and its --out value (the parts that decide numbers)."""
    out, skip = [], False
    for a in list(command)[1:]:
        if skip:
            skip = False
            continue
        if a == "--out":
            skip = True
            continue
        if a.startswith("--out="):
            continue
        out.append(a)
    return out


def _untimed(diag: dict | None) -> dict | None:
    """A method's diagnostics without its wall times (runtime_s, gradient_s, ...), which load changes."""
    if diag is None:
        return None
    return {k: v for k, v in diag.items() if not (k.endswith("_s") or "runtime" in k)}


def replay_certificate(record: str | Path, rerun: str | Path) -> dict:
    """Compare a record with a run of the same command by today's code (`rerun`, a run folder).

    InputError when the rerun is not today's code or not the record's command. Returns the certificate:
    the record's and today's code versions, the command, the fields compared, `identical` (every number
    within `REPLAY_RTOL`, everything else equal), `bit_identical`, every difference beyond the tolerance,
    and the rerun's timings and machine (for the reader, not compared)."""
    rec_s, rec_m = _load(record, "summary.json"), _load(record, "manifest.json")
    new_s, new_m = _load(rerun, "summary.json"), _load(rerun, "manifest.json")
    today = today_versions(rec_m.get("code_versions") or rec_s.get("methods", {}))
    if new_m.get("code_versions") != today:
        raise InputError("rerun", str(rerun), f"a run folder computed by today's code {today}")
    if command_without_out(rec_m.get("command", [])) != command_without_out(
        new_m.get("command", [])
    ):
        raise InputError(
            "rerun",
            str(rerun),
            f"a run of the record's command {' '.join(rec_m.get('command', []))}",
        )
    diffs: dict = {}
    exact = True
    for k, entry in rec_s.get("methods", {}).items():
        other = new_s.get("methods", {}).get(k, {})
        pairs = [(f, entry.get(f), other.get(f)) for f in COMPARED]
        pairs.append(
            ("diagnostics", _untimed(entry.get("diagnostics")), _untimed(other.get("diagnostics")))
        )
        for f, a, b in pairs:
            exact = exact and a == b
            if not _close(a, b):
                diffs.setdefault(k, {})[f] = [a, b]
    exact = exact and rec_s.get("agreement") == new_s.get("agreement")
    if not _close(rec_s.get("agreement"), new_s.get("agreement")):
        diffs["agreement"] = [rec_s.get("agreement"), new_s.get("agreement")]
    return {
        "schema": "bayespinn.run.replay/1",
        "record_code_versions": rec_m.get("code_versions"),
        "code_versions": today,
        "command": command_without_out(new_m.get("command", [])),
        "compared": [f"methods.*.{f}" for f in COMPARED]
        + ["methods.*.diagnostics (but times)", "agreement"],
        "identical": not diffs,
        "bit_identical": exact,
        "relative_tolerance": REPLAY_RTOL,
        "differences": diffs,
        "rerun_timings_s": new_m.get("timings_s"),
        "rerun_machine": new_m.get("machine"),
        "rerun_git_commit": new_m.get("git_commit"),
    }


def run_freshness(record: str | Path) -> tuple[bool, str]:
    """(fresh, how): was this run record computed by today's code, directly or vouched for by an identical
    replay (`replay.json` beside it)?"""
    man = _load(record, "manifest.json")
    recorded = man.get("code_versions")
    if not recorded:
        return False, "predates code versions"
    today = today_versions(recorded)
    if recorded == today:
        return True, "today's code"
    cert_path = Path(record) / REPLAY
    if cert_path.is_file():
        cert = json.loads(cert_path.read_text(encoding="utf-8"))
        if (
            cert.get("identical")
            and cert.get("code_versions") == today
            and cert.get("record_code_versions") == recorded
        ):
            return True, "replayed: identical with today's code"
    return False, f"computed by code {recorded}, today's is {today}"
