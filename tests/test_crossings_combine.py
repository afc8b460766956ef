"""Several crossings analysed one at a time and combined (`crossings.combine`): the grid's numbers against
closed forms, the crossing-level error against data made by its own generative model, and the whole path
against the one-model analysis of the same crossings.

- Without the crossing-level error the combination is the product of the crossings' likelihoods: with
  Gaussian posteriors under an informative prior (so that dividing each by the prior matters) it equals the
  closed-form product; a combination that forgot the division (the prior counted once per crossing) is
  the negative control.
- With it: crossings that agree leave EI near the product; crossings that disagree widen it.
- Calibration (slow): crossings drawn from the hierarchical model itself (tau from its half-Cauchy prior,
  each crossing's EI_i = EI + delta_i, a Gaussian posterior about a noisy EI_i); the 90 % intervals hold EI
  inside the binomial 99 % region over 100 replicates; the plain product (tau = 0) is the negative control
  and misses far more often.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from bayespinn.crossings.combine import combine
from bayespinn.methods import REFERENCE_KEY
from bayespinn.uq.coverage import binomial_acceptance
from bayespinn.uq.priors import EIPrior

MEANS = np.array([20.7510, 20.7525, 20.7490])
SDS = np.array([0.0020, 0.0030, 0.0025])


def _draws(means, sds, seed: int, n: int = 4000) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [m + s * rng.standard_normal(n) for m, s in zip(means, sds, strict=True)]


def _product(means, sds, prior: EIPrior) -> tuple[float, float]:
    """The closed-form posterior of log EI: the prior times each crossing's posterior over the prior."""
    p0 = 1.0 / prior.log_sd**2
    prec = p0 + np.sum(1.0 / sds**2 - p0)
    num = prior.loc * p0 + np.sum(means / sds**2 - prior.loc * p0)
    return num / prec, prec**-0.5


def test_plain_combination_is_the_closed_form_product():
    prior = EIPrior(math.exp(20.75), 0.004)  # informative: the division by the prior matters
    mean, sd = _product(MEANS, SDS, prior)
    comb = combine(_draws(MEANS, SDS, 1), prior, crossing_error=False)
    x, tau = comb.draws(np.random.default_rng(2))
    assert np.all(tau == 0)
    assert abs(x.mean() - mean) < 0.1 * sd
    assert 0.97 < x.std() / sd < 1.07  # the kernel density's bandwidth adds about 2 %
    # negative control: the answer of a combination that counted the prior once per crossing (no
    # division) fails the same check
    p0 = 1.0 / prior.log_sd**2
    wrong_prec = p0 + np.sum(1.0 / SDS**2)
    assert not 0.97 < x.std() / wrong_prec**-0.5 < 1.07
    # each crossing's draws, resampled within the combination, follow the combined EI when tau = 0
    w = comb.predictive_weights(0, _draws(MEANS, SDS, 1)[0])
    u = _draws(MEANS, SDS, 1)[0]
    m0 = float(np.sum(w * u) / np.sum(w))
    s0 = float(np.sqrt(np.sum(w * (u - m0) ** 2) / np.sum(w)))
    assert abs(m0 - mean) < 0.15 * sd
    assert 0.85 < s0 / sd < 1.15


def test_crossing_error_keeps_agreement_and_widens_disagreement():
    prior = EIPrior(math.exp(20.75), 0.5)
    s = np.full(10, 0.002)
    same = np.full(10, 20.75) + s * np.linspace(-1, 1, 10)  # scatter within their sds
    apart = np.full(10, 20.75) + 4 * s * np.linspace(-1, 1, 10)  # scatter of 2.4 sds rms
    product_sd = 0.002 / math.sqrt(10)
    x_same, t_same = combine(_draws(same, s, 3), prior).draws(np.random.default_rng(4))
    x_apart, t_apart = combine(_draws(apart, s, 3), prior).draws(np.random.default_rng(4))
    assert x_same.std() < 1.25 * product_sd
    assert x_apart.std() > 2.0 * product_sd
    assert t_apart.mean() > 0.002 > t_same.mean()


@pytest.mark.slow
def test_combined_intervals_are_calibrated_on_the_hierarchical_model():
    """100 replicates of 10 crossings (module docstring): 90 % interval hits inside the binomial 99 %
    region; the plain product's hits below it (negative control)."""
    prior = EIPrior(math.exp(20.75), 0.5)
    rng = np.random.default_rng(20261206)
    R, J = 100, 10
    lo, hi = binomial_acceptance(R, 0.90, 0.01)
    hits = {True: 0, False: 0}
    for _ in range(R):
        s = 0.002 * np.exp(0.3 * rng.standard_normal(J))
        c = float(np.median(s))
        tau = abs(c * math.tan(math.pi * (rng.random() - 0.5)))  # half-Cauchy, scale c
        ei = prior.loc + 0.01 * rng.standard_normal()
        centres = ei + tau * rng.standard_normal(J) + s * rng.standard_normal(J)
        draws = [m + si * rng.standard_normal(2000) for m, si in zip(centres, s, strict=True)]
        for with_error in (True, False):
            x, _ = combine(draws, prior, crossing_error=with_error).draws(rng, 2000)
            q = np.quantile(x, [0.05, 0.95])
            hits[with_error] += int(q[0] <= ei <= q[1])
    assert lo <= hits[True] <= hi, (hits, lo, hi)
    assert hits[False] < lo, (hits, lo, hi)


@pytest.mark.slow
def test_combined_crossings_agree_with_one_model_of_them():
    """Three well-specified crossings (constant forces, each speed and entry time inferred): combined one
    at a time, EI's mean within 0.5 of the one-model analysis' sd and its sd no narrower (the crossing
    error's own uncertainty widens it: three crossings cannot rule out an error of their own size;
    measured 1.73x, mean -0.14 sd); each crossing's speed within 0.3 of its sd (measured 0.02-0.05)."""
    import bayespinn as bp
    from bayespinn.crossings import crossings_reference
    from bayespinn.data.measurements import Measurements
    from bayespinn.uq.sampler import MCMCSettings

    settings = MCMCSettings(n_walkers=16, n_groups=2, tau_factor=30.0, min_steps=500)
    base = bp.resolve("deflection")
    speeds = (6.8, 7.115, 7.5)
    parts = []
    for i, sp in enumerate(speeds):
        c = dataclasses.replace(base, vehicle=dataclasses.replace(base.vehicle, speed=sp))
        d = bp.simulate(c, 20, seed=20 + i)
        parts.append(dataclasses.replace(d, crossing=np.full(len(d), f"c{i}")))
    fields = ("x", "t", "value", "kind", "y", "sensor", "value_true", "crossing")
    data = Measurements(*(np.concatenate([getattr(p, f) for p in parts]) for f in fields))
    toml = {
        "vehicle": {"speed_sd": 0.02, "entry_time_sd": 0.02},
        "crossing": [{"name": f"c{i}", "speed": 1.005 * sp} for i, sp in enumerate(speeds)],
    }
    cfg = bp.resolve("deflection", toml)
    one = crossings_reference(
        data, cfg, seed=0, settings=settings, fit_checks=False, method=REFERENCE_KEY
    ).summary()
    comb = crossings_reference(
        data, cfg, seed=0, settings=settings, combine=True, method=REFERENCE_KEY
    )
    two = comb.summary()
    assert "crossing_error" in two
    assert abs(two["EI"]["mean"] - one["EI"]["mean"]) < 0.5 * one["EI"]["sd"]
    assert 0.95 < two["EI"]["sd"] / one["EI"]["sd"] < 2.0
    for name in ("c0", "c1", "c2"):
        a, b = two["crossings"][name], one["crossings"][name]
        assert abs(a["speed"]["mean"] - b["speed"]["mean"]) < 0.3 * b["speed"]["sd"]
        assert a["fit_check"]["verdict"] in ("fits", "misfit")
    # the combined posterior predicts each crossing's own rows (the report's and the fit check's draws)
    pred = comb.predictor(data.x, data.t, "deflection", 20)
    assert pred.shape == (20, len(data)) and np.all(np.isfinite(pred))
