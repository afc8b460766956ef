"""A last-layer posterior predictive (`uq.lastlayer_posterior.LastLayerPredictor`) builds each posterior draw's
output-weight posterior once, however many times a report asks it for responses, and its draws are those
of the uncached predictive."""

import math

import numpy as np
import pytest
import torch

from bayespinn.uq.conditioned import ConditionedLastLayer
from bayespinn.uq.lastlayer_algebra import feature_jet
from bayespinn.uq.lastlayer_posterior import LastLayerPredictor


@pytest.fixture(scope="module")
def last_layer(smoke_fit):
    cfg, data, problem, res = smoke_fit
    ll = ConditionedLastLayer(
        res.model(), 0, problem, data, np.random.default_rng(0), n_pde=40, n_bc=10, n_ic=10
    )
    lt0 = math.log(ll.theta_fit)
    return cfg, ll, lt0, math.log(ll.noise_mode(lt0))


def _counting(ll, monkeypatch) -> list:
    built = []
    inner = type(ll).weights_factor

    def counted(self, *key):
        built.append(key)
        return inner(self, *key)

    monkeypatch.setattr(type(ll), "weights_factor", counted)
    return built


def _one_by_one(ll, x, t, kx, lt, ls, rng) -> np.ndarray:
    """The predictive draw by draw: each draw's weights posterior and its first-mode columns at its own
    theta (`_fv_jet`), as the predictive computed them before it batched and kept them."""
    sc = ll.sc
    xi = torch.as_tensor(x, dtype=torch.float64) / sc.L
    tau = torch.as_tensor(t, dtype=torch.float64) / sc.T
    Phi_f = feature_jet(ll.model, ll.member, xi, tau, kx, 0).dx(kx)[:, : ll.kf]
    out = []
    for a, b in zip(lt, ls, strict=True):
        mean, cov = ll.weights_posterior(float(a), float(b))
        with torch.no_grad():
            jv = ll._fv_jet(xi, tau, kx, 0, torch.tensor(float(a), dtype=torch.float64))
        Phi = torch.cat([Phi_f, jv.dx(kx)], dim=1)
        Lc = torch.linalg.cholesky(cov + 1e-30 * torch.eye(ll.k, dtype=torch.float64))
        z = torch.as_tensor(rng.standard_normal(ll.k), dtype=torch.float64)
        out.append((Phi @ (mean + Lc @ z)).numpy() * sc.U / sc.L**kx)
    return np.array(out)


def test_the_cache_changes_no_draw(last_layer):
    """Same draws, same rng: the batched, cached predictive returns the draw-by-draw one's numbers (to
    rounding), also on the call that reads every factor from the cache."""
    cfg, ll, lt0, ls0 = last_layer
    assert ll.fv is not None  # the first mode's columns follow theta: the batched path is exercised
    lt = lt0 + np.array([-0.01, 0.0, 0.015])
    ls = np.full(3, ls0)
    x, t = np.linspace(1.0, cfg.beam.length - 1.0, 7), np.full(7, 1.2)
    ref = _one_by_one(ll, x, t, 2, lt, ls, np.random.default_rng(5))
    plain = ll.predictive(x, t, 2, lt, ls, np.random.default_rng(5))
    np.testing.assert_allclose(plain, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())
    factors: dict = {}
    first = ll.predictive(x, t, 2, lt, ls, np.random.default_rng(5), factors=factors)
    again = ll.predictive(x, t, 2, lt, ls, np.random.default_rng(5), factors=factors)
    assert len(factors) == 3
    np.testing.assert_array_equal(first, plain)
    np.testing.assert_array_equal(again, plain)


def test_a_report_builds_each_draws_weights_posterior_once(last_layer, monkeypatch):
    """Three calls (deflection, moment, curvature at other points) with 12 of 40 draws: 12 weight
    posteriors built in all. The negative control, a predictor that picks a fresh subset at every call
    (as before the cache), builds more than 12."""
    cfg, ll, lt0, ls0 = last_layer
    rng = np.random.default_rng(1)
    lt = lt0 + 0.01 * rng.standard_normal(40)
    ls = ls0 + 0.05 * rng.standard_normal(40)
    x = np.linspace(0.5, cfg.beam.length - 0.5, 9)
    built = _counting(ll, monkeypatch)
    pred = LastLayerPredictor(ll, lt, ls, shift=0.0)
    draws = [
        pred(x, np.full(9, 0.8), "deflection", 12, rng),
        pred(x[::-1], np.full(9, 1.6), "moment", 12, rng),
        pred(x, np.full(9, 2.0), "curvature", 12, rng),
    ]
    assert [d.shape for d in draws] == [(12, 9)] * 3
    assert len(built) == 12
    assert len(set(built)) == 12

    built.clear()
    for _ in range(3):  # the old behaviour: a fresh random subset each call, nothing kept
        idx = rng.choice(lt.size, size=12, replace=False)
        ll.predictive(x, np.full(9, 0.8), 0, lt[idx], ls[idx], rng)
    assert len(built) > 12
