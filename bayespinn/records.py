"""Committed records read back: a figure by its key path, and the provenance of the record that holds it.

A record is a JSON file the toolkit wrote: a run folder's summary.json (its manifest.json beside it),
a study's JSON, or a study page's JSON. A figure quoted anywhere is named by the record and a key path
into it, e.g. ``reports/paper/coverage.json :: rows[method=ensemble,snr_db=30].hits``, so it is tied to
exactly one field. Its provenance (git commit, dirty flag, date, machine) is the one nearest to that field:
the run folder's manifest, the study's ``provenance``, or the run of the table row the path goes through.
Records written by older code load as they are: a figure computed by older code is shown with its
commit and date, never relabelled.
"""

from __future__ import annotations

import json
import re
import subprocess
from functools import cache
from pathlib import Path

from .errors import InputError
from .provenance import commits, short_commit

#: a key path, step by step: a field name (quoted with "..." when it holds dots or brackets, as in
#: "EI_segments[0]"), then any number of [index] or [field=value,...] selectors
_TOKEN = re.compile(r'"([^"]*)"|([^.\[\]"]+)|\[([^\]]*)\]|(\.)')


def load(path: str | Path) -> dict:
    """A record's JSON (InputError naming the file when it is missing or not JSON)."""
    p = Path(path)
    try:
        return json.loads(p.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(
            "record", str(p), f"a readable JSON record ({type(exc).__name__})"
        ) from None


def _literal(text: str):
    """A selector's value: JSON when it parses (10, 10.0, null, true), else the text itself."""
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def _matches(item, conds: list[tuple[str, object]]) -> bool:
    if not isinstance(item, dict):
        return False
    for k, v in conds:
        have = item.get(k)
        same = have == v or (
            isinstance(have, int | float) and isinstance(v, int | float) and float(have) == float(v)
        )
        if not same or isinstance(have, bool) != isinstance(v, bool):
            return False
    return True


def _select(node, sel: str, path: str):
    """node[sel]: an integer index, or the one list item whose fields equal `k=v,...`."""
    sel = sel.strip()
    if re.fullmatch(r"-?\d+", sel):
        if not isinstance(node, list) or not -len(node) <= int(sel) < len(node):
            raise KeyError(f"{path}: no item [{sel}]")
        return node[int(sel)]
    conds = []
    for part in sel.split(","):
        k, eq, v = part.partition("=")
        if not eq:
            raise KeyError(f"{path}: selector [{sel}] is neither an index nor field=value pairs")
        conds.append((k.strip(), _literal(v.strip())))
    hits = [x for x in (node if isinstance(node, list) else []) if _matches(x, conds)]
    if len(hits) != 1:
        raise KeyError(f"{path}: [{sel}] matches {len(hits)} items, not one")
    return hits[0]


def steps(keypath: str) -> list[tuple[str, str]]:
    """A key path as ("field", name) and ("select", selector) steps. KeyError when it cannot be read."""
    out, pos, need_field = [], 0, True
    while pos < len(keypath):
        m = _TOKEN.match(keypath, pos)
        if not m:
            raise KeyError(f"{keypath}: cannot read it from position {pos}")
        quoted, name, sel, dot = m.groups()
        if dot:
            if need_field:
                raise KeyError(f"{keypath}: an empty step at position {pos}")
            need_field = True
        elif sel is not None:
            if need_field:
                raise KeyError(f"{keypath}: a selector without a field at position {pos}")
            out.append(("select", sel))
        else:
            if not need_field:
                raise KeyError(f"{keypath}: two fields without a dot at position {pos}")
            out.append(("field", quoted if quoted is not None else name))
            need_field = False
        pos = m.end()
    if need_field:
        raise KeyError(f"{keypath}: ends without a field")
    return out


def walk(doc, keypath: str) -> list:
    """Every node from `doc` down to the field `keypath` names (the field last). KeyError when the path
    does not lead to exactly one field."""
    nodes, node = [doc], doc
    for kind, name in steps(keypath):
        if kind == "field":
            if not isinstance(node, dict) or name not in node:
                raise KeyError(f"{keypath}: no field {name!r}")
            node = node[name]
        else:
            node = _select(node, name, keypath)
        nodes.append(node)
    return nodes


def get(doc, keypath: str):
    """The field `keypath` names in `doc` (see `walk`)."""
    return walk(doc, keypath)[-1]


def _is_provenance(d) -> bool:
    return isinstance(d, dict) and "git_commit" in d and ("date" in d or "machine" in d)


def _nearest_provenance(doc: dict, keypath: str) -> dict | None:
    """The provenance nearest to the field: a `provenance` entry, a `runs` list (its last run: the one that
    wrote the file) or dict (the run a table row names), or a dict that is itself one, on the way down."""
    found = None
    nodes = walk(doc, keypath)
    for node in nodes[:-1]:
        if not isinstance(node, dict):
            continue
        if _is_provenance(node.get("provenance")):
            found = node["provenance"]
        runs = node.get("runs")
        if isinstance(runs, list) and runs and _is_provenance(runs[-1]):
            found = runs[-1]
        if isinstance(node.get("run"), str):
            owner = next(
                (n for n in nodes if isinstance(n, dict) and isinstance(n.get("runs"), dict)), None
            )
            if owner is not None and _is_provenance(owner["runs"].get(node["run"])):
                found = owner["runs"][node["run"]]
        if _is_provenance(node) and node is not doc:
            found = node
    return found


@cache
def commit_date(sha: str | None, root: str) -> str | None:
    """The committer date (YYYY-MM-DD) of a commit in the git repository at `root`, or None."""
    if not sha:
        return None
    try:
        r = subprocess.run(
            ["git", "-C", root, "show", "-s", "--format=%cs", sha],
            capture_output=True,
            text=True,
            timeout=10,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return r.stdout.strip() or None if r.returncode == 0 else None


@cache
def added_date(rel: str, root: str) -> str | None:
    """The date (YYYY-MM-DD) of the commit that first added the file `rel` in the repository at `root`."""
    try:
        r = subprocess.run(
            ["git", "-C", root, "log", "--diff-filter=A", "--format=%cs", "--", rel],
            capture_output=True,
            text=True,
            timeout=10,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    lines = r.stdout.split() if r.returncode == 0 else []
    return lines[-1] if lines else None


def _machine_text(m: dict | None) -> str:
    if not m:
        return "n/a"
    cpu = str(m.get("cpu_model") or "n/a").strip()
    dev = m.get("device")
    out = f"{cpu}, {m.get('cpus')} cores" if m.get("cpus") else cpu
    return out + (f", {dev}" if dev and dev != "cpu" else "")


def _coverage_run(path: Path, root: Path) -> dict | None:
    """A coverage study file's provenance: the run of the coverage table's row that names the file."""
    table = path.parent.parent / "coverage.json"
    if not table.is_file():
        return None
    doc = load(table)
    rel = path.relative_to(path.parent.parent).as_posix()
    for row in doc.get("rows", []):
        if row.get("file") == rel:
            return (doc.get("runs") or {}).get(row.get("run"))
    return None


def provenance_of(path: str | Path, keypath: str, root: str | Path = ".") -> dict:
    """Commit, date and machine of the figure at `keypath` in the record `path` (relative to `root`):
    {"commit", "date", "machine", "replicates"} as strings for a page. A record whose provenance has no
    date (older run manifests) is dated by its commit ("YYYY-MM-DD, commit date"), or where that commit
    is not in the history, by the commit that added the record ("YYYY-MM-DD, committed"). `replicates` lists
    the commits of a study's replicates where they are recorded."""
    root = Path(root)
    p = root / path
    doc = load(p)
    get(doc, keypath)  # KeyError for a path that leads nowhere
    prov = None
    if p.name in ("summary.json", "manifest.json") and (p.parent / "manifest.json").is_file():
        prov = load(p.parent / "manifest.json")
    elif doc.get("schema") == "bayespinn.coverage/1" and not _is_provenance(doc.get("provenance")):
        prov = _coverage_run(p, root)  # older study files: the coverage table's run that wrote them
    if prov is None:
        prov = _nearest_provenance(doc, keypath)
    if prov is None:
        return {"commit": "n/a", "date": "n/a", "machine": "n/a", "replicates": ""}
    sha = prov.get("git_commit")
    date = prov.get("date")
    if date:
        date = str(date)[:10]
    else:
        cd = commit_date(sha, str(root.resolve()))
        added = None if cd else added_date(p.relative_to(root).as_posix(), str(root.resolve()))
        date = f"{cd}, commit date" if cd else f"{added}, committed" if added else "n/a"
    recs = doc.get("records")
    reps = ""
    if isinstance(recs, list) and recs and any("git_commit" in r for r in recs):
        reps = ", ".join(f"{k} ({v})" for k, v in commits(recs).items())
    return {
        "commit": short_commit(sha, prov.get("git_dirty")),
        "date": date,
        "machine": _machine_text(prov.get("machine")),
        "replicates": reps,
    }
