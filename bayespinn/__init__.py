"""bayespinn: how stiff a girder really is, and how sure we can be.

Physics-informed identification of the flexural rigidity EI of a bridge girder from measurements under
a moving load, with posteriors from a modal reference (emcee), deep ensembles of PINNs and a B-PINN.
"""

__version__ = "0.1.0"

from .config import Beam, Config, Vehicle, preset, resolve  # noqa: E402
from .data.measurements import Measurements, read_csv  # noqa: E402
from .data.synthetic import simulate  # noqa: E402
from .pipeline import RunResult, analyse, write_run  # noqa: E402
from .uq.posterior import Posterior  # noqa: E402

__all__ = [
    "Beam",
    "Config",
    "Measurements",
    "Posterior",
    "RunResult",
    "Vehicle",
    "analyse",
    "preset",
    "read_csv",
    "resolve",
    "simulate",
    "write_run",
]
