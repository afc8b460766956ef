"""The NUTS driver says what went wrong: divergences, trajectories cut at the maximum tree depth, warnings."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from bayespinn.uq.nuts import _Counted, nuts_health, problems, run_nuts
from bayespinn.uq.sampler import ESS_MIN, RHAT_MAX


def _seed(i: int) -> np.random.SeedSequence:
    return np.random.SeedSequence(1234, spawn_key=(i,))


def _gauss(params):
    u = params["u"]
    return 0.5 * (u * u).sum()


def _flat_direction(params):
    """An improper density: a unit Gaussian in u[0], flat in u[1] (no U-turn ever ends a trajectory)."""
    u = params["u"]
    return 0.5 * u[0] ** 2 + 0.0 * u[1]


def _funnel(params):
    """Neal's funnel: log-scale v ~ N(0, 3), x | v ~ N(0, exp(v / 2)); its neck makes NUTS diverge."""
    v, x = params["u"][0], params["u"][1:]
    return v**2 / 18.0 + 0.5 * (x * x).sum() * torch.exp(-v) + 0.5 * x.numel() * v


def test_well_posed_target_has_no_problems():
    runs = [
        run_nuts(
            _gauss,
            {"u": torch.zeros(2, dtype=torch.float64)},
            warmup=150,
            samples=300,
            seed=_seed(c),
            max_tree_depth=6,
        )
        for c in range(2)
    ]
    h = nuts_health(runs)
    assert (
        h["divergences"] == 0 and h["tree_depth_saturated"] == 0 and h["nonfinite_potential"] == 0
    )
    assert (
        1 <= h["mean_tree_depth"] <= 4
    )  # a unit Gaussian needs a few leapfrog steps, not hundreds
    assert all(
        r.lp.shape == (300,) and np.all(r.lp <= 0) for r in runs
    )  # lp = -potential, potential >= 0
    diag = {"rhat": 1.0, "ess_bulk": 800.0, "ess_tail": 700.0, **h}
    assert problems(diag) == []


def test_a_flat_direction_saturates_the_tree_depth_and_is_not_converged():
    runs = [
        run_nuts(
            _flat_direction,
            {"u": torch.zeros(2, dtype=torch.float64)},
            warmup=40,
            samples=40,
            seed=_seed(c),
            max_tree_depth=5,
        )
        for c in range(2)
    ]
    h = nuts_health(runs)
    assert h["tree_depth_saturated_fraction"] > 0.5
    trouble = problems({"rhat": 1.0, "ess_bulk": 1e4, "ess_tail": 1e4, **h})
    assert any("maximum tree depth" in t for t in trouble)


def test_the_funnel_diverges_and_is_not_converged():
    runs = [
        run_nuts(
            _funnel,
            {"u": torch.zeros(4, dtype=torch.float64)},
            warmup=100,
            samples=200,
            seed=_seed(c),
            max_tree_depth=6,
            full_mass=False,
        )
        for c in range(2)
    ]
    h = nuts_health(runs)
    assert h["divergences"] > 0
    assert any(
        "divergent" in t for t in problems({"rhat": 1.0, "ess_bulk": 1e4, "ess_tail": 1e4, **h})
    )


def test_problems_name_every_threshold():
    t = problems(
        {
            "rhat": RHAT_MAX + 0.05,
            "ess_bulk": ESS_MIN - 1,
            "ess_tail": ESS_MIN - 1,
            "divergences": 3,
            "tree_depth_saturated": 2,
            "max_tree_depth": 10,
        }
    )
    assert len(t) == 5 and "R-hat" in t[0] and "bulk ESS" in t[1] and "tail ESS" in t[2]
    assert problems({"rhat": float("nan"), "ess_bulk": 500.0, "ess_tail": 500.0}) == ["R-hat n/a"]


def test_a_potential_that_cannot_be_evaluated_is_outside_the_support():
    def broken(params):
        u = params["u"]
        if float(u[0]) > 1.0:
            torch.linalg.cholesky(-torch.eye(2, dtype=torch.float64))  # raises LinAlgError
        if float(u[0]) < -1.0:
            return u.sum() * float("nan")
        return 0.5 * (u * u).sum()

    pot = _Counted(broken)
    for x, finite in ((0.0, True), (2.0, False), (-2.0, False)):
        u = torch.tensor([x, 0.0], dtype=torch.float64, requires_grad=True)
        pe = pot({"u": u})
        assert bool(torch.isfinite(pe)) == finite
        if not finite:
            assert float(pe) == float("inf")
            (g,) = torch.autograd.grad(pe, u)
            assert torch.all(g == 0)
    assert pot.calls == 3 and pot.nonfinite == 2


@pytest.fixture(scope="module")
def struggling_run(tmp_path_factory):
    """The B-PINN on two deflection points: with the vague noise prior its posterior has no floor in sigma
    (two points, dozens of output weights: the marginal likelihood grows without bound as sigma -> 0).
    Slow (about 5 minutes): the trajectories that run to the maximum depth cost 1023 gradients each."""
    from bayespinn.cli import main

    tmp = tmp_path_factory.mktemp("struggle")
    (tmp / "two.toml").write_text("[data]\nn_points = 2\n", encoding="utf-8")
    out = tmp / "run"
    code = main(
        [
            "run",
            "--snr",
            "30",
            "--method",
            "bpinn",
            "--profile",
            "smoke",
            "--seed",
            "1",
            "--quiet",
            "--config",
            str(tmp / "two.toml"),
            "--out",
            str(out),
        ]
    )
    assert code == 0
    return out


@pytest.mark.slow
def test_a_struggling_bpinn_says_so_in_summary_and_report(struggling_run):
    d = json.loads((struggling_run / "summary.json").read_text())["methods"]["bpinn"]["diagnostics"]
    assert d["converged"] is False
    assert d["divergences"] > 0 or d["tree_depth_saturated"] > 0
    assert any("divergent" in p or "tree depth" in p for p in d["problems"])
    report = (struggling_run / "report.md").read_text()
    assert "did not meet its convergence criteria" in report
    assert "divergent transitions" in report or "maximum tree depth" in report


class _CorrelatedGauss:
    """A picklable potential of z (the last-layer B-PINN's interface): a correlated 2-D Gaussian."""

    def __call__(self, params):
        z = params["z"]
        return 0.5 * (z[0] ** 2 + (z[1] - 0.8 * z[0]) ** 2 / 0.36)


def test_bpinn_chains_are_the_same_wherever_they_run():
    """The B-PINN's chains run as executor tasks: one worker or two, the draws are identical bit for bit
    (each chain is a function of its own seed); another seed gives other draws (negative control)."""
    from bayespinn.executor import Executor
    from bayespinn.uq.bpinn import nuts
    from bayespinn.uq.nuts import NUTSSettings

    s = NUTSSettings(chains=3, warmup=40, samples=40)
    z_map, L = np.zeros(2), np.array([[1.0, 0.0], [0.8, 0.6]])

    def draws(seed, workers):
        d, runs = nuts(
            _CorrelatedGauss(), z_map, L, s, _seed(seed), False, Executor(workers=workers)
        )
        assert len(runs) == s.chains and d.shape == (s.chains, s.samples, 2)
        return d

    one, two = draws(0, 1), draws(0, 2)
    np.testing.assert_array_equal(one, two)
    assert not np.array_equal(one, draws(1, 1))
