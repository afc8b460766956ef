"""The inference methods, as objects, and the one registry that the CLI, the pipeline, sweeps, coverage
studies, the report and the study scripts read.

A method is a small class: its CLI name, summary key, display name and colour are class attributes, it
is built from its own frozen, validated settings, and `infer(data, config, *, seed)` returns a
`Posterior`. The built-in ones are the modal reference (`modal`), the deep ensemble (`ensemble`) and the
B-PINN (`bpinn`, last-layer or full-weight). A user's own method joins everything with `register`:

    import bayespinn as bp

    class Laplace(bp.methods.Method):
        name, key, display, colour = "laplace", "laplace", "Laplace approximation", "#8e44ad"

        def infer(self, data, config, *, seed):
            ...
            return bp.Posterior("laplace", EI_draws, sigma_draws)

    bp.methods.register(Laplace)
    bp.analyse(data, cfg, methods=("modal", "laplace"))
"""

from __future__ import annotations

from ..errors import InputError
from ..options import RunOptions
from .base import Method, Settings, check_choice, check_device

__all__ = [
    "REFERENCE_KEY",
    "Method",
    "Settings",
    "build",
    "by_key",
    "check_choice",
    "check_device",
    "colour",
    "display",
    "get",
    "keys",
    "names",
    "parse",
    "reference_key",
    "register",
    "unregister",
]


_REGISTRY: dict[str, type[Method]] = {}


def register(cls: type[Method], *, replace: bool = False) -> type[Method]:
    """Add a method class to the registry (usable as a decorator). Its CLI name and summary key must be new
    unless `replace`."""
    if not (isinstance(cls, type) and issubclass(cls, Method)):
        raise InputError("method", cls, "a subclass of bayespinn.methods.Method")
    for attr in ("name", "key"):
        v = getattr(cls, attr, None)
        if not isinstance(v, str) or not v or any(c in v for c in " ,/\\="):
            raise InputError(
                f"{cls.__name__}.{attr}", v, "a non-empty name without spaces, commas or slashes"
            )
    if not isinstance(getattr(cls, "display", None), str) or not cls.display:
        raise InputError(
            f"{cls.__name__}.display", getattr(cls, "display", None), "a non-empty string"
        )
    if cls.name == "all":
        raise InputError(f"{cls.__name__}.name", cls.name, "a name other than 'all'")
    clash = [c for c in _REGISTRY.values() if c.key == cls.key and c.name != cls.name]
    if not replace and (cls.name in _REGISTRY or clash):
        raise InputError("method", cls.name, "a name and key not yet registered (or replace=True)")
    _REGISTRY[cls.name] = cls
    return cls


def unregister(name: str) -> None:
    """Remove a method (a user's; the built-in ones can be removed too, e.g. in tests)."""
    _REGISTRY.pop(name, None)


def names() -> tuple[str, ...]:
    """The CLI names of the registered methods, the reference first."""
    return tuple(_REGISTRY)


def get(name: str) -> type[Method]:
    """The method class of a CLI name (InputError naming `--method` otherwise)."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise InputError("--method", name, ", ".join(names())) from None


def keys() -> tuple[str, ...]:
    """Summary keys of the registered methods, in registry order."""
    return tuple(c.key for c in _REGISTRY.values())


def by_key(key: str) -> type[Method] | None:
    """The method class of a summary key, or None."""
    return next((c for c in _REGISTRY.values() if c.key == key), None)


def display(key: str) -> str:
    """The display name of a summary key (the key itself when no method has it)."""
    c = by_key(key)
    return c.display if c else key


def colour(key: str) -> str:
    c = by_key(key)
    return c.colour if c else Method.colour


def reference_key() -> str | None:
    """The summary key of the reference method, the one the others are judged against."""
    return next((c.key for c in _REGISTRY.values() if c.reference), None)


def parse(text: str, single: bool = False) -> list[str]:
    """'all' or a comma list of registered CLI names -> the list in registry order (the reference first);
    InputError naming `--method` for an unknown name."""
    known = names()
    wanted = list(known) if text.strip() == "all" else [m.strip() for m in text.split(",")]
    for m in wanted:
        if m not in known:
            raise InputError("--method", text, f"{', '.join(known)}, all, or a comma list of them")
    if single and len(wanted) != 1:
        raise InputError("--method", text, f"exactly one of {', '.join(known)}")
    return [m for m in known if m in wanted]


def build(name: str, opts: RunOptions | None = None) -> Method:
    """The method of a CLI name built from the command line's options."""
    return get(name).from_options(opts or RunOptions())


def _builtins() -> None:
    from .bpinn import BPINN
    from .ensemble import DeepEnsemble
    from .modal import ModalMCMC

    for c in (ModalMCMC, DeepEnsemble, BPINN):
        register(c)


_builtins()

#: the summary key of the reference method (the modal one's, `methods.modal`), the one the others are
#: judged against
REFERENCE_KEY: str = reference_key()
