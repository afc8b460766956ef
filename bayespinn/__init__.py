"""bayespinn: how stiff a girder really is, and how sure we can be.

Physics-informed identification of the flexural rigidity EI of a bridge girder from measurements under
a moving load, with posteriors from a modal reference (emcee), deep ensembles of PINNs and a B-PINN.
"""

from . import methods
from .config import Beam, Config, Vehicle, preset, resolve
from .data.measurements import Measurements, read_csv
from .data.synthetic import simulate
from .pipeline import RunResult, analyse, write_run
from .uq.posterior import Posterior
from .version import __version__

__all__ = [
    "Beam",
    "Config",
    "Measurements",
    "Posterior",
    "RunResult",
    "Vehicle",
    "__version__",
    "analyse",
    "methods",
    "preset",
    "read_csv",
    "resolve",
    "simulate",
    "write_run",
]
