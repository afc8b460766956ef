"""The modal reference for a smooth EI field (`[model] EI_field = "smooth"`), as the pipeline's `Posterior`:
`girder_field.field_posterior` run from a configuration, its summary in the contract's keys (`EI` the
span-averaged flexibility's equivalent, `EI_x` the field along the span with its 90 % band, `local_loss`
the loss's depth, position and width), and a predictor for the fit check and the report."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..config import Config
from ..data.measurements import Measurements
from ..physics.fe_modal import GirderModalModel
from ..physics.girder import Girder
from ..physics.hermite import element_of
from ..physics.loads import quantity_weights
from .girder_field import PIECES, FieldPosterior, field_posterior
from .posterior import Posterior, summarise

#: modes of the predictor (predictions away from the data are cheap)
PREDICT_MODES = 16


@dataclass
class FieldReference(Posterior):
    """A `Posterior` of the span-equivalent EI and sigma that carries the field posterior (`field`) for the
    summary's `EI_x` and `local_loss`."""

    field: FieldPosterior | None = field(default=None, repr=False, compare=False)

    def summary(self, truth: dict | None = None) -> dict:
        out = super().summary(truth)
        if self.field is None:
            return out
        # the truth's EI(x) where it is given on the same points
        t = (truth or {}).get("EI_x")
        x = np.linspace(0.0, self.field.length, len(t["x"])) if isinstance(t, dict) else None
        same = x is not None and np.allclose(x, t["x"]) and len(t.get("EI", ())) == len(x)
        ex = self.field.EI_x(t["EI"] if same else None)
        out["EI_x"] = ex
        p = self.field.params()
        out["local_loss"] = {k: summarise(p[k]) for k in ("depth", "position", "width")}
        return out


class FieldPredictor:
    """Posterior predictive of the field's surrogate: noise-free responses for posterior draws of the
    field; the `Posterior.predictor` contract."""

    def __init__(self, cfg: Config, post: FieldPosterior):
        self.cfg, self.post = cfg, post
        mean_ei = post.loss.EI_pieces(post.theta).mean(0)
        self.template = Girder.from_beam(cfg.beam, tuple(float(e) for e in mean_ei))

    def __call__(
        self, x, t, quantity: str = "deflection", n_draws: int = 200, rng=None
    ) -> np.ndarray:
        rng = rng or np.random.default_rng(0)
        p = self.post
        pick = rng.choice(p.theta.shape[0], size=min(n_draws, p.theta.shape[0]), replace=False)
        x, t = np.broadcast_arrays(np.asarray(x, float).ravel(), np.asarray(t, float).ravel())
        m = GirderModalModel(
            self.template,
            self.cfg.vehicle,
            x,
            t,
            *quantity_weights(quantity),
            n_modes=PREDICT_MODES,
        )
        th = p.theta[pick]
        ei = p.loss.EI_pieces(th)
        out = m.predict(ei)
        if quantity in ("moment", "curvature"):
            # the surrogate's moment is its curvature times its piece's EI; the field's curvature is
            # that moment over the field's own EI at x (as the posterior's likelihood reads a gauge)
            piece = element_of(x, m.h, m.n_elements)[0] // (m.n_elements // PIECES)
            out = -ei[:, piece] * out
            if quantity == "curvature":
                out = -out / p.loss.EI_at(th, x)
        return out


def field_reference(
    data: Measurements, cfg: Config, *, seed, progress: bool = False, method: str
) -> FieldReference:
    """The reference posterior of a smooth EI field for `cfg` given the data, labelled `method` (the
    reference's summary key)."""
    return field_result(method, cfg, field_posterior(data, cfg, seed=seed, progress=progress))


def field_result(
    key: str, cfg: Config, fp: FieldPosterior, info: dict | None = None
) -> FieldReference:
    """The pipeline's Posterior of method `key` carrying the field posterior `fp` (the reference's, or a
    PINN method's, `uq.girder_pinn`), its predictor the field's surrogate."""
    return FieldReference(
        key,
        fp.EI,
        fp.sigma,
        diagnostics=fp.diagnostics,
        info={"EI_nominal": fp.EI_nominal, **(info or {})},
        runtime_s=fp.runtime_s,
        predictor=FieldPredictor(cfg, fp),
        field=fp,
    )
