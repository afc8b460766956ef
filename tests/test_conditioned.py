"""The B-PINN's last-layer model in a well-conditioned basis (`uq.conditioned`) is the same model as
`LastLayer`'s, and it keeps the log marginal smooth where the plain one's Grams round it to noise."""

import math

import numpy as np
import pytest
import torch

from bayespinn.uq.conditioned import ConditionedLastLayer
from bayespinn.uq.lastlayer import LastLayer, feature_jet

#: log marginals of the two bases on the smoke fit: rounding of float64 Grams of ~100-row designs
SAME_NATS = 1e-6


def _both(smoke_fit, **kw):
    cfg, data, problem, res = smoke_fit
    a = dict(n_pde=40, n_bc=10, n_ic=10, **kw)
    model = res.model()
    return (
        LastLayer(model, 0, problem, data, np.random.default_rng(0), **a),
        ConditionedLastLayer(model, 0, problem, data, np.random.default_rng(0), **a),
    )


def _lm(ll, lt, ls):
    with torch.no_grad():
        return float(ll.log_marginal(torch.tensor(lt, dtype=torch.float64), torch.tensor(ls)))


@pytest.mark.parametrize("vary", [True, False])
def test_the_conditioned_basis_is_the_same_model(smoke_fit, vary):
    """Log marginal, the weights' posterior and the predictive agree with the plain basis'."""
    plain, cond = _both(smoke_fit, vary_first_mode=vary)
    assert cond.first_mode_varies == plain.first_mode_varies == vary
    lt0 = math.log(plain.theta_fit)
    ls0 = math.log(plain.noise_mode(lt0))
    for dlt in (-0.02, 0.0, 0.02):
        for dls in (-0.3, 0.0, 0.3):
            assert _lm(cond, lt0 + dlt, ls0 + dls) == pytest.approx(
                _lm(plain, lt0 + dlt, ls0 + dls), abs=SAME_NATS
            )
    m0, c0 = plain.weights_posterior(lt0, ls0)
    m1, c1 = cond.weights_posterior(lt0, ls0)
    np.testing.assert_allclose(m1, m0, rtol=0, atol=1e-7 * float(m0.abs().max()))
    np.testing.assert_allclose(c1, c0, rtol=0, atol=1e-7 * float(c0.abs().max()))
    x, t = np.full(5, 20.0), np.linspace(1.0, 5.0, 5)
    draws = [ll.predictive(x, t, 0, [lt0], [ls0], np.random.default_rng(3)) for ll in (plain, cond)]
    np.testing.assert_allclose(draws[1], draws[0], rtol=1e-4, atol=0)


def _jaggedness(ll, lt0, ls0) -> float:
    """Largest third difference of the log marginal over 40 steps of 1e-4 in log theta: a smooth function's
    is its third derivative times 1e-12, rounding noise's about the noise itself."""
    g = lt0 + 1e-4 * np.arange(40)
    f = np.array([_lm(ll, v, ls0) for v in g])
    return float(np.abs(np.diff(f, 3)).max())


def test_the_conditioned_basis_keeps_the_marginal_smooth(smoke_fit):
    """The smoke fit's features mixed by a matrix of condition number 1e8 (nearly collinear columns, as a
    trained fast-profile PINN's 69 are: the coverage study at 30 dB, replicate 99, had a precision of
    condition number 1e18) put the weights' prior 1e-16 below the Grams' largest entries: the plain
    basis' log marginal turns to rounding noise (the control), the conditioned one's stays smooth."""
    plain, cond = _both(smoke_fit, vary_first_mode=False)
    D, P4, P2, Bm, Cm = plain.rows(lambda *a: feature_jet(plain.model, 0, *a))
    P4, P2 = P4 * plain.pde_mask, P2 * plain.pde_mask
    k = D.shape[1]
    r = np.random.default_rng(7)
    Q1, _ = np.linalg.qr(r.standard_normal((k, k)))
    Q2, _ = np.linalg.qr(r.standard_normal((k, k)))
    M = torch.as_tensor(Q1 @ np.diag(np.logspace(0, 8, k)) @ Q2, dtype=torch.float64)
    mixed = [ll.with_rows(D @ M, P4 @ M, P2 @ M, Bm @ M, Cm @ M) for ll in (plain, cond)]
    lt0 = math.log(plain.theta_fit)
    ls0 = math.log(math.sqrt(plain.fit_rss / plain.n))
    assert _jaggedness(mixed[0], lt0, ls0) > 1e-3  # control: the plain basis is rounding noise here
    assert _jaggedness(mixed[1], lt0, ls0) < 1e-6
    # the unmixed rows through with_rows give back the model itself
    again = cond.with_rows(D, P4, P2, Bm, Cm)
    assert _lm(again, lt0, ls0) == pytest.approx(_lm(plain, lt0, ls0), abs=SAME_NATS)
