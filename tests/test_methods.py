"""Methods as objects: the registry, settings validation, a user's method through run, sweep, coverage and
the report, and the package's import structure (no cycles, no method module importing another)."""

from __future__ import annotations

import ast
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

import bayespinn as bp
from bayespinn import methods
from bayespinn.errors import InputError
from bayespinn.executor import Executor
from bayespinn.options import RunOptions

PACKAGE = Path(bp.__file__).resolve().parent


# ------------------------------------------------------------------------------------------ registry
def test_builtin_methods_in_the_registry():
    assert methods.names()[:3] == ("modal", "ensemble", "bpinn")
    assert methods.keys()[:3] == ("modal_mcmc", "ensemble", "bpinn")
    assert methods.reference_key() == "modal_mcmc"
    assert methods.display("ensemble") == "Deep ensemble"
    assert methods.colour("bpinn").startswith("#")
    assert methods.parse("all")[:3] == ["modal", "ensemble", "bpinn"]
    assert methods.parse("bpinn,modal") == ["modal", "bpinn"]  # registry order, the reference first


def test_bpinn_settings_pick_the_variant():
    from bayespinn.methods.bpinn import FullWeightBPINN, LastLayerBPINN

    assert type(methods.build("bpinn", RunOptions(profile="fast"))) is LastLayerBPINN
    assert (
        type(methods.build("bpinn", RunOptions(profile="paper"))) is LastLayerBPINN
    )  # never a default
    assert type(methods.get("bpinn")(bpinn_variant="full", profile="smoke")) is FullWeightBPINN
    assert (
        type(methods.build("bpinn", RunOptions(profile="paper", bpinn_variant="full")))
        is FullWeightBPINN
    )


@pytest.mark.parametrize(
    ("name", "fields", "field"),
    [
        ("modal", {"profile": "fastt"}, "profile"),
        ("modal", {"noise_prior": "flat"}, "noise_prior"),
        ("ensemble", {"members": 0}, "members"),
        ("ensemble", {"members": 2.5}, "members"),
        ("ensemble", {"device": "tpu"}, "device"),
        ("bpinn", {"bpinn_variant": "fulll"}, "bpinn_variant"),
    ],
)
def test_bad_settings_name_the_field(name, fields, field):
    with pytest.raises(InputError) as e:
        methods.get(name)(**fields)
    assert e.value.field == field


def test_unknown_method_names_the_flag():
    with pytest.raises(InputError) as e:
        methods.parse("modal,ensemblee")
    assert e.value.field == "--method"
    with pytest.raises(InputError):
        methods.get("nope")


def test_bad_registrations_are_refused():
    class NoKey(methods.Method):
        name, display = "nokey", "No key"

    with pytest.raises(InputError):
        methods.register(NoKey)
    with pytest.raises(InputError):
        methods.register(
            type("Clash", (methods.Method,), {"name": "x2", "key": "ensemble", "display": "x"})
        )
    with pytest.raises(InputError):
        methods.register(int)


# ------------------------------------------------------------------------------------------ a user's method
@dataclass(frozen=True)
class ToySettings(methods.Settings):
    draws: int = 400


class Toy(methods.Method):
    """A user's method: log-normal EI around the prior median with the prior's spread, sigma from the data's
    scatter about a smooth fit (no physics; only the plumbing is under test)."""

    name, key, display, colour = "toy", "toy", "Toy method", "#8e44ad"
    Settings = ToySettings

    def infer(self, data, config, *, seed):
        from bayespinn.uq.priors import EIPrior

        rng = np.random.default_rng(np.random.SeedSequence(seed if isinstance(seed, int) else 0))
        prior = EIPrior.from_spec(config.prior)
        ei = prior.sample(rng, (2, self.settings.draws))
        sd = float(np.std(data.value)) if len(data) else 1.0
        sigma = sd * np.exp(0.05 * rng.standard_normal((2, self.settings.draws)))
        return bp.Posterior(self.key, ei, sigma, diagnostics={"converged": True})


@pytest.fixture
def toy():
    methods.register(Toy)
    yield Toy
    methods.unregister("toy")


def test_a_users_method_runs_through_run_and_the_report(toy, tmp_path):
    from bayespinn.pipeline import run

    out = tmp_path / "run"
    run(
        bp.preset(),
        methods=["modal", "toy"],
        snr_db=20.0,
        seed=1,
        out=out,
        opts=RunOptions(profile="smoke"),
        argv=["test"],
    )
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["methods"]) == {"modal_mcmc", "toy"}
    assert "toy" in summary["agreement"]  # judged against the reference like a PINN
    manifest = json.loads((out / "manifest.json").read_text())
    assert set(manifest["methods"]) == {"modal_mcmc", "toy"} and "git_commit" in manifest
    assert (out / "posterior_toy.nc").is_file()
    import jsonschema
    from test_schemas import schema

    for name, doc in (("summary", summary), ("manifest", manifest)):
        jsonschema.validate(doc, schema(name), cls=jsonschema.Draft202012Validator)
    assert "Toy method" in (out / "report.md").read_text(encoding="utf-8")


def test_a_users_method_runs_through_analyse_as_an_instance(toy):
    cfg = bp.preset()
    data = bp.simulate(cfg, snr_db=20, seed=3)
    res = bp.analyse(data, cfg, methods=[Toy(draws=50)], seed=0)
    assert res.posteriors["toy"].EI.shape == (2, 50)


def test_a_users_method_runs_through_sweep_and_coverage(toy, tmp_path):
    from bayespinn.sweep import sweep
    from bayespinn.uq.coverage import coverage_study

    opts = RunOptions(profile="smoke", executor=Executor("local", workers=1))
    doc = sweep(bp.preset(), levels=[20.0, 30.0], methods=["toy"], seed=0, out=tmp_path, opts=opts)
    assert len(doc["levels"]) == 2 and (tmp_path / "snr20" / "summary.json").is_file()
    res = coverage_study(
        "toy",
        bp.preset(),
        20.0,
        replicates=4,
        seed=0,
        opts=RunOptions(profile="smoke"),
        executor=Executor("local", workers=1),
        progress=False,
    )
    assert res["method"] == "toy" and res["replicates"] == 4
    assert sum(res["commits"].values()) == 4  # each replicate names the commit that computed it


# ------------------------------------------------------------------------------------------ imports
def _modules() -> dict[str, Path]:
    out = {}
    for p in PACKAGE.rglob("*.py"):
        parts = p.relative_to(PACKAGE.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = p
    return out


def _imports(mods: dict[str, Path]) -> dict[str, set[str]]:
    """Every bayespinn module each module imports, anywhere in its source (inside functions too)."""
    graph = {}
    for name, path in mods.items():
        pkg = name if path.name == "__init__.py" else name.rpartition(".")[0]
        deps = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                deps.update(a.name for a in node.names if a.name in mods)
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = pkg.split(".")
                    base = base[: len(base) - (node.level - 1)]
                    stem = ".".join(base + ([node.module] if node.module else []))
                else:
                    stem = node.module or ""
                for a in node.names:
                    full = f"{stem}.{a.name}"
                    deps.add(full if full in mods else stem)
        graph[name] = {d for d in deps if d in mods and d != name}
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    return out


def test_no_import_cycle_in_the_package():
    assert _cycles(_imports(_modules())) == []


def test_the_cycle_finder_finds_a_cycle():
    """Negative control: a cycle planted in a copy of the graph is found."""
    g = _imports(_modules())
    g["bayespinn.uq.posterior"] = g["bayespinn.uq.posterior"] | {"bayespinn.uq.modal_mcmc"}
    found = _cycles(g)
    assert len(found) == 1 and {"bayespinn.uq.modal_mcmc", "bayespinn.uq.posterior"} <= set(
        found[0]
    )


def _string_literals(sources: dict[str, str], text: str) -> list[str]:
    """The modules whose source has `text` as a string constant (docstrings and comments aside)."""
    out = []
    for name, src in sources.items():
        tree = ast.parse(src)
        docs = {
            id(n.body[0].value)
            for n in ast.walk(tree)
            if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
            and n.body
            and isinstance(n.body[0], ast.Expr)
            and isinstance(n.body[0].value, ast.Constant)
        }
        if any(
            isinstance(n, ast.Constant) and n.value == text and id(n) not in docs
            for n in ast.walk(tree)
        ):
            out.append(name)
    return sorted(out)


def test_the_reference_key_is_written_only_in_the_modal_method():
    """Everything else finds the reference through the registry (`methods.REFERENCE_KEY`)."""
    sources = {n: p.read_text(encoding="utf-8") for n, p in _modules().items()}
    assert _string_literals(sources, methods.REFERENCE_KEY) == ["bayespinn.methods.modal"]
    assert methods.REFERENCE_KEY == methods.reference_key() == methods.get("modal").key


def test_the_literal_finder_finds_a_planted_literal():
    """Negative control: the key written into another module is found; in a docstring it is not."""
    sources = {n: p.read_text(encoding="utf-8") for n, p in _modules().items()}
    sources["bayespinn.uq.posterior"] += f"\nKEY = {methods.REFERENCE_KEY!r}\n"
    sources["bayespinn.uq.agreement"] += f"\n\ndef f():\n    {methods.REFERENCE_KEY!r}\n"
    assert _string_literals(sources, methods.REFERENCE_KEY) == [
        "bayespinn.methods.modal",
        "bayespinn.uq.posterior",
    ]


#: each method's own modules: the class and what computes it
FAMILIES = {
    "modal": {"bayespinn.methods.modal", "bayespinn.uq.modal_mcmc"},
    "ensemble": {"bayespinn.methods.ensemble", "bayespinn.uq.ensemble"},
    "bpinn": {"bayespinn.methods.bpinn", "bayespinn.uq.bpinn", "bayespinn.uq.bpinn_full"},
}


def test_no_method_module_imports_another_method():
    g = _imports(_modules())
    for fam, mods in FAMILIES.items():
        others = set().union(*(m for f, m in FAMILIES.items() if f != fam))
        for m in mods:
            assert not g[m] & others, f"{m} imports {g[m] & others}"
    # the two B-PINN variants share bpinn_core, nuts and lastlayer, and neither imports the other
    assert "bayespinn.uq.bpinn_full" not in g["bayespinn.uq.bpinn"]
    assert "bayespinn.uq.bpinn" not in g["bayespinn.uq.bpinn_full"]
