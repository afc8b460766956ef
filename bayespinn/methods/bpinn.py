"""The B-PINN, in two variants: last-layer (`uq.bpinn`, the fast default) and full-weight
(`uq.bpinn_full`). `BPINN` is the registered method (CLI `bpinn`); built from settings it becomes the
variant they name (`uq.bpinn_core.resolve_variant`: 'auto' is the last-layer one)."""

from __future__ import annotations

from dataclasses import dataclass

from .. import seeding
from ..options import BPINN_VARIANTS
from .base import Method, Settings, check_choice, check_device


@dataclass(frozen=True)
class BPINNSettings(Settings):
    """device: cpu or cuda; bpinn_variant: auto, last-layer or full."""

    device: str = "cpu"
    bpinn_variant: str = "auto"

    def __post_init__(self) -> None:
        super().__post_init__()
        check_device(self.device)
        check_choice("bpinn_variant", self.bpinn_variant, BPINN_VARIANTS)


class BPINN(Method):
    """Bayesian PINN with priors on EI and the noise level, sampled by NUTS (Pyro)."""

    name = "bpinn"
    key = "bpinn"
    display = "B-PINN"
    colour = "#2e8b3d"
    Settings = BPINNSettings
    modules = ("bayespinn.methods.bpinn",)  # imports both variants

    def __new__(cls, settings=None, **kw):
        if cls is BPINN:
            from ..uq.bpinn_core import resolve_variant

            s = (
                settings
                if settings is not None
                else BPINNSettings(
                    **{k: v for k, v in kw.items() if k not in ("progress", "executor")}
                )
            )
            if isinstance(s, BPINNSettings):
                cls = (
                    FullWeightBPINN
                    if resolve_variant(s.bpinn_variant, s.profile) == "full"
                    else LastLayerBPINN
                )
        return super().__new__(cls)

    def _sampler(self):
        raise NotImplementedError

    def infer(self, data, config, *, seed):
        from ..uq.priors import NoisePrior
        from ..uq.shared_fit import ensemble_seed, member_seed

        s = self.settings
        return self._sampler()(
            data,
            config,
            seed=seeding.stream(seed, "pyro"),
            profile=s.profile,
            device=s.device,
            noise=NoisePrior.build(s.noise_prior, data.value, s.snr_db),
            progress=self.progress,
            # the deep ensemble's member 0 fit on the same data (`uq.shared_fit`)
            fit_seed=member_seed(ensemble_seed(seed)),
            **self._sampler_options(),
        )

    def _sampler_options(self) -> dict:
        return {}


class LastLayerBPINN(BPINN):
    """NUTS on log EI and log sigma (and the AR(1) noise coefficient), the network's output weights
    integrated out exactly."""

    def check(self, data, config) -> None:
        from ..uq.girder_pinn import check_girder

        if config.real_girder:  # EI per segment, springs or an uncertain load (`uq.girder_pinn`)
            return check_girder(config, data, self.display)
        # AR(1) noise is in its likelihood (`uq.pinn_ar1`); the girder model is checked as for white noise
        from ..uq.pinn_ar1 import as_white

        super().check(data, as_white(config))

    def infer(self, data, config, *, seed):
        from ..uq.girder_pinn import girder_bpinn_posterior, member_fit_seed

        if not config.real_girder:
            return super().infer(data, config, seed=seed)
        from ..uq.shared_fit import ensemble_seed

        return girder_bpinn_posterior(
            data,
            config,
            seed=seeding.stream(seed, "pyro"),
            profile=self.settings.profile,
            # the deep ensemble's member 0 network on the same data (same seed, same training)
            fit_seed=member_fit_seed(ensemble_seed(seed), 0),
            progress=self.progress,
            executor=self.executor,
        )

    def _sampler(self):
        from ..uq.bpinn import lastlayer_posterior

        return lastlayer_posterior

    def _sampler_options(self) -> dict:
        # its chains run as tasks of the run's executor (one process per core by default)
        return {"executor": self.executor}


class FullWeightBPINN(BPINN):
    """NUTS on every hidden weight, log EI and log sigma (output weights integrated out exactly)."""

    def check(self, data, config) -> None:
        if config.model.noise != "iid":
            from ..errors import InputError

            raise InputError(
                "model.noise",
                config.model.noise,
                "'iid' for the full-weight B-PINN (its sampler has no AR(1) likelihood); the last-layer "
                "B-PINN (--bpinn-variant last-layer), the deep ensemble and the modal reference have it",
            )
        super().check(data, config)

    def _sampler(self):
        from ..uq.bpinn_full import full_posterior

        return full_posterior
