"""The PINN engine: network, Taylor-mode derivatives, loss terms and the one training loop.

Public surface::

    Problem, Scales                       what is fitted (problem.py)
    TrainSettings, PROFILES               how (settings.py; profiles 'smoke', 'fast', 'paper')
    fit, FitResult                        the training loop (train.py)
    PINN                                  the (batched) network (network.py)
    Objective                             loss terms (losses.py)
    beta_bias_factor                      the Gaussian-delta bias correction (beta.py)
"""

from .beta import beta_bias_factor
from .losses import Objective
from .network import PINN
from .problem import Problem, Scales
from .settings import PROFILES, TrainSettings
from .train import FitResult, fit, networks_per_batch

__all__ = [
    "PINN",
    "PROFILES",
    "FitResult",
    "Objective",
    "Problem",
    "Scales",
    "TrainSettings",
    "beta_bias_factor",
    "fit",
    "networks_per_batch",
]
