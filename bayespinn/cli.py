"""The `bayespinn` command line: parse, resolve configuration (preset < TOML < flags), call the library,
map errors to exit codes (0 ok, 2 bad usage or input, 1 anything else). No science here."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from . import __version__
from .config import Config, parse_snr, resolve, snr_label
from .errors import InputError

log = logging.getLogger("bayespinn")

METHOD_KEYS = {"modal": "modal_mcmc", "ensemble": "ensemble", "bpinn": "bpinn"}


class UsageError(InputError):
    """A flag-level error found by argparse."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # one line, exit 2, no usage dump
        raise UsageError("command line", " ".join(sys.argv[1:]), message)


def _int(name: str, minimum: int):
    def conv(s: str) -> int:
        try:
            v = int(s)
        except ValueError:
            raise InputError(name, s, f"an integer >= {minimum}") from None
        if v < minimum:
            raise InputError(name, s, f"an integer >= {minimum}")
        return v

    return conv


def parse_methods(text: str, single: bool = False) -> list[str]:
    """'all' or a comma list of modal, ensemble, bpinn -> ordered list of method names."""
    names = (
        ["modal", "ensemble", "bpinn"]
        if text.strip() == "all"
        else [m.strip() for m in text.split(",")]
    )
    for m in names:
        if m not in METHOD_KEYS:
            raise InputError(
                "--method", text, "modal, ensemble, bpinn, all, or a comma list of them"
            )
    if single and len(names) != 1:
        raise InputError("--method", text, "exactly one of modal, ensemble, bpinn")
    return [m for m in ("modal", "ensemble", "bpinn") if m in names]


def parse_level(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise InputError("--level", text, "a credible level in (0, 1), e.g. 0.9") from None
    if not 0.0 < v < 1.0:
        raise InputError("--level", text, "a credible level in (0, 1), e.g. 0.9")
    return v


def _common(p: argparse.ArgumentParser, *, snr: bool = True, method: bool = True) -> None:
    if snr:
        p.add_argument("--snr", help="'clean' or a finite SNR in dB (> 0)")
    p.add_argument(
        "--case", default="deflection", help="deflection (case study 1) or strain (case study 2)"
    )
    if method:
        p.add_argument(
            "--method", default="all", help="modal, ensemble, bpinn, all, or a comma list"
        )
    p.add_argument(
        "--members", type=_int("--members", 1), default=5, help="ensemble size (default 5)"
    )
    p.add_argument("--profile", default="fast", help="smoke, fast (default) or paper")
    p.add_argument("--config", help="TOML file overriding the Exeter preset")
    p.add_argument("--seed", type=_int("--seed", 0), default=0, help="root seed (default 0)")
    p.add_argument("--device", default="auto", help="auto, cpu or cuda")
    p.add_argument("--executor", default="local", help="local (process pool) or ray")
    p.add_argument(
        "--address", default=None, help="Ray cluster address (with --executor ray), or 'auto'"
    )
    p.add_argument(
        "--workers", type=_int("--workers", 1), default=None, help="local worker processes"
    )
    p.add_argument("--noise-prior", dest="noise_prior", default="vague", help="vague or snr")
    p.add_argument(
        "--bpinn-variant",
        dest="bpinn_variant",
        default="auto",
        help="B-PINN sampler: last-layer, full (every hidden weight), or auto (default: full for "
        "--profile paper, else last-layer)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress output")


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="bayespinn",
        description="Girder stiffness (EI) from moving-load measurements, with honest uncertainty.",
    )
    p.add_argument("--version", action="version", version=f"bayespinn {__version__}")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)

    r = sub.add_parser(
        "run", help="simulate (or load) data, run the UQ methods, write a report folder"
    )
    _common(r)
    r.add_argument("--data", help="a measurement CSV instead of synthetic data")
    r.add_argument("--out", help="output folder (default reports/runs/<case>-snr<S>-seed<seed>)")

    s = sub.add_parser("sweep", help="run at several SNR levels, one combined report")
    _common(s)
    s.add_argument("--out", help="output folder (default reports/sweeps/<case>-seed<seed>)")

    c = sub.add_parser(
        "coverage", help="posterior-coverage study over independent synthetic datasets"
    )
    _common(c)
    c.add_argument("--replicates", type=_int("--replicates", 1), default=100)
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
    c.add_argument(
        "--mix-versions",
        dest="mix_versions",
        action="store_true",
        help="keep resumed replicates computed by other code than today's (recorded in the study); "
        "without it they are refused",
    )

    m = sub.add_parser("simulate", help="write a synthetic measurement CSV")
    _common(m, method=False)
    m.add_argument("--out", required=False, help="the CSV file to write")

    b = sub.add_parser("bench", help="performance figures as JSON")
    b.add_argument("--out", required=False, help="the JSON file to write")
    b.add_argument("--device", default="auto")
    b.add_argument("--quiet", action="store_true")
    b.add_argument("--seed", type=_int("--seed", 0), default=0)
    return p


def resolve_device(name: str) -> str:
    """'auto' -> 'cuda' when a GPU is usable, else 'cpu'; 'cuda' without a GPU is bad input."""
    if name not in ("auto", "cpu", "cuda"):
        raise InputError("--device", name, "auto, cpu or cuda")
    if name == "cpu":
        return "cpu"
    import torch

    has = torch.cuda.is_available()
    if name == "cuda" and not has:
        raise InputError(
            "--device", name, "a machine with a CUDA GPU (none is visible here); use cpu or auto"
        )
    return "cuda" if has else "cpu"


def _config(args) -> Config:
    if args.case not in ("deflection", "strain"):
        raise InputError("--case", args.case, "deflection or strain")
    if getattr(args, "profile", "fast") not in ("smoke", "fast", "paper"):
        raise InputError("--profile", args.profile, "smoke, fast or paper")
    if getattr(args, "bpinn_variant", "auto") not in ("auto", "last-layer", "full"):
        raise InputError("--bpinn-variant", args.bpinn_variant, "auto, last-layer or full")
    if getattr(args, "noise_prior", "vague") not in ("vague", "snr"):
        raise InputError("--noise-prior", args.noise_prior, "vague or snr")
    if getattr(args, "executor", "local") not in ("local", "ray"):
        raise InputError("--executor", args.executor, "local or ray")
    resolve_device(getattr(args, "device", "auto"))
    return resolve(args.case, args.config)


def _cmd_simulate(args) -> int:
    from .data.synthetic import simulate

    if args.snr is None:
        raise InputError(
            "--snr", None, "'clean' or a finite number of dB > 0 (required for simulate)"
        )
    snr = parse_snr(args.snr)
    if not args.out:
        raise InputError("--out", None, "the path of the CSV file to write")
    cfg = _config(args)
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


def _setup_logging(quiet: bool) -> None:
    """bayespinn's own messages to stderr (INFO, or WARNING with --quiet); other libraries stay quiet."""
    lg = logging.getLogger("bayespinn")
    if not any(getattr(h, "_bayespinn", False) for h in lg.handlers):
        h = logging.StreamHandler(sys.stderr)
        h.setFormatter(logging.Formatter("%(message)s"))
        h._bayespinn = True
        lg.addHandler(h)
    lg.setLevel(logging.WARNING if quiet else logging.INFO)
    lg.propagate = False
    import warnings

    warnings.filterwarnings("ignore", category=FutureWarning, module="arviz")
    warnings.filterwarnings("ignore", message=".*ArviZ is undergoing a major refactor.*")


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script; returns the exit code."""
    argv = sys.argv[1:] if argv is None else argv
    try:
        args = build_parser().parse_args(argv)
    except InputError as exc:
        print(f"bayespinn: error: {exc}", file=sys.stderr)
        return 2
    except SystemExit as exc:  # --help / --version
        return int(exc.code or 0)
    quiet = getattr(args, "quiet", False)
    _setup_logging(quiet)
    try:
        return int(_commands()[args.command](args) or 0)
    except InputError as exc:
        print(f"bayespinn: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("bayespinn: interrupted", file=sys.stderr)
        return 1
    except Exception as exc:  # noqa: BLE001 - the last line of defence: one line, exit 1
        log.debug("failure", exc_info=True)
        print(f"bayespinn: failed: {exc.__class__.__name__}: {exc}", file=sys.stderr)
        return 1


def default_out(args, kind: str = "runs") -> Path:
    snr = parse_snr(args.snr) if getattr(args, "snr", None) is not None else None
    label = "data" if getattr(args, "data", None) else f"snr{snr_label(snr)}"
    return Path("reports") / kind / f"{args.case}-{label}-seed{args.seed}"
