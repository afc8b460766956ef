"""The deep ensemble of PINNs (`uq.ensemble`)."""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import InputError
from .base import Method, Settings, check_device


@dataclass(frozen=True)
class EnsembleSettings(Settings):
    """members: networks in the ensemble (>= 1); device: cpu or cuda."""

    members: int = 5
    device: str = "cpu"

    def __post_init__(self) -> None:
        super().__post_init__()
        if isinstance(self.members, bool) or not isinstance(self.members, int) or self.members < 1:
            raise InputError("members", self.members, "an integer >= 1")
        check_device(self.device)


class DeepEnsemble(Method):
    """PINNs trained from independent starts, then randomise-then-optimise, pooled into a posterior."""

    name = "ensemble"
    key = "ensemble"
    display = "Deep ensemble"
    colour = "#c0392b"
    Settings = EnsembleSettings
    modules = ("bayespinn.methods.ensemble", "bayespinn.uq.ensemble_batch")

    def check(self, data, config) -> None:
        from ..uq.girder_pinn import check_girder

        if config.real_girder:  # EI per segment, springs or an uncertain load (`uq.girder_pinn`)
            return check_girder(config, data, self.display)
        # AR(1) noise is in its likelihood (`uq.pinn_ar1`); the girder model is checked as for white noise
        from ..uq.pinn_ar1 import as_white

        super().check(data, as_white(config))

    def batches(self) -> bool:
        """On a GPU the members of many datasets' ensembles train as one network (`ensemble_batch`)."""
        from ..uq.ensemble import _batched

        return _batched(self.settings.device)

    def infer_many(self, datas, config, *, seeds):
        """The posterior of each dataset (same girder model, one seed each): on a GPU their ensembles train
        as one network (`uq.ensemble_batch.ensemble_posteriors`), elsewhere `infer` runs on each in turn."""
        # AR(1) noise and real girders: one ensemble at a time
        if not self.batches() or config.model.noise != "iid" or config.real_girder:
            return [self.infer(d, config, seed=sd) for d, sd in zip(datas, seeds, strict=True)]
        from ..uq.ensemble_batch import ensemble_posteriors
        from ..uq.priors import NoisePrior
        from ..uq.shared_fit import ensemble_seed

        s = self.settings
        return ensemble_posteriors(
            list(datas),
            config,
            seeds=[ensemble_seed(sd) for sd in seeds],
            noises=[NoisePrior.build(s.noise_prior, d.value, s.snr_db) for d in datas],
            members=s.members,
            profile=s.profile,
            device=s.device,
            executor=self.executor,
            progress=self.progress,
        )

    def infer(self, data, config, *, seed):
        from ..uq.ensemble import ensemble_posterior
        from ..uq.girder_pinn import girder_ensemble_posterior
        from ..uq.priors import NoisePrior
        from ..uq.shared_fit import ensemble_seed

        s = self.settings
        if config.real_girder:
            return girder_ensemble_posterior(
                data,
                config,
                seed=ensemble_seed(seed),
                members=s.members,
                profile=s.profile,
                progress=self.progress,
                executor=self.executor,
            )
        return ensemble_posterior(
            data,
            config,
            seed=ensemble_seed(seed),
            members=s.members,
            profile=s.profile,
            device=s.device,
            noise=NoisePrior.build(s.noise_prior, data.value, s.snr_db),
            executor=self.executor,
            progress=self.progress,
        )
