"""The modal reference: emcee on the reduced modal model's exact likelihood (`uq.modal_mcmc`)."""

from __future__ import annotations

from dataclasses import dataclass

from .. import seeding
from .base import Method, Settings


@dataclass(frozen=True)
class ModalSettings(Settings):
    """mcmc: a `uq.sampler.MCMCSettings` overriding the profile's (coverage studies use shorter runs)."""

    mcmc: object = None


class ModalMCMC(Method):
    """The reference posterior of (EI, sigma): emcee on the modal surrogate, exact up to Monte Carlo error
    for the model every method shares."""

    name = "modal"
    key = "modal_mcmc"
    display = "Modal reference (emcee)"
    colour = "#1f5fa8"
    reference = True
    Settings = ModalSettings

    def infer(self, data, config, *, seed):
        from ..uq.modal_mcmc import modal_posterior
        from ..uq.priors import NoisePrior
        from ..uq.sampler import MCMCSettings

        s = self.settings
        return modal_posterior(
            data,
            config,
            noise_prior=NoisePrior.build(s.noise_prior, data.value, s.snr_db),
            seed=seeding.stream(seed, "emcee"),
            settings=s.mcmc or MCMCSettings.for_profile(s.profile),
            progress=self.progress,
        )
