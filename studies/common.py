"""What the study scripts share: the common flags, provenance, and merging rows into a table's JSON.

No science here: the scripts call bayespinn's public API, and this module only parses, records and
merges. Every table JSON holds `rows` (one per method and SNR level or scenario) and `runs` (the
provenance of each invocation that produced rows); re-running a script for some methods replaces
those methods' rows and keeps the others, so a table can be filled in one method at a time.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
import warnings
from collections.abc import Callable, Iterable
from pathlib import Path

from bayespinn import methods
from bayespinn.config import parse_snr, snr_label
from bayespinn.data.measurements import atomic_write_text
from bayespinn.errors import InputError
from bayespinn.executor import cpu_count
from bayespinn.flags import Parser, add_method_flags, check_method_flags
from bayespinn.options import RunOptions, resolve_device
from bayespinn.provenance import commits, commits_text, record_commit, short_commit
from bayespinn.provenance import provenance as _provenance
from bayespinn.uq.posterior import jsonable

log = logging.getLogger("studies")

#: summary keys in report order (the method registry's)
METHOD_ORDER = methods.keys()


# ------------------------------------------------------------------------------------------ flags
def parser(description: str) -> argparse.ArgumentParser:
    """The flags every study script takes: the command line's method flags (`options.add_method_flags`,
    checked by `options.check_method_flags` in `run_options`), --methods and --out; errors are one line."""
    p = Parser(description=description)
    p.add_argument(
        "--methods",
        default="modal,ensemble,bpinn",
        help="comma list of modal, ensemble, bpinn, or 'all' (default all three)",
    )
    p.add_argument("--out", default="reports/paper", help="output folder (default reports/paper)")
    add_method_flags(p)
    return p


def methods_of(text: str) -> list[str]:
    """CLI method names from a comma list (bayespinn's own parser and order)."""
    return methods.parse(text)


def levels_of(text: str) -> list[float | None]:
    """SNR levels from a comma list such as 'clean,10,20' (None is clean)."""
    return [parse_snr(s.strip(), "--snr") for s in text.split(",") if s.strip()]


def run_options(args, snr_db: float | None = None) -> RunOptions:
    check_method_flags(args)
    return RunOptions(
        profile=args.profile,
        members=args.members,
        device=resolve_device(args.device),
        noise_prior=args.noise_prior,
        bpinn_variant=args.bpinn_variant,
        snr_db=snr_db,
        progress=not args.quiet,
    )


def setup_logging(quiet: bool) -> None:
    """Progress of the scripts and of bayespinn on stderr (warnings only with --quiet)."""
    logging.basicConfig(
        level=logging.WARNING if quiet else logging.INFO,
        format="%(message)s",
        stream=sys.stderr,
        force=True,
    )
    for noisy in ("matplotlib", "h5py", "numexpr", "PIL"):
        logging.getLogger(noisy).setLevel(logging.WARNING)
    warnings.filterwarnings("ignore", category=FutureWarning, module="arviz")
    warnings.filterwarnings("ignore", message=".*ArviZ is undergoing a major refactor.*")


def entry(main: Callable[[list[str] | None], int]) -> None:
    """Run main() as a script: exit 2 with one line for bad input, else main's code. SIGINT and SIGTERM stop
    the worker processes at once (`bayespinn.stopping`); finished replicates stay in their checkpoint."""
    from bayespinn.stopping import stop_cleanly

    try:
        with stop_cleanly():
            code = main(None)
    except InputError as exc:
        print(f"{Path(sys.argv[0]).name}: error: {exc}", file=sys.stderr)
        code = 2
    except KeyboardInterrupt as exc:
        print(f"{Path(sys.argv[0]).name}: stopped ({exc or 'SIGINT'})", file=sys.stderr)
        code = 1
    sys.exit(code)


# ------------------------------------------------------------------------------------- provenance
def command_line(script: str, argv: list[str]) -> str:
    """The command that reproduces this invocation, e.g. `python studies/table4.py --methods modal`."""
    p = Path(script).resolve()
    try:
        shown = os.path.relpath(p)
        if shown.startswith(".."):
            shown = str(p)
    except ValueError:
        shown = str(p)
    import shlex

    return shlex.join(["python", shown, *argv])


def provenance(script: str, argv: list[str], args, **extra) -> dict:
    """Who made these rows: command, profile, seed, date, git commit (and whether the code had uncommitted
    changes), machine and package versions (`bayespinn.provenance`), plus the study's own entries."""
    device = resolve_device(args.device)
    prov = _provenance(device)
    out = {
        "command": command_line(script, argv),
        "profile": args.profile,
        "seed": args.seed,
        "members": args.members,
        "noise_prior": args.noise_prior,
        **prov,
        "machine": {**prov["machine"], "cpus": cpu_count()},
    }
    out.update(extra)
    return out


def provenance_lines(runs: dict, used: Iterable[str]) -> list[str]:
    """One bullet per run that produced rows of the table, labelled as in the tables' `run` column."""
    lines = []
    for rid in used:
        r = runs[rid]
        m = r["machine"]
        git = (r.get("git_commit") or "n/a")[:12] + (
            " (uncommitted changes)" if r.get("git_dirty") else ""
        )
        lines.append(
            f"run {run_label(runs, rid)}: `{r['command']}`; profile **{r['profile']}**, seed {r['seed']}"
            + (f", {r['members']} ensemble members" if "ensemble" in r.get("methods", []) else "")
            + f", noise prior {r.get('noise_prior', 'vague')}; {r['date']}; machine: {m['cpus']} CPU cores "
            f"({m['cpu_model']}), {m['torch_threads']} torch threads, device {m['device']}, "
            f"{m['platform']}; bayespinn {r['versions'].get('bayespinn')}, git {git}"
            + "".join(
                f"; {k.replace('_', ' ')}: {_show(r[k])}" for k in EXTRAS if r.get(k) is not None
            )
        )
    return lines


#: study-specific provenance entries shown after the common ones
EXTRAS = ("levels", "snr_db", "gauge", "sample_rate", "replicates", "workers", "note")


def _show(v) -> str:
    if isinstance(v, dict):
        return ", ".join(f"{k} {_show(x)}" for k, x in v.items())
    if isinstance(v, list | tuple):
        return ", ".join(_show(x) for x in v)
    if v is None:
        return "clean"
    return f"{v:g}" if isinstance(v, float) else str(v)


def cli_name(key: str) -> str:
    """The CLI method name of a summary key (modal_mcmc -> modal)."""
    cls = methods.by_key(key)
    if cls is None:
        raise KeyError(key)
    return cls.name


def run_cell(doc: dict, row: dict) -> str:
    """The `run` column of a table row: the run's label and the commit it ran at."""
    prov = doc["runs"][row["run"]]
    return f"{run_label(doc['runs'], row['run'])} ({short_commit(prov.get('git_commit'), prov.get('git_dirty'))})"


def run_label(runs: dict, rid: str) -> str:
    """A short label for a run id: its position among the runs (1, 2, ...), stable within one file."""
    return str(list(runs).index(rid) + 1)


def run_id(prov: dict) -> str:
    return f"{prov['date']} {','.join(prov.get('methods', []))}".strip()


# ---------------------------------------------------------------------------------------- merging
def snr_key(v) -> tuple:
    """Sort key: clean first, then increasing dB."""
    return (0, 0.0) if v is None else (1, float(v))


def method_key(k: str) -> int:
    return METHOD_ORDER.index(k) if k in METHOD_ORDER else len(METHOD_ORDER)


def load_table(path: Path, schema: str) -> dict:
    """The table JSON at path, or an empty one; a file of another schema is not merged into."""
    if path.exists():
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
            if doc.get("schema") == schema:
                doc.setdefault("rows", [])
                doc.setdefault("runs", {})
                return doc
            log.warning(
                "warning: %s has schema %r, not %r: starting a new table",
                path,
                doc.get("schema"),
                schema,
            )
        except (OSError, json.JSONDecodeError) as exc:
            log.warning("warning: %s is unreadable (%s): starting a new table", path, exc)
    return {"schema": schema, "rows": [], "runs": {}}


def merge(
    doc: dict, new_rows: list[dict], prov: dict, key: tuple[str, ...], sort: Callable
) -> dict:
    """Replace the rows of doc that share `key` with a new row, add the rest, record the run and
    drop runs no row refers to any more. Returns doc (changed in place)."""
    rid = run_id(prov)
    doc["runs"][rid] = prov
    for r in new_rows:
        r["run"] = rid
    fresh = {tuple(_hashable(r[k]) for k in key) for r in new_rows}
    kept = [r for r in doc["rows"] if tuple(_hashable(r[k]) for k in key) not in fresh]
    doc["rows"] = sorted(kept + new_rows, key=sort)
    used = {r["run"] for r in doc["rows"]}
    doc["runs"] = {k: v for k, v in doc["runs"].items() if k in used}
    return doc


def _hashable(v):
    return None if v is None else (float(v) if isinstance(v, int | float) else v)


def runs_in_order(doc: dict) -> list[str]:
    return list(doc["runs"])


# ------------------------------------------------------------------------------------------- files


def write_json(path: Path, obj: dict) -> None:
    atomic_write_text(path, json.dumps(jsonable(obj), indent=2) + "\n")


def not_run_yet(doc: dict) -> list:
    """A paragraph naming the methods without rows in a table's doc (none when every method has rows)."""
    from bayespinn.report.document import Paragraph
    from bayespinn.report.units import name

    missing = [k for k in METHOD_ORDER if k not in {r["method"] for r in doc["rows"]}]
    if not missing:
        return []
    text = ", ".join(name(k) for k in missing)
    return [Paragraph(f"Not run yet: {text} (add them with `--methods`; existing rows are kept).")]


def write_markdown(path: Path, blocks: list) -> None:
    from bayespinn.report.markdown import render_markdown

    atomic_write_text(path, render_markdown(blocks))


# ------------------------------------------------------------------------------------------ display
def snr_text(v) -> str:
    return "clean" if v is None else f"{snr_label(v)} dB"


def kN(v: float | None) -> str:
    """EI [N m^2] shown in kN m^2 with thousands separators, as the paper prints it."""
    if v is None or not math.isfinite(v):
        return "n/a"
    return f"{v / 1e3:,.0f}"


def kN_interval(ci) -> str:
    if not ci or ci[0] is None or ci[1] is None:
        return "n/a"
    return f"[{kN(ci[0])}, {kN(ci[1])}]"


def yes_no(b) -> str:
    return "n/a" if b is None else ("yes" if b else "**no**")


def inside(ci, v) -> bool | None:
    if v is None or not ci or ci[0] is None or ci[1] is None:
        return None
    return bool(ci[0] <= v <= ci[1])


def key_of(method: str) -> str:
    """Summary key of a CLI method name."""
    return methods.get(method).key


# ------------------------------------------------------------------------------ replicate studies
def open_study(path: Path, schema: str, fingerprint: str) -> dict:
    """The study file at `path` to resume (a fresh one when it is missing or another study's). Its
    replicates are kept whichever commit computed them: each names its own (`record_commit`)."""
    doc = {}
    if path.is_file():
        doc = json.loads(path.read_text(encoding="utf-8"))
        if doc.get("schema") != schema or doc.get("fingerprint") != fingerprint:
            log.warning("warning: %s is another study: starting afresh", path)
            doc = {}
    if not doc:
        doc = {"schema": schema, "fingerprint": fingerprint, "records": []}
    return doc


def run_replicates(doc: dict, path: Path, n: int, compute, summarise, tag: str) -> dict:
    """Compute replicates 0..n-1 not yet in doc["records"] (`compute(i)` returns one record with its
    "index"), rewriting the study file atomically after each so an interruption loses at most the replicate
    under way; the summary (`summarise(doc)`) is kept current."""
    done = {r["index"] for r in doc["records"]}
    for i in range(n):
        if i in done:
            continue
        doc["records"].append(compute(i))
        doc["records"].sort(key=lambda r: r["index"])
        doc["summary"] = summarise(doc)
        write_json(path, doc)
        log.info("[%s] replicate %d of %d", tag, i + 1, n)
    doc["summary"] = summarise(doc)
    write_json(path, doc)
    return doc


def gather_studies(folder: Path, schema: str, summarise) -> dict:
    """Every study file of `schema` under `folder` with records, summarised (without its records and
    configuration values), with the commits its replicates were computed at (`commits`)."""
    studies = {}
    for f in sorted(folder.glob("*.json")) if folder.is_dir() else []:
        doc = json.loads(f.read_text(encoding="utf-8"))
        if doc.get("schema") != schema or not doc.get("records"):
            continue
        studies[f.stem] = {
            **{k: v for k, v in doc.items() if k not in ("records", "config_values")},
            "summary": summarise(doc),
            "commits": commits(doc["records"]),
        }
    return studies


def commits_sentence(d: dict) -> str:
    """Which code computed a study's replicates, for its page: the commits and how many each; for records
    older than per-replicate commits, the commit and date of the run that last wrote the study."""
    counts = dict(d.get("commits") or {})
    old = counts.pop("unrecorded", 0)
    runs = d.get("runs")
    prov = d.get("provenance") or (runs[-1] if isinstance(runs, list) and runs else {}) or {}
    last = (
        f"last written at commit {short_commit(prov.get('git_commit'), prov.get('git_dirty'))}"
        f" on {str(prov.get('date', 'n/a'))[:10]}"
    )
    if not counts:
        return f"{last}; the replicates' own commits were not recorded then"
    text = f"computed at commit {commits_text(counts)}"
    return text + (f", {old} unrecorded ({last})" if old else "")


def replicate_provenance() -> dict:
    """What each replicate of a study records about its code: `git_commit` and `git_dirty`."""
    return record_commit()
