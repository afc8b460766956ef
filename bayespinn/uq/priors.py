"""Priors shared by every method: log-normal on EI, and on the noise sd sigma either vague or SNR-centred.

Both act on log-parameters; densities below are with respect to (log EI, log sigma).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from .. import seeding
from ..config import PriorSpec
from ..errors import InputError
from .posterior import Posterior

NOISE_PRIORS = ("vague", "snr")
#: sd of log(sigma) for the SNR-conditioned prior: the nominal SNR is known to about +-2 dB
SNR_LOG_SD = 0.25
#: the vague prior is uniform in log(sigma) (Jeffreys) between these multiples of the data RMS
VAGUE_LOW, VAGUE_HIGH = 1e-7, 2.0


@dataclass(frozen=True)
class EIPrior:
    """log EI ~ Normal(log median, log_sd)."""

    median: float
    log_sd: float

    @classmethod
    def from_spec(cls, spec: PriorSpec) -> EIPrior:
        return cls(spec.EI_median, spec.EI_log_sd)

    @property
    def loc(self) -> float:
        return math.log(self.median)

    def logpdf(self, log_EI: np.ndarray) -> np.ndarray:
        z = (np.asarray(log_EI) - self.loc) / self.log_sd
        return -0.5 * z**2 - math.log(self.log_sd * math.sqrt(2 * math.pi))

    def sample(self, rng: np.random.Generator, size=None) -> np.ndarray:
        return np.exp(rng.normal(self.loc, self.log_sd, size))


@dataclass(frozen=True)
class NoisePrior:
    """Prior on log(sigma).

    kind 'vague': uniform in log(sigma) on [VAGUE_LOW, VAGUE_HIGH] x RMS(data) (scale-invariant Jeffreys
    prior, made proper by wide bounds). kind 'snr': log(sigma) ~ Normal(log(sigma_nominal), SNR_LOG_SD),
    sigma_nominal being the sd that the nominal SNR implies for these data.
    """

    kind: str
    low: float
    high: float
    center: float = float("nan")
    log_sd: float = SNR_LOG_SD

    def __post_init__(self) -> None:
        if self.kind not in NOISE_PRIORS:
            raise InputError("--noise-prior", self.kind, "vague or snr")

    @classmethod
    def build(cls, kind: str, values: np.ndarray, snr_db: float | None = None) -> NoisePrior:
        """The prior for a measurement vector `values` (and the nominal SNR for kind 'snr')."""
        values = np.asarray(values, float)
        if values.size == 0:  # no measurements: sigma cannot be learnt; a nominal wide range
            return cls(kind if kind == "vague" else "vague", 1e-12, 1.0)
        rms = float(np.sqrt(np.mean(values**2)))
        if rms <= 0:
            raise InputError("data.value", 0.0, "measurements that are not all zero")
        if kind == "snr":
            if snr_db is None:
                raise InputError(
                    "--noise-prior", "snr", "a nominal SNR in dB (--snr) to centre the prior on"
                )
            # data power = signal power + sigma^2, so sigma^2 = power / (10^(snr/10) + 1)
            nominal = rms / math.sqrt(10 ** (snr_db / 10) + 1)
            return cls("snr", VAGUE_LOW * rms, VAGUE_HIGH * rms, nominal, SNR_LOG_SD)
        return cls(kind, VAGUE_LOW * rms, VAGUE_HIGH * rms)

    def logpdf(self, log_sigma: np.ndarray) -> np.ndarray:
        ls = np.asarray(log_sigma, float)
        inside = (ls >= math.log(self.low)) & (ls <= math.log(self.high))
        if self.kind == "vague":
            val = -math.log(math.log(self.high / self.low))
            return np.where(inside, val, -np.inf)
        z = (ls - math.log(self.center)) / self.log_sd
        return np.where(
            inside, -0.5 * z**2 - math.log(self.log_sd * math.sqrt(2 * math.pi)), -np.inf
        )

    def describe(self) -> str:
        if self.kind == "vague":
            return f"log-uniform sigma on [{self.low:.3g}, {self.high:.3g}]"
        return f"log-normal sigma, median {self.center:.3g}, log-sd {self.log_sd}"


def prior_only(ei_prior: EIPrior, seed, t0: float, method: str) -> Posterior:
    """No measurements: the posterior is the prior (exact draws); sigma is not estimable (NaN).

    Every method returns this when there are no data: the physics alone fixes the shape of the
    response for any EI, so only measurements can identify EI.
    """
    r = np.random.default_rng(seeding.stream(seed, "emcee"))
    EI = ei_prior.sample(r, (4, 1000))
    diag = {"converged": True, "scheme": "no data: exact prior draws"}
    info = {"identified": False, "note": "EI is not identified by these data"}
    return Posterior(
        method,
        EI,
        np.full(EI.shape, np.nan),
        diagnostics=diag,
        info=info,
        runtime_s=time.perf_counter() - t0,
    )
