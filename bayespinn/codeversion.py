"""Which code produced a result: a fingerprint of the source a method's numbers depend on.

A git commit names the whole tree, so it changes with every edit to a report or a README and says
nothing about whether an old result still holds. `code_version(module)` instead hashes the syntax
trees (docstrings dropped, so neither formatting nor documentation counts) of the module and of every
bayespinn module it imports, transitively, including imports inside functions. Two results with the
same code version were computed by the same code; a record whose version differs from today's was
computed by code that has changed since, and is stale until it is re-run. Package `__init__` files
hold re-exports only: their imports are followed, their own text is not hashed; the root package's
`__init__` (the public API: `analyse`, `write_run`, ...) is not followed at all, since no method's
numbers come from it.
"""

from __future__ import annotations

import ast
import functools
import hashlib
import sys
from pathlib import Path

PACKAGE = "bayespinn"
ROOT = Path(__file__).resolve().parent

#: packages whose `__init__` is never followed: the root (the public API's re-exports) and the method
#: registry (it imports every built-in method to register it; no method's numbers come from another's)
NOT_FOLLOWED = (PACKAGE, PACKAGE + ".methods")
#: what every synthetic-data result depends on besides the method: the data simulator
DATA_MODULES = ("bayespinn.data.synthetic",)


def module_path(name: str) -> Path | None:
    """The source file of a bayespinn module (or of a user's module that holds a registered method), or
    None when it is neither."""
    if name != PACKAGE and not name.startswith(PACKAGE + "."):
        return _user_module(name)
    parts = name.split(".")[1:]
    if not parts:
        return ROOT / "__init__.py"
    rel = Path(*parts)
    for cand in (ROOT / rel.with_suffix(".py"), ROOT / rel / "__init__.py"):
        if cand.is_file():
            return cand
    return None


def _user_module(name: str) -> Path | None:
    import sys

    from . import methods

    if not any(name in c.code_modules() for c in map(methods.get, methods.names())):
        return None
    f = getattr(sys.modules.get(name), "__file__", None)
    return Path(f) if f and f.endswith(".py") and Path(f).is_file() else None


def _resolve(module: str, node: ast.ImportFrom) -> list[str]:
    """Absolute module names an ImportFrom inside `module` may refer to."""
    if node.level:
        base = module.split(".")
        is_pkg = module_path(module) is not None and module_path(module).name == "__init__.py"
        base = base if is_pkg else base[:-1]
        base = base[: len(base) - (node.level - 1)]
        stem = ".".join(base + ([node.module] if node.module else []))
    else:
        stem = node.module or ""
    # `from pkg import name` may import a submodule called name
    return [stem] + [f"{stem}.{a.name}" for a in node.names]


def imports_of(module: str) -> set[str]:
    """The bayespinn modules that `module` imports anywhere in its source."""
    path = module_path(module)
    if path is None:
        return set()
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            names = _resolve(module, node)
        else:
            continue
        # the root package's __init__ holds the public API's re-exports (run, analyse, ...) and the method
        # registry's imports every method: importing a submodule runs them, but no method's numbers come
        # from them, so they are never followed (`NOT_FOLLOWED`)
        out.update(n for n in names if n not in NOT_FOLLOWED and module_path(n) is not None)
    return out


def closure(*modules: str) -> list[str]:
    """`modules` and every bayespinn module they import, transitively (sorted)."""
    seen: set[str] = set()
    todo = [m for m in modules if module_path(m) is not None]
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        seen.add(m)
        # a submodule's package __init__ runs first (the root package's excepted, see `imports_of`)
        parent = m.rpartition(".")[0]
        parents = {parent} if parent and parent not in NOT_FOLLOWED else set()
        todo.extend(i for i in imports_of(m) | parents if i not in seen)
    return sorted(seen)


def _strip_docstrings(tree: ast.AST) -> ast.AST:
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                if isinstance(body[0].value.value, str):
                    node.body = body[1:] or [ast.Pass()]
    return tree


def _dump(tree: ast.AST) -> str:
    """`ast.dump` as Python 3.11 writes it, on any later Python too: 3.12 added the (here always empty)
    `type_params` field to functions and classes, and 3.13 hides empty fields unless told to show them, so
    the same source would otherwise get another code version under another Python (a GPU machine's 3.12)."""
    kw = {}
    if sys.version_info >= (3, 12):
        for node in ast.walk(tree):
            if "type_params" in node._fields and not getattr(node, "type_params", None):
                delattr(node, "type_params")
    if sys.version_info >= (3, 13):
        kw["show_empty"] = True
    return ast.dump(tree, annotate_fields=False, **kw)


@functools.cache
def _module_digest(module: str) -> str:
    path = module_path(module)
    tree = _strip_docstrings(ast.parse(path.read_text(encoding="utf-8")))
    return hashlib.sha256(_dump(tree).encode()).hexdigest()


def code_version(*modules: str) -> str:
    """A 12-hex-digit fingerprint of the code of `modules` and everything they import."""
    h = hashlib.sha256()
    for m in closure(*modules):
        if module_path(m).name == "__init__.py":
            continue  # re-exports only: followed for their imports, not hashed
        h.update(m.encode() + b"\0" + _module_digest(m).encode() + b"\n")
    return h.hexdigest()[:12]


def method_version(method: str, *extra: str) -> str:
    """The code version of one method's results on synthetic data (CLI name: modal, ensemble, bpinn, or a
    registered method's): its class's `code_modules()`, the data simulator and everything they import.

    extra : further modules the result depends on (e.g. the coverage driver for a coverage record)
    """
    from . import methods

    try:
        mods = methods.get(method).code_modules()
    except Exception:  # noqa: BLE001 - InputError: not a registered method
        raise ValueError(
            f"no code version for method {method!r}; known: {', '.join(methods.names())}"
        ) from None
    return code_version(*mods, *DATA_MODULES, *extra)


def forget() -> None:
    """Drop this process's memo of module digests, so that the next versions are read from disk afresh."""
    _module_digest.cache_clear()
