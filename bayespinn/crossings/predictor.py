"""Posterior predictive of the crossing reference, and each crossing's fit check.

The predictor follows the `Posterior.predictor` contract (x, t, quantity, n_draws, rng) -> (n_draws, P): the
noise-free response for posterior draws of (EI, damping, speed, entry time), plus, with fluctuating axle
forces, the response to the force fluctuation's posterior mean (its conditional mean given the data at the
posterior mean of the other parameters): a fixed force history in time, so that a well-specified
fluctuating-force model leaves white residuals for the fit check. Times are on the data's clock.

With several crossings, points are matched to crossings by being the data's own rows of that quantity (what
the fit check and the report's predictive draws ask for); other points are predicted for the first crossing.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..config import Config
from ..data.measurements import Measurements
from ..physics.loads import quantity_weights
from ..uq import fitcheck
from ..uq.posterior import Posterior
from .forward import CrossingModel
from .likelihood import CrossingsLogPosterior, rows_of

#: walkers per vectorised call of the forward model
CHUNK = 16
#: modes carried by the predictions (reports, fit check), at least
PREDICT_MODES = 24


class CrossingRows:
    """Which crossing each point of a prediction belongs to: the data's own rows of a quantity are matched
    to their crossings (what the fit check and the report's predictive draws ask for); other points go
    to the first crossing."""

    def __init__(self, data: Measurements, rows: list):
        strain = np.asarray(data.kind) == "strain"
        which = np.empty(len(data), int)
        for i, r in enumerate(rows):
            which[r] = i
        self.rows = {
            "deflection": (data.x[~strain], data.t[~strain], which[~strain]),
            "curvature": (data.x[strain], data.t[strain], which[strain]),
        }

    def of(self, x: np.ndarray, t: np.ndarray, quantity: str) -> np.ndarray:
        rx, rt, which = self.rows.get(quantity, (None, None, None))
        if (
            rx is not None
            and rx.shape == x.shape
            and np.array_equal(rx, x)
            and np.array_equal(rt, t)
        ):
            return which
        return np.zeros(x.size, int)


class CrossingsPredictor:
    """Noise-free predictions of the crossing reference (module docstring)."""

    def __init__(
        self, cfg: Config, data: Measurements, post: CrossingsLogPosterior, flat, mean_theta
    ):
        self.cfg, self.post = cfg, post
        self.params = post.unpack(flat)
        self.n = flat.shape[0]
        self.weights = None
        self.mean = post.unpack(mean_theta[None])
        if (
            post.forces
        ):  # the force fluctuation's conditional mean at the posterior mean of the rest
            self.weights = post.force_weights(mean_theta[None])
        self.rows = CrossingRows(data, [c.rows for c in post.terms])

    def response(self, i: int, idx, x, t, a_u, a_xx) -> np.ndarray:
        """Crossing i's response at (x, t) for the draws idx, (len(idx), P)."""
        c = self.post.terms[i]
        p = self.params
        nb = c.model.n_basis if self.weights is not None else 0
        model = CrossingModel(
            c.model.L, c.model.mu, c.model.loads, c.model.offsets, x, t, a_u, a_xx,
            n_modes=max(c.model.n_modes, PREDICT_MODES), n_basis=nb, basis_modes=c.model.basis_modes,
            band=c.model.band if nb else None,
        )  # fmt: skip
        view = dataclasses.replace(c, model=model)
        out = []
        for ch in np.array_split(idx, max(1, len(idx) // CHUNK)):
            sub = rows_of(p, ch)
            if not nb:
                out.append(view.predict(sub, i))
                continue
            mu, R = view.responses(sub, i)
            d = view.column_sds(self.mean, i)
            out.append(mu + R @ (d[0] * self.weights[i]))
        return np.concatenate(out, axis=0)

    def __call__(self, x, t, quantity: str = "deflection", n_draws: int = 200, rng=None):
        rng = rng or np.random.default_rng(0)
        x, t = np.broadcast_arrays(np.asarray(x, float).ravel(), np.asarray(t, float).ravel())
        w = quantity_weights(quantity)
        idx = rng.choice(self.n, size=min(n_draws, self.n), replace=False)
        which = self.rows.of(x, t, "curvature" if w[1] else "deflection")
        out = np.empty((idx.size, x.size))
        for i in np.unique(which):
            sel = which == i
            out[:, sel] = self.response(int(i), idx, x[sel], t[sel], *w)
        if quantity == "moment":
            out = -self.params["EI"][idx][:, None] * out
        return out


class _OneCrossing:
    """A view of the reference's posterior for one crossing's rows (its fit check)."""

    def __init__(self, ref: Posterior, i: int):
        self.sigma = ref.sigma
        self.noise_ar1 = None
        pred = ref.predictor

        def predictor(x, t, quantity="deflection", n_draws=200, rng=None):
            rng = rng or np.random.default_rng(0)
            x, t = np.broadcast_arrays(np.asarray(x, float).ravel(), np.asarray(t, float).ravel())
            w = (1.0, 0.0) if quantity == "deflection" else (0.0, 1.0)
            idx = rng.choice(pred.n, size=min(n_draws, pred.n), replace=False)
            return pred.response(i, idx, x, t, *w)

        self.predictor = predictor


def crossing_fit_checks(ref: Posterior, data: Measurements, cfg: Config, post) -> dict:
    """Each crossing's fit check on its own rows (`uq.fitcheck.check`), by crossing name."""
    out = {}
    for i, c in enumerate(post.terms):
        fc = fit_check_on_rows(_OneCrossing(ref, i), data, c.rows, cfg)
        if fc is not None:
            out[c.name] = fc
    return out


def fit_check_on_rows(post, data: Measurements, rows, cfg: Config) -> dict | None:
    """`uq.fitcheck.check` of a posterior (or a view of one crossing of it) on the data's given rows."""
    sub = data.select(np.isin(np.arange(len(data)), rows))
    duration = max(float(np.max(sub.t)), 1e-9) if len(sub) else 1.0
    return fitcheck.check(post, sub, cfg.beam.length, duration, seed=0)
