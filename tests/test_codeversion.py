"""Code versions: what a result's numbers depend on, and nothing else."""

from __future__ import annotations

import bayespinn.codeversion as cv


def test_a_method_depends_on_its_own_modules_and_the_simulator_only():
    from bayespinn import methods

    modal = cv.closure(*methods.get("modal").code_modules(), *cv.DATA_MODULES)
    assert "bayespinn.uq.modal_mcmc" in modal and "bayespinn.physics.modal" in modal
    assert "bayespinn.data.synthetic" in modal and "bayespinn.physics.fem" in modal
    assert "bayespinn.seeding" in modal and "bayespinn.config" in modal
    assert not any(m.startswith(("bayespinn.pinn", "bayespinn.report")) for m in modal)
    # the registry (which imports every method) is not followed: no method depends on another
    assert not any(m.startswith(("bayespinn.uq.ensemble", "bayespinn.uq.bpinn")) for m in modal)
    assert "bayespinn.methods.modal" in modal and "bayespinn.methods.base" in modal
    bpinn = cv.closure(*methods.get("bpinn").code_modules())
    assert "bayespinn.uq.bpinn" in bpinn and "bayespinn.uq.bpinn_full" in bpinn  # both variants
    assert (
        "bayespinn.uq.nuts" in bpinn and "bayespinn.pinn.train" in bpinn
    )  # imports inside functions count


def test_version_ignores_docstrings_and_formatting_but_not_code(tmp_path, monkeypatch):
    pkg = tmp_path / "bayespinn"
    (pkg / "uq").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "uq" / "__init__.py").write_text("")
    src = pkg / "uq" / "m.py"
    src.write_text(
        '"""Doc."""\nfrom .. import helper\n\ndef f(x):\n    """f."""\n    return x + 1\n'
    )
    (pkg / "helper.py").write_text("A = 1\n")
    monkeypatch.setattr(cv, "ROOT", pkg)
    cv._module_digest.cache_clear()
    v0 = cv.code_version("bayespinn.uq.m")
    src.write_text(
        '"""Other words."""\nfrom .. import helper\n\n\ndef f(x):\n    return (x + 1)  # same\n'
    )
    cv._module_digest.cache_clear()
    assert cv.code_version("bayespinn.uq.m") == v0
    (pkg / "helper.py").write_text("A = 2\n")  # an imported module's code changes: a new version
    cv._module_digest.cache_clear()
    assert cv.code_version("bayespinn.uq.m") != v0
    cv._module_digest.cache_clear()


def test_the_root_package_init_is_not_followed(tmp_path, monkeypatch):
    """The public API's re-exports (bayespinn/__init__.py importing the pipeline) change no method's version;
    a submodule imported through `from .. import x` still counts."""
    pkg = tmp_path / "bayespinn"
    (pkg / "uq").mkdir(parents=True)
    (pkg / "uq" / "__init__.py").write_text("")
    (pkg / "uq" / "m.py").write_text("from .. import seeding\n\ndef f():\n    return seeding.A\n")
    (pkg / "seeding.py").write_text("A = 1\n")
    (pkg / "api.py").write_text("B = 1\n")
    (pkg / "__init__.py").write_text("from .api import B\n")
    monkeypatch.setattr(cv, "ROOT", pkg)
    cv._module_digest.cache_clear()
    v0 = cv.code_version("bayespinn.uq.m")
    assert "bayespinn.seeding" in cv.closure("bayespinn.uq.m")
    (pkg / "api.py").write_text("B = 2\n")
    cv._module_digest.cache_clear()
    assert cv.code_version("bayespinn.uq.m") == v0
    (pkg / "seeding.py").write_text("A = 2\n")
    cv._module_digest.cache_clear()
    assert cv.code_version("bayespinn.uq.m") != v0
    cv._module_digest.cache_clear()


def test_ast_dump_is_python_311s_on_any_python():
    """The code version of a source does not depend on the Python that reads it (3.12 adds empty
    `type_params` to functions and classes, 3.13 hides empty fields): the dump is 3.11's."""
    import ast

    from bayespinn.codeversion import _dump

    tree = ast.parse("class A:\n    def f(self):\n        pass\n")
    assert _dump(tree) == (
        "Module([ClassDef('A', [], [], [FunctionDef('f', arguments([], [arg('self')], kwonlyargs=[], "
        "kw_defaults=[], defaults=[]), [Pass()], [])], [])], [])"
    )
