"""Command-line flags shared by `bayespinn` and the study scripts: one-line errors (`Parser`), the flags
that choose how the methods run (`add_method_flags`) and their checks (`check_method_flags`)."""

from __future__ import annotations

import argparse
import sys

from .errors import InputError
from .options import check_choices, int_at_least, resolve_device


class UsageError(InputError):
    """A flag-level error found by argparse."""


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors: a bad flag raises UsageError (exit 2 where it is caught), no usage dump."""

    def error(self, message: str):
        raise UsageError("command line", " ".join(sys.argv[1:]), message)

    def _get_value(self, action, arg_string):
        # argparse turns any ValueError of a flag's type into "invalid <function> value"; the types of
        # `options` raise InputError, which already names the flag, the value and what was expected
        try:
            return super()._get_value(action, arg_string)
        except argparse.ArgumentError as err:
            if isinstance(err.__context__, InputError):
                raise err.__context__ from None
            raise


def add_method_flags(p: argparse.ArgumentParser) -> None:
    """The flags that choose how the methods run, declared once for the command line and the study scripts
    (`check_method_flags` checks their values)."""
    p.add_argument(
        "--members", type=int_at_least("--members", 1), default=5, help="ensemble size (default 5)"
    )
    p.add_argument(
        "--profile",
        default="fast",
        help="smoke (seconds, tests), fast (default, minutes on a 2-core CPU) or paper",
    )
    p.add_argument(
        "--seed", type=int_at_least("--seed", 0), default=0, help="root seed (default 0)"
    )
    p.add_argument("--device", default="auto", help="auto, cpu or cuda (default auto)")
    p.add_argument(
        "--noise-prior",
        dest="noise_prior",
        default="vague",
        help="prior on the noise sd: vague (default) or snr",
    )
    p.add_argument(
        "--bpinn-variant",
        dest="bpinn_variant",
        default="auto",
        help="B-PINN sampler: last-layer, full (every hidden weight; hours per run, see docs/methods.md), "
        "or auto (default: last-layer)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.add_argument(
        "--verbose",
        action="store_true",
        help="also every training step and the library's detailed messages",
    )


def check_method_flags(args) -> None:
    """InputError naming the flag for a bad profile, B-PINN variant, noise prior, executor or device."""
    check_choices(args)
    resolve_device(getattr(args, "device", "auto"))
