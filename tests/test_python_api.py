"""The Python API of the contract: analyse in memory, write_run, and the README's example as written."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

import bayespinn as bp
from bayespinn.errors import InputError
from bayespinn.options import RunOptions

ROOT = Path(__file__).resolve().parents[1]


def readme_example() -> str:
    """Every python block of the README's 'From Python' section, in order (one program)."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    m = re.search(r"^## From Python\n(.*?)(?=^## )", text, re.S | re.M)
    assert m, "README has no '## From Python' section"
    blocks = re.findall(r"```python\n(.*?)```", m.group(1), re.S)
    assert blocks, "the 'From Python' section has no python block"
    return "\n".join(blocks)


def test_readme_example_runs_as_written(tmp_path, monkeypatch, capsys):
    from bayespinn import methods

    monkeypatch.chdir(tmp_path)
    before = methods.names()
    try:
        exec(compile(readme_example(), "README.md", "exec"), {"__name__": "__readme__"})
    finally:
        for n in set(methods.names()) - set(before):  # the example's own method
            methods.unregister(n)
    assert "90 %" in capsys.readouterr().out
    folder = tmp_path / "reports" / "runs" / "from-python"
    summary = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
    assert summary["methods"]["modal_mcmc"]["EI"]["rel_error_pct"] is not None
    assert (folder / "report.html").is_file() and (folder / "posterior_modal_mcmc.nc").is_file()


def test_analyse_writes_no_file_and_matches_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cfg = bp.resolve("deflection")
    data = bp.simulate(cfg, snr_db=20, seed=3)
    res = bp.analyse(data, cfg, methods="modal", seed=0, profile="smoke", snr_db=20)
    assert list(tmp_path.iterdir()) == []  # nothing written
    assert (
        res.summary["truth"] is None
        and "rel_error_pct" not in res.summary["methods"]["modal_mcmc"]["EI"]
    )
    lo, hi = res.posteriors["modal_mcmc"].interval(0.9)
    assert lo < res.posteriors["modal_mcmc"].EI.mean() < hi
    again = bp.analyse(data, cfg, methods=("modal",), seed=0, profile="smoke", snr_db=20)
    assert (
        again.summary["methods"]["modal_mcmc"]["EI"] == res.summary["methods"]["modal_mcmc"]["EI"]
    )
    out = bp.write_run(res, tmp_path / "run", report=False)
    assert json.loads((out / "summary.json").read_text())["methods"] == json.loads(
        json.dumps(res.summary["methods"])
    )


@pytest.mark.parametrize(
    "kw, field",
    [
        ({"methods": ("modal", "mcmc")}, "--method"),
        ({"profile": "fastest"}, "profile"),
        ({"truth": {"EI": -1.0}}, "truth"),
        ({"methods": ("ensemble",), "opts": RunOptions(members=0)}, "members"),
        ({"opts": RunOptions(profile="smoke", noise_prior="flat")}, "noise_prior"),
        ({"methods": ("bpinn",), "opts": RunOptions(bpinn_variant="fulll")}, "bpinn_variant"),
        ({"methods": ("ensemble",), "opts": RunOptions(profile="quick")}, "profile"),
    ],
)
def test_analyse_names_the_bad_input(kw, field):
    cfg = bp.resolve("deflection")
    data = bp.simulate(cfg, snr_db=20, seed=3)
    args = {"methods": ("modal",), "profile": "smoke", **kw}
    with pytest.raises(InputError, match=re.escape(field)):
        bp.analyse(data, cfg, **args)


def test_example_script_runs_with_tiny_settings(tmp_path):
    r = subprocess.run(
        [
            sys.executable,
            str(ROOT / "examples" / "from_python.py"),
            "--profile",
            "smoke",
            "--methods",
            "modal",
            "--out",
            str(tmp_path / "ex"),
        ],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert "modal_mcmc: EI" in r.stdout and (tmp_path / "ex" / "summary.json").is_file()


@pytest.mark.parametrize(
    "kw, field",
    [({"level": 1.5}, "--level"), ({"level": 0.0}, "--level"), ({"replicates": 0}, "--replicates")],
)
def test_coverage_names_the_bad_input(kw, field):
    from bayespinn.uq.coverage import coverage_study

    with pytest.raises(InputError, match=re.escape(field)):
        coverage_study("modal", bp.resolve("deflection"), 20.0, **kw)


def test_a_bad_executor_names_the_field():
    from bayespinn.executor import Executor

    with pytest.raises(InputError, match="--executor"):
        Executor("cluster")


def test_a_failing_predictor_does_not_lose_the_posterior_file(tmp_path, caplog):
    """A degenerate posterior whose predictive draws fail (a Cholesky of a covariance that is not positive
    definite) still gets its posterior file, without the posterior_predictive group, and a warning."""
    import arviz as az
    import numpy as np

    cfg = bp.resolve("deflection")
    data = bp.simulate(cfg, snr_db=20, seed=3)
    res = bp.analyse(data, cfg, methods=("modal",), seed=0, profile="smoke", snr_db=20)

    def broken(*args, **kwargs):
        raise np.linalg.LinAlgError("not positive definite")

    res.posteriors["modal_mcmc"].predictor = broken
    out = bp.write_run(res, tmp_path / "run", report=False)
    idata = az.from_netcdf(out / "posterior_modal_mcmc.nc")
    assert "posterior_predictive" not in idata.groups() and "observed_data" in idata.groups()
    assert "posterior predictive at the data points failed" in caplog.text


def test_the_manifest_says_where_the_time_went():
    from bayespinn.pipeline import time_breakdown
    from bayespinn.uq.posterior import Posterior

    post = Posterior("bpinn", [[1.0, 2.0]], [[1.0, 1.0]], diagnostics={"fit_runtime_s": 3.0})
    post.runtime_s = 5.0
    ens = Posterior("ensemble", [[1.0, 2.0]], [[1.0, 1.0]], diagnostics={"fit_runtime_s": 8.0})
    ens.runtime_s = 5.0
    # members trained in parallel for less than the wall time: still a sum over workers, as it says
    par = Posterior(
        "ensemble", [[1.0]], [[1.0]], diagnostics={"fit_runtime_s": 3.0, "fit_runtime_summed": True}
    )
    par.runtime_s = 5.0
    out = time_breakdown({"bpinn": post, "ensemble": ens})
    assert out["bpinn"] == {"wall": 5.0, "training": 3.0, "rest": 2.0}
    assert out["ensemble"] == {"wall": 5.0, "training_summed_over_workers": 8.0}
    assert time_breakdown({"ensemble": par})["ensemble"] == {
        "wall": 5.0,
        "training_summed_over_workers": 3.0,
    }
