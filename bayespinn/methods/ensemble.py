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

    def infer(self, data, config, *, seed):
        from ..uq.ensemble import ensemble_posterior
        from ..uq.priors import NoisePrior
        from ..uq.shared_fit import ensemble_seed

        s = self.settings
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
