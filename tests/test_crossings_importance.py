"""The crossing reference's importance sampler (`crossings.importance`) on targets whose answer is known:
the Pareto tail index against ArviZ's PSIS on draws of known tail, AMIS against a Gaussian it was not
started on, and a negative control (the guide alone, one round) that its own convergence check must reject.
Fixed seeds; the bands are many Monte Carlo sds wide (about 1e-4 false failures each)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bayespinn.crossings import importance
from bayespinn.crossings.importance import amis, pareto_khat

# a correlated 4-d Gaussian target, with a hard lower bound on its last coordinate (like the force time
# scale's truncated prior), and a guide cloud that is too narrow and shifted by 3 target sds
MEAN = np.array([1.0, -2.0, 0.5, 0.0])
SD = np.array([0.01, 0.3, 0.002, 1.0])
CORR = np.array(
    [[1.0, 0.6, -0.3, 0.0], [0.6, 1.0, 0.2, 0.1], [-0.3, 0.2, 1.0, 0.0], [0.0, 0.1, 0.0, 1.0]]
)
COV = CORR * SD[:, None] * SD[None, :]
BOUND = -1.5  # last coordinate >= BOUND: 6.7 % of the Gaussian's mass is cut


def _log_target(z: np.ndarray) -> np.ndarray:
    d = z - MEAN
    q = np.einsum("wi,ij,wj->w", d, np.linalg.inv(COV), d)
    return np.where(z[:, 3] >= BOUND, -0.5 * q, -np.inf)


def _guide(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return MEAN + 3.0 * SD + rng.standard_normal((2000, 4)) * (0.3 * SD)


def _truncated_moments() -> tuple[np.ndarray, np.ndarray]:
    """Mean and sd of the truncated target, by a million exact rejection draws (MC error < 1e-3 sd)."""
    rng = np.random.default_rng(99)
    z = rng.multivariate_normal(MEAN, COV, size=1_000_000)
    z = z[z[:, 3] >= BOUND]
    return z.mean(0), z.std(0)


@pytest.mark.parametrize("k", [0.2, 0.5, 0.8, 1.2])
def test_pareto_khat_agrees_with_psis_on_known_tails(k):
    """Weights with a Pareto tail of shape k: the estimate within 0.05 of ArviZ's PSIS k-hat on the same
    draws and within 0.2 of k (its sampling sd at 4000 draws is about 0.07)."""
    az = pytest.importorskip("arviz")
    rng = np.random.default_rng(int(100 * k))
    lw = np.log(rng.pareto(1.0 / k, 4000) + 1.0)
    ours = pareto_khat(lw)
    assert abs(ours - float(az.psislw(lw.copy())[1])) < 0.05
    assert abs(ours - k) < 0.2


def test_pareto_khat_of_light_or_too_few_weights():
    rng = np.random.default_rng(1)
    assert pareto_khat(rng.normal(0.0, 0.3, 4000)) < 0.3
    assert pareto_khat(np.array([0.0, 1.0, -np.inf])) == math.inf


def test_amis_recovers_a_target_it_was_not_started_on():
    """From a guide 3 sds off and 3x too narrow, AMIS converges (its own check), and its resampled
    draws give the truncated target's mean within 0.15 sd and its sd within 10 % in every coordinate,
    with no draw outside the support."""
    draws, lt, info = amis(_log_target, _guide(0), np.random.default_rng(0))
    assert info["passed"] and info["ess"] >= importance.ESS_TARGET
    assert info["khat"] <= importance.KHAT_MAX
    assert draws.shape == (importance.N_OUT, 4) and np.all(np.isfinite(lt))
    assert np.all(draws[:, 3] >= BOUND)
    m, s = _truncated_moments()
    assert np.all(np.abs(draws.mean(0) - m) / s < 0.15)
    assert np.all(np.abs(draws.std(0) / s - 1.0) < 0.1)


def test_the_guide_alone_fails_the_check(monkeypatch):
    """Negative control: one round (importance sampling from the guide's inflated Gaussian, no adaptation)
    on the same target: the check must say it has not converged."""
    monkeypatch.setattr(importance, "MAX_ROUNDS", 1)
    _, _, info = amis(_log_target, _guide(0), np.random.default_rng(0))
    assert not info["passed"]
    assert info["ess"] < importance.ESS_TARGET or info["khat"] > importance.KHAT_MAX


def test_amis_is_a_function_of_its_seed():
    a = amis(_log_target, _guide(3), np.random.default_rng(5))[0]
    b = amis(_log_target, _guide(3), np.random.default_rng(5))[0]
    np.testing.assert_array_equal(a, b)


def test_a_target_with_no_support_near_the_guide_is_an_error():
    with pytest.raises(RuntimeError, match="no draw inside"):
        amis(lambda z: np.full(z.shape[0], -np.inf), _guide(0), np.random.default_rng(0))


def test_curvature_sds_of_a_gaussian_and_none_where_there_is_no_curvature():
    """The Laplace sds that start the hyperparameters' importance sampler: exact on a Gaussian (central
    differences are exact on a quadratic), and None, silently, where the Hessian is not positive definite
    or a difference point lies outside the support (the caller then uses fixed scales)."""
    import warnings

    from bayespinn.crossings.curvature import curvature_sds

    sd = np.array([1.0, 2.0, 0.1])
    step = np.full(3, 1e-2)
    got = curvature_sds(lambda p: 0.5 * np.sum((p / sd) ** 2, axis=1), np.zeros(3), step)
    np.testing.assert_allclose(got, sd, rtol=1e-6)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        edge = curvature_sds(
            lambda p: np.where(p[:, 0] > 0, np.inf, 0.5 * np.sum(p**2, axis=1)), np.zeros(3), step
        )
        assert edge is None
        assert curvature_sds(lambda p: -0.5 * np.sum(p**2, axis=1), np.zeros(3), step) is None
