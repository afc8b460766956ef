"""The last-layer marginal on a grid as one batch equals the point-by-point one."""

import math

import numpy as np
import pytest
import torch

from bayespinn.uq.lastlayer import LastLayer
from bayespinn.uq.lastlayer_grid import BATCH, log_marginal_grid


@pytest.fixture(scope="module")
def ll(smoke_fit):
    cfg, data, problem, res = smoke_fit
    s = res.settings
    return LastLayer(
        res.model(),
        0,
        problem,
        data,
        np.random.default_rng(0),
        n_pde=300,
        n_bc=60,
        n_ic=60,
        beta_rel=s.beta_rel,
        images=s.images,
    )


def _pointwise(ll, lt, ls):
    T = lambda v: torch.tensor(float(v), dtype=torch.float64)  # noqa: E731
    with torch.no_grad():
        return np.array([float(ll.log_marginal(T(a), T(b))) for a, b in zip(lt, ls, strict=True)])


def test_grid_over_theta_and_sigma_equals_point_by_point(ll):
    """Over theta (the first mode's vibration re-evaluated at each) and over sigma, in more than one
    batch; a grid shifted by one step differs (the comparison can fail)."""
    assert ll.fv is not None  # the smoke profile's tied vibrations: the varying block is exercised
    lt0, ls0 = math.log(ll.theta_fit), 0.5 * math.log(ll.fit_rss / ll.n)
    lt = lt0 + np.linspace(-0.3, 0.3, BATCH + 7)
    ls = ls0 + np.linspace(-1.0, 1.0, BATCH + 7)
    for a, b in ((lt, np.full_like(lt, ls0)), (np.full_like(ls, lt0), ls), (lt, ls)):
        ref = _pointwise(ll, a, b)
        got = log_marginal_grid(ll, a, b)
        np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-8)
    shifted = log_marginal_grid(ll, lt + (lt[1] - lt[0]), ls0)
    assert np.abs(shifted - _pointwise(ll, lt, np.full_like(lt, ls0))).max() > 1e-6


def test_scalars_broadcast_against_a_grid(ll):
    lt0, ls0 = math.log(ll.theta_fit), 0.5 * math.log(ll.fit_rss / ll.n)
    g = ls0 + np.linspace(-0.5, 0.5, 5)
    np.testing.assert_allclose(
        log_marginal_grid(ll, lt0, g), _pointwise(ll, np.full(5, lt0), g), rtol=1e-10, atol=1e-8
    )
