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
    real_girders = True
    real_crossings = True

    def check(self, data, config) -> None:
        # Method.check refuses AR(1) noise for the PINN methods; with real_girders it checks nothing else,
        # and this reference describes every [model] (its girder posterior carries the AR(1) likelihood)
        from ..crossings import check_crossings, needs_crossings
        from ..errors import InputError

        if config.model.EI_field == "smooth":
            from ..uq.girder_field import check_field

            if needs_crossings(config, data):
                raise InputError(
                    "model.EI_field",
                    "smooth",
                    "'segments' with a speed, entry time, damping or axle forces to infer, or several "
                    "crossings (the smooth field takes the crossing as stated)",
                )
            check_field(config, data)
            self._vague_only("a smooth EI field")
        elif needs_crossings(config, data):  # a speed, entry time, damping or forces, or crossings
            check_crossings(config, data)
            self._vague_only(
                "a crossing with a speed, entry time, damping or axle forces to infer, or several crossings"
            )
        elif not config.ideal:
            from ..uq.girder_reference import check_segments

            check_segments(config, data)
            self._vague_only("a girder with EI per segment, springs or an uncertain load")

    def _vague_only(self, what: str) -> None:
        """Refuse --noise-prior other than vague for `what`: its reference integrates sigma out under the
        vague prior."""
        if self.settings.noise_prior != "vague":
            from ..errors import InputError

            raise InputError(
                "--noise-prior",
                self.settings.noise_prior,
                f"vague for {what} (its reference integrates sigma out under the vague prior)",
            )

    def infer(self, data, config, *, seed):
        """The reference posterior: `uq.field_reference.field_reference` for a smooth EI field,
        `crossings.crossings_reference` when the crossing leaves anything uncertain
        (`crossings.needs_crossings`), else the girder reference for a real girder, else today's modal
        posterior of (EI, sigma)."""
        from ..uq.modal_mcmc import modal_posterior
        from ..uq.priors import NoisePrior
        from ..uq.sampler import MCMCSettings

        s = self.settings
        from ..crossings import crossings_reference, needs_crossings

        if config.model.EI_field == "smooth":
            from ..uq.field_reference import field_reference

            return field_reference(data, config, seed=seed, progress=self.progress, method=self.key)
        if needs_crossings(config, data):
            return crossings_reference(
                data,
                config,
                seed=seeding.stream(seed, "emcee"),
                settings=s.mcmc or MCMCSettings.for_profile(s.profile),
                progress=self.progress,
                method=self.key,
            )
        if not config.ideal:
            from ..uq.girder_reference import girder_reference

            return girder_reference(
                data,
                config,
                seed=seeding.stream(seed, "emcee"),
                progress=self.progress,
                method=self.key,
            )
        return modal_posterior(
            data,
            config,
            noise_prior=NoisePrior.build(s.noise_prior, data.value, s.snr_db),
            seed=seeding.stream(seed, "emcee"),
            settings=s.mcmc or MCMCSettings.for_profile(s.profile),
            progress=self.progress,
            method=self.key,
        )
