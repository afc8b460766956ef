"""Uncertainty quantification: the shared Posterior type, priors, and one module per method."""

from .posterior import Posterior, central_interval, summarise
from .priors import EIPrior, NoisePrior

__all__ = ["EIPrior", "NoisePrior", "Posterior", "central_interval", "summarise"]
