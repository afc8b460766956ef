"""The axles' shared road in the fluctuating-force law (`bayespinn.crossings.likelihood`): a vehicle's axles
ride the same road, so their relative force fluctuations are alike at the same position on the span. The
common part's columns give exactly the prior covariance (1 - r) I + r 1 1' between the axles' weights, and
the correlation r is what the data say: near 1 when every axle's fluctuation is the same history, low when
each axle has its own (the negative control)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from gauges import three_gauges

from bayespinn.crossings.forward import CrossingModel
from bayespinn.crossings.likelihood import CrossingTerm, woodbury_loglik

L, MU, EI, V, T0 = 20.0, 4000.0, 5e9, 10.0, 0.5
LOADS, OFFSETS = np.array([60e3, 90e3]), np.array([0.0, 4.0])


def term(common: bool = True) -> CrossingTerm:
    """Two strain gauges and a deflection point at 100 Hz for 3.5 s, the lorry entering at 0.5 s."""
    x, t, a_u, a_xx = three_gauges(3.5, 100)
    model = CrossingModel(
        L, MU, LOADS, OFFSETS, x, t, a_u, a_xx, n_modes=8, n_basis=12, basis_modes=1
    )
    rows = np.arange(x.size)
    return CrossingTerm("c", rows, np.zeros(x.size), model, V, 0.0, T0, 0.0, common=common)


def params(r: float, s: float = 0.05, ell: float = 0.3) -> dict:
    one = np.ones(1)
    return {
        "EI": one * EI, "zeta": one * 0.01, "v": [one * V], "t0": [one * T0],
        "s": one * s, "l": one * ell, "r": one * r,
    }  # fmt: skip


@pytest.fixture(scope="module")
def shared():
    return term(True)


def test_the_common_columns_give_the_stated_covariance(shared):
    """B B' with the common part equals the axles' columns under the weights' covariance
    (1 - r) I + r 1 1' (per basis function), and differs from the independent axles' (r = 0)."""
    own = term(False)
    J, M = LOADS.size, shared.model.n_basis
    _, R = own.responses(params(0.0), 0)
    f = own.column_sds(params(0.0), 0)[0, :M]
    r = 0.7
    corr = (1 - r) * np.eye(J) + r * np.ones((J, J))
    cov = np.kron(corr, np.diag(f**2))  # column j M + m
    expect = R[0] @ cov @ R[0].T
    _, Rs = shared.responses(params(r), 0)
    B = Rs[0] * shared.column_sds(params(r), 0)[0]
    assert Rs.shape[2] == (J + 1) * M
    assert np.allclose(B @ B.T, expect, rtol=1e-10, atol=1e-12 * np.abs(expect).max())
    independent = R[0] @ np.kron(np.eye(J), np.diag(f**2)) @ R[0].T
    assert not np.allclose(independent, expect, rtol=0.05, atol=0.05 * np.abs(expect).max())


@pytest.mark.parametrize("same", [True, False])
def test_the_correlation_is_what_the_data_say(shared, same):
    """Fluctuations drawn from the force law itself, the same history for both axles or each its own:
    the likelihood over r peaks high (r >= 0.9) for the first and low (r <= 0.5) for the second."""
    J, M = LOADS.size, shared.model.n_basis
    rng = np.random.default_rng(11)
    _, R = shared.responses(params(0.0), 0)
    f = shared.column_sds(params(0.0), 0)[0, :M]
    w = rng.standard_normal(M) * f
    weights = np.tile(w, J) if same else rng.standard_normal(J * M) * np.tile(f, J)
    signal = R[0, :, : J * M] @ weights
    sig = 0.05 * float(np.std(signal))
    y = signal + sig * rng.standard_normal(signal.size)
    grid = np.linspace(0.01, 0.99, 50)
    ll = []
    _, Rs = shared.responses(params(0.0), 0)  # the columns do not depend on r, their sds do
    for r in grid:
        B = Rs * shared.column_sds(params(r), 0)[:, None, :]
        ll.append(woodbury_loglik(y[None], B, np.array([sig**2]))[0])
    best = grid[int(np.argmax(ll))]
    if same:
        assert best >= 0.9
    else:
        assert best <= 0.5
    assert math.isfinite(max(ll))
