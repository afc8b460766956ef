"""The `bayespinn` command line: parse, resolve configuration (preset < TOML < flags), call the library,
map errors to exit codes (0 ok, 2 bad usage or input, 1 anything else). No science here."""

from __future__ import annotations

import argparse
import logging
import sys
import warnings
from pathlib import Path

from .config import parse_snr, snr_label
from .errors import InputError
from .flags import Parser, UsageError, add_method_flags
from .options import (
    config_from_args,
    default_out,
    int_at_least,
    parse_level,
    resolve_device,
)
from .version import __version__

__all__ = ["UsageError", "build_parser", "default_out", "main", "resolve_device"]

log = logging.getLogger("bayespinn")
_show_warning = warnings.showwarning


def _common(p: argparse.ArgumentParser, *, snr: bool = True, method: bool = True) -> None:
    if snr:
        p.add_argument("--snr", help="'clean' or a finite SNR in dB (> 0)")
    p.add_argument(
        "--case", default="deflection", help="deflection (case study 1) or strain (case study 2)"
    )
    p.add_argument("--config", help="TOML file overriding the Exeter preset")
    if not method:  # simulate: data only, none of the flags that choose how the methods run
        p.add_argument(
            "--seed", type=int_at_least("--seed", 0), default=0, help="root seed (default 0)"
        )
        p.add_argument("--quiet", action="store_true", help="no progress output")
        return
    p.add_argument("--method", default="all", help="modal, ensemble, bpinn, all, or a comma list")
    add_method_flags(p)
    p.add_argument("--executor", default="local", help="local (process pool) or ray")
    p.add_argument(
        "--address", default=None, help="Ray cluster address (with --executor ray), or 'auto'"
    )
    p.add_argument(
        "--workers", type=int_at_least("--workers", 1), default=None, help="local worker processes"
    )


#: every command with its one line, in the order `bayespinn help` lists them
COMMANDS = {
    "run": "simulate (or load) data, run the UQ methods, write a report folder",
    "sweep": "run at several SNR levels, one combined report",
    "coverage": "posterior-coverage study over independent synthetic datasets",
    "simulate": "write a synthetic measurement CSV",
    "bench": "performance figures as JSON",
    "help": "this list; `bayespinn help COMMAND` for a command's options",
}


def listing() -> str:
    """What `bayespinn` alone and `bayespinn help` print: the commands, one line each."""
    width = max(map(len, COMMANDS))
    rows = "\n".join(f"  {k:<{width}}  {v}" for k, v in COMMANDS.items())
    return (
        "usage: bayespinn COMMAND [options]\n\n"
        "Girder stiffness (EI) from moving-load measurements, with honest uncertainty.\n\n"
        f"commands:\n{rows}\n\n"
        "quick start: bayespinn run --snr 10   (then open reports/runs/deflection-snr10-seed0/report.html)\n"
    )


def build_parser() -> argparse.ArgumentParser:
    p = Parser(
        prog="bayespinn",
        description="Girder stiffness (EI) from moving-load measurements, with honest uncertainty.",
    )
    p.add_argument("--version", action="version", version=f"bayespinn {__version__}")
    sub = p.add_subparsers(dest="command", required=True, parser_class=Parser)

    r = sub.add_parser("run", help=COMMANDS["run"])
    _common(r)
    r.add_argument("--data", help="a measurement CSV instead of synthetic data")
    r.add_argument("--out", help="output folder (default reports/runs/<case>-snr<S>-seed<seed>)")

    s = sub.add_parser("sweep", help=COMMANDS["sweep"])
    _common(s)
    s.add_argument("--out", help="output folder (default reports/sweeps/<case>-seed<seed>)")

    c = sub.add_parser("coverage", help=COMMANDS["coverage"])
    _common(c)
    c.add_argument("--replicates", type=int_at_least("--replicates", 1), default=100)
    c.add_argument("--level", type=parse_level, default=0.9)
    c.add_argument(
        "--truth",
        default="fixed",
        help="fixed (the config's EI) or prior (draw EI per replicate: SBC)",
    )
    c.add_argument(
        "--out",
        help="coverage JSON file (default reports/coverage/<method>-snr<S>-seed<seed>.json)",
    )
    c.add_argument(
        "--resume",
        action="store_true",
        help="reuse the replicates of the --out file already there when it is the same study "
        "(same method, configuration, SNR, seed, level and options)",
    )

    m = sub.add_parser("simulate", help=COMMANDS["simulate"])
    _common(m, method=False)
    m.add_argument("--out", required=False, help="the CSV file to write")

    b = sub.add_parser("bench", help=COMMANDS["bench"])
    b.add_argument("--out", required=False, help="the JSON file to write")
    b.add_argument("--device", default="auto")
    b.add_argument("--quiet", action="store_true")
    b.add_argument("--verbose", action="store_true", help="also the library's detailed messages")
    b.add_argument("--seed", type=int_at_least("--seed", 0), default=0)
    b.add_argument(
        "--run",
        action="store_true",
        help="also time the quick start's analysis (bayespinn run --snr 10) and break it down by method",
    )
    return p


def _cmd_simulate(args) -> int:
    from .data.synthetic import simulate

    if args.snr is None:
        raise InputError(
            "--snr", None, "'clean' or a finite number of dB > 0 (required for simulate)"
        )
    snr = parse_snr(args.snr)
    if not args.out:
        raise InputError("--out", None, "the path of the CSV file to write")
    from .commands import writable_out

    writable_out(args.out, folder=False)
    cfg = config_from_args(args)
    data = simulate(cfg, snr, args.seed)
    data.to_csv(args.out)
    if not args.quiet:
        log.info(
            "wrote %d %s samples at SNR %s to %s", len(data), cfg.case, snr_label(snr), args.out
        )
    return 0


def _commands():
    from . import commands

    return {
        "simulate": _cmd_simulate,
        "run": commands.cmd_run,
        "sweep": commands.cmd_sweep,
        "coverage": commands.cmd_coverage,
        "bench": commands.cmd_bench,
    }


def _setup_logging(quiet: bool, verbose: bool = False) -> None:
    """bayespinn's own messages to stderr: INFO (progress bars and one line per method phase), DEBUG with
    --verbose (every training step), WARNING with --quiet; other libraries stay quiet. Python warnings the
    library raises become one line each ("warning: ..."), not a file name and a source line."""
    lg = logging.getLogger("bayespinn")
    if not any(getattr(h, "_bayespinn", False) for h in lg.handlers):
        h = logging.StreamHandler(sys.stderr)
        h.setFormatter(logging.Formatter("%(message)s"))
        h._bayespinn = True
        lg.addHandler(h)
    lg.setLevel(logging.WARNING if quiet else logging.DEBUG if verbose else logging.INFO)
    lg.propagate = False
    import warnings

    def one_line(message, category, filename, lineno, file=None, line=None):
        if str(filename).startswith(str(Path(__file__).parent)):
            lg.warning("warning: %s", message)
        else:  # another library's warning: as Python shows it
            _show_warning(message, category, filename, lineno, file, line)

    warnings.showwarning = one_line

    warnings.filterwarnings("ignore", category=FutureWarning, module="arviz")
    warnings.filterwarnings("ignore", message=".*ArviZ is undergoing a major refactor.*")


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script; returns the exit code."""
    argv = sys.argv[1:] if argv is None else argv
    first = next((a for a in argv if not a.startswith("-")), None)
    if first is None and not any(a in ("-h", "--help", "--version") for a in argv):
        print("bayespinn: error: a command is required\n\n" + listing(), end="", file=sys.stderr)
        return 2
    if argv and argv[0] == "help":
        rest = argv[1:]
        if not rest:
            print(listing(), end="")
            return 0
        if rest[0] not in COMMANDS or rest[0] == "help":
            print(
                f"bayespinn: error: help: got {rest[0]!r}, expected a command\n\n" + listing(),
                end="",
                file=sys.stderr,
            )
            return 2
        argv = [rest[0], "--help"]
    if first is not None and first not in COMMANDS and argv[0] == first:
        print(
            f"bayespinn: error: command: got {first!r}, expected one of {', '.join(COMMANDS)}\n\n"
            + listing(),
            end="",
            file=sys.stderr,
        )
        return 2
    try:
        args = build_parser().parse_args(argv)
    except InputError as exc:
        print(f"bayespinn: error: {exc}", file=sys.stderr)
        return 2
    except SystemExit as exc:  # --help / --version
        return int(exc.code or 0)
    quiet = getattr(args, "quiet", False)
    _setup_logging(quiet, getattr(args, "verbose", False))
    from .stopping import stop_cleanly

    try:
        with (
            stop_cleanly()
        ):  # SIGINT/SIGTERM: workers killed, nothing half-written, studies resumable
            return int(_commands()[args.command](args) or 0)
    except InputError as exc:
        print(f"bayespinn: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        print(
            f"bayespinn: stopped ({exc or 'SIGINT'}); finished work is kept for a resume",
            file=sys.stderr,
        )
        return 1  # the contract: 1 for any failure other than bad input
    except Exception as exc:  # noqa: BLE001 - the last line of defence: one line, exit 1
        log.debug("failure", exc_info=True)
        print(f"bayespinn: failed: {exc.__class__.__name__}: {exc}", file=sys.stderr)
        return 1
