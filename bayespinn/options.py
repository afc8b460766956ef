"""Option parsing and validation shared by the command line and the study scripts.

Every bad value raises `InputError` naming the flag, the value and what was expected (the CLI maps it
to exit code 2), so a mistyped profile or method fails the same way from any entry point.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from .config import Config, parse_snr, resolve, snr_label
from .errors import InputError

PROFILES = ("smoke", "fast", "paper")
BPINN_VARIANTS = ("auto", "last-layer", "full")
NOISE_PRIORS = ("vague", "snr")
EXECUTORS = ("local", "ray")
CASES = ("deflection", "strain")


@dataclass(frozen=True)
class RunOptions:
    """The command line's method options, one bag for every method; each method takes the fields its own
    settings have (`bayespinn.methods.Method.from_options`)."""

    profile: str = "fast"
    members: int = 5
    device: str = "cpu"
    noise_prior: str = "vague"
    snr_db: float | None = None
    progress: bool = False
    executor: object = None  # bayespinn.executor.Executor for ensemble members
    mcmc: object = None  # bayespinn.uq.sampler.MCMCSettings overriding the profile's
    bpinn_variant: str = "auto"  # last-layer, full, or auto (`uq.bpinn_core.resolve_variant`)


def int_at_least(name: str, minimum: int):
    """An argparse type: an integer >= minimum, else InputError naming the flag."""

    def conv(s: str) -> int:
        try:
            v = int(s)
        except ValueError:
            raise InputError(name, s, f"an integer >= {minimum}") from None
        if v < minimum:
            raise InputError(name, s, f"an integer >= {minimum}")
        return v

    return conv


def parse_level(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise InputError("--level", text, "a credible level in (0, 1), e.g. 0.9") from None
    if not 0.0 < v < 1.0:
        raise InputError("--level", text, "a credible level in (0, 1), e.g. 0.9")
    return v


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


def check_choices(args) -> None:
    """InputError naming the flag for a bad profile, B-PINN variant, noise prior or executor (flags a
    command does not have are skipped)."""
    if getattr(args, "profile", "fast") not in PROFILES:
        raise InputError("--profile", args.profile, "smoke, fast or paper")
    if getattr(args, "bpinn_variant", "auto") not in BPINN_VARIANTS:
        raise InputError("--bpinn-variant", args.bpinn_variant, "auto, last-layer or full")
    if getattr(args, "noise_prior", "vague") not in NOISE_PRIORS:
        raise InputError("--noise-prior", args.noise_prior, "vague or snr")
    if getattr(args, "executor", "local") not in EXECUTORS:
        raise InputError("--executor", args.executor, "local or ray")


def config_from_args(args) -> Config:
    """Check the common flags of a parsed command line and resolve its configuration (preset < TOML)."""
    if args.case not in CASES:
        raise InputError("--case", args.case, "deflection or strain")
    check_choices(args)
    cfg = resolve(args.case, args.config)  # first: a bad input is told before torch is imported
    resolve_device(getattr(args, "device", "auto"))
    return cfg


def default_out(args, kind: str = "runs") -> Path:
    """reports/<kind>/<case>-snr<S>-seed<seed> (or -data- for a measurement file)."""
    snr = parse_snr(args.snr) if getattr(args, "snr", None) is not None else None
    label = "data" if getattr(args, "data", None) else f"snr{snr_label(snr)}"
    return Path("reports") / kind / f"{args.case}-{label}-seed{args.seed}"
