"""One entry point over the UQ methods: `infer(method, data, cfg, ...) -> Posterior`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import seeding
from ..config import Config
from ..data.measurements import Measurements
from ..errors import InputError
from .posterior import Posterior
from .priors import NoisePrior

#: CLI name -> summary key
KEYS = {"modal": "modal_mcmc", "ensemble": "ensemble", "bpinn": "bpinn"}


@dataclass(frozen=True)
class RunOptions:
    """What every method needs besides the data: profile, ensemble size, device, noise prior, progress."""

    profile: str = "fast"
    members: int = 5
    device: str = "cpu"
    noise_prior: str = "vague"
    snr_db: float | None = None
    progress: bool = False
    executor: object = None  # bayespinn.executor.Executor for ensemble members
    mcmc: object = None  # bayespinn.uq.sampler.MCMCSettings overriding the profile's
    bpinn_variant: str = "auto"  # last-layer, full, or auto (`bpinn.resolve_variant`)


def noise_prior(data: Measurements, opts: RunOptions) -> NoisePrior:
    return NoisePrior.build(opts.noise_prior, data.value, opts.snr_db)


def infer(
    method: str,
    data: Measurements,
    cfg: Config,
    seed: int | np.random.SeedSequence,
    opts: RunOptions,
) -> Posterior:
    """Run one method (CLI name: modal, ensemble, bpinn) on the data."""
    if method == "modal":
        from .modal_mcmc import MCMCSettings, modal_posterior

        return modal_posterior(
            data,
            cfg,
            noise_prior=noise_prior(data, opts),
            seed=seeding.stream(seed, "emcee"),
            settings=opts.mcmc or MCMCSettings.for_profile(opts.profile),
            progress=opts.progress,
        )
    if method == "ensemble":
        from .ensemble import ensemble_posterior

        return ensemble_posterior(
            data,
            cfg,
            seed=seeding.stream(seed, "ensemble"),
            opts=opts,
            noise=noise_prior(data, opts),
        )
    if method == "bpinn":
        from .bpinn import bpinn_posterior

        return bpinn_posterior(
            data, cfg, seed=seeding.stream(seed, "pyro"), opts=opts, noise=noise_prior(data, opts)
        )
    raise InputError("--method", method, "modal, ensemble or bpinn")
