"""The modal reference for real girders, as the pipeline's `Posterior`: `girder_posterior` run from a
configuration, its summary in the contract's keys, and a predictor for the fit check and the report.

`ModalMCMC` uses it whenever the analysis model is not the uniform, pinned, known-load girder with white
noise (`Config.ideal`): EI per segment (`[model] EI_segments`), springs at the supports (`supports =
"springs"`), an uncertain axle-load factor (`vehicle.load_rel_sd` > 0 with `load_factor = "auto"`) or AR(1)
noise (`[model] noise = "ar1"`). `EI` in the
summary is then the span-averaged flexibility's equivalent L / integral dx / EI, per draw.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..config import Config
from ..data.measurements import Measurements
from ..errors import InputError
from ..physics.fe_modal import GirderModalModel
from ..physics.girder import Girder
from ..physics.loads import quantity_weights
from .girder_posterior import GirderPosterior, girder_posterior
from .posterior import Posterior
from .priors import EIPrior

#: modes of the predictor (the posterior's own choice is made at the data; predictions elsewhere are cheap)
PREDICT_MODES = 16


@dataclass
class GirderReference(Posterior):
    """A `Posterior` of the span-equivalent EI and sigma that carries the girder posterior (`girder`) for the
    summary's EI_segments, rotational_stiffness and load_factor."""

    girder: GirderPosterior | None = field(default=None, repr=False, compare=False)

    @property
    def noise_ar1(self) -> np.ndarray | None:
        """Draws of the AR(1) coefficient of the noise, or None (white-noise model)."""
        return None if self.girder is None else self.girder.noise_ar1

    def summary(self, truth: dict | None = None) -> dict:
        if self.girder is None:
            return super().summary(truth)
        out = self.girder.summary(truth)
        out["runtime_s"] = float(self.runtime_s)
        return out


class GirderPredictor:
    """Posterior predictive of the girder surrogate: noise-free responses for posterior draws of
    (EI per segment, springs, load factor); the `Posterior.predictor` contract."""

    def __init__(self, cfg: Config, post: GirderPosterior):
        self.cfg, self.post = cfg, post
        b = cfg.beam
        mean_ei = post.EI_segments.reshape(-1, post.n_segments).mean(0)
        ks = (
            tuple(np.median(post.rotational_stiffness.reshape(-1, 2), axis=0))
            if post.rotational_stiffness is not None
            else (0.0, 0.0)
        )
        self.template = Girder(
            b.length,
            tuple(float(e) for e in mean_ei),
            b.mass_per_length,
            b.section_depth,
            b.damping_ratio,
            rotational_stiffness=tuple(float(k) for k in ks),
        )

    def __call__(
        self, x, t, quantity: str = "deflection", n_draws: int = 200, rng=None
    ) -> np.ndarray:
        rng = rng or np.random.default_rng(0)
        p = self.post
        S = p.n_segments
        ei = p.EI_segments.reshape(-1, S)
        pick = rng.choice(ei.shape[0], size=min(n_draws, ei.shape[0]), replace=False)
        x, t = np.broadcast_arrays(np.asarray(x, float).ravel(), np.asarray(t, float).ravel())
        w = quantity_weights(quantity)
        springs = p.rotational_stiffness is not None
        m = GirderModalModel(
            self.template,
            self.cfg.vehicle,
            x,
            t,
            *w,
            n_modes=PREDICT_MODES,
            infer_springs=springs,
        )
        ks = p.rotational_stiffness.reshape(-1, 2)[pick] if springs else None
        lf = p.load_factor.reshape(-1)[pick] if p.load_factor is not None else None
        out = m.predict(ei[pick], ks, lf)
        if quantity == "moment":
            seg = np.clip((x / self.cfg.beam.length * S).astype(int), 0, S - 1)
            out = -ei[pick][:, seg] * out
        return out


def girder_reference(
    data: Measurements, cfg: Config, *, seed, settings=None, progress: bool = False, method: str
) -> GirderReference:
    """The reference posterior of `cfg`'s analysis model (`[model]`, `[prior]`) given the data, labelled
    `method` (the reference's summary key)."""
    check_segments(cfg, data)
    m = cfg.model
    gp = girder_posterior(
        data,
        cfg.beam,
        cfg.vehicle,
        ei_prior=EIPrior.from_spec(cfg.prior),
        EI_segments=m.EI_segments,
        supports=m.supports,
        load_factor="auto" if cfg.infers_load_factor else "off",
        load_rel_sd=cfg.vehicle.load_rel_sd,
        k_median=cfg.prior.k_median,
        k_log_sd=cfg.prior.k_log_sd,
        EI_nominal=m.EI_nominal,
        noise=m.noise,
        seed=seed,
        settings=settings,
    )
    info = {"EI_nominal": gp.EI_nominal, **gp.info}
    return GirderReference(
        method,
        gp.EI,
        gp.sigma,
        diagnostics=gp.diagnostics,
        info=info,
        runtime_s=gp.runtime_s,
        predictor=GirderPredictor(cfg, gp),
        sample_stats=getattr(gp, "sample_stats", {}) or {},
        girder=gp,
    )


def check_segments(cfg: Config, data: Measurements) -> None:
    """`model.EI_segments` the data can carry: at most one segment per 5 observations (each segment's EI is a
    parameter the data must pin; with fewer the posterior is the prior's)."""
    S = cfg.model.EI_segments
    if S > 1 and S * 5 > len(data):
        raise InputError(
            "model.EI_segments",
            S,
            f"at most {max(1, len(data) // 5)} for {len(data)} observations (5 per segment)",
        )
