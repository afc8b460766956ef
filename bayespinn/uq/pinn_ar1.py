"""AR(1) noise in the PINN methods' results: the posterior that carries the coefficient's draws, and the
analysis model the rest of a method's checks see.

The deep ensemble and the last-layer B-PINN take `[model] noise = "ar1"` into their last-layer likelihood
(`lastlayer.LastLayer` with `noise`) and, for the ensemble's randomise-then-optimise members, into the
training objective (`pinn.Problem.noise_ar1`). Their posterior is then an `AR1Posterior`: the draws of
rho beside EI and sigma, `noise_ar1` in the summary (as the reference's), posterior predictive draws with
AR(1) noise along the sensors' series, and the coefficient the fit check whitens the residuals with.
"""

from __future__ import annotations

import dataclasses
import zlib
from dataclasses import dataclass, field

import numpy as np

from .posterior import Posterior, summarise


@dataclass
class AR1Posterior(Posterior):
    """A `Posterior` whose noise model is AR(1): ``ar1`` holds the coefficient's draws (chain, draw)."""

    ar1: np.ndarray | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.ar1 is None:
            raise ValueError("an AR1Posterior needs the draws of the AR(1) coefficient (ar1)")
        self.ar1 = np.asarray(self.ar1, float).reshape(self.EI.shape)

    @property
    def noise_ar1(self) -> np.ndarray:
        """Draws of the AR(1) coefficient of the noise."""
        return self.ar1

    def summary(self, truth: dict | None = None) -> dict:
        out = super().summary(truth)
        return {"EI": out["EI"], "sigma": out["sigma"], "noise_ar1": summarise(self.ar1), **out}

    def predictive_draws(self, data, n_draws: int = 200, seed: int = 0) -> np.ndarray | None:
        """`Posterior.predictive_draws` with AR(1) noise: the noise-free response for n posterior draws plus
        sigma times unit AR(1) noise along the sensors' series (`data.synthetic.ar1_noise`), (sigma, rho)
        drawn together from the posterior. A function of `seed`."""
        from ..data.synthetic import ar1_noise

        quiet = dataclasses.replace(self, sigma=np.zeros_like(self.sigma))
        resp = Posterior.predictive_draws(quiet, data, n_draws, seed)
        if resp is None or not np.isfinite(self.sigma).any():
            return None
        ss = np.random.SeedSequence(int(seed), spawn_key=(zlib.crc32(b"ar1_predictive"),))
        rng = np.random.default_rng(ss)
        ok = np.flatnonzero(np.isfinite(self.sigma.ravel()))
        k = rng.choice(ok, size=resp.shape[0], replace=True)
        sig, rho = self.sigma.ravel()[k], self.ar1.ravel()[k]
        noise = np.stack(
            [ar1_noise(rng.standard_normal(resp.shape[1]), data, float(r)) for r in rho]
        )
        return resp + sig[:, None] * noise

    def to_inference_data(self, data=None, seed: int = 0):
        """`Posterior.to_inference_data` with the coefficient's draws as the posterior's `noise_ar1`."""
        idata = super().to_inference_data(data, seed)
        post = idata.posterior
        idata.posterior = post.assign(noise_ar1=(("chain", "draw"), self.ar1))
        idata.posterior.attrs.update(post.attrs)
        return idata


def as_white(config):
    """The configuration with `[model] noise = "iid"`: what a method that takes AR(1) noise into its own
    likelihood lets the generic checks (`Method.check`) see."""
    return dataclasses.replace(config, model=dataclasses.replace(config.model, noise="iid"))
