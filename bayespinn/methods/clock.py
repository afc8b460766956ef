"""A recording that starts before the vehicle arrives, for a method that takes the crossing as stated (the
PINN methods): the data on the crossing's own clock, and the posterior's predictions back on the data's.

A recording's clock is not the vehicle's: `[vehicle] entry_time` says when the first axle enters the span.
The PINN methods model the crossing from its entry (t = 0: the girder at rest, the first axle at the left
support). With a stated entry time (its sd 0) they read the rows from the entry on, on the clock t - entry
time; the rows before it carry the girder at rest, i.e. nothing about EI, and their share of the noise
level is left to those after. Their posterior predicts on the data's clock (`ShiftedPredictor`): zero
response before the entry, so the fit check and the report see every row, those before the entry included.
An entry time to infer (`entry_time_sd > 0`) is the modal reference's (`crossings`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..config import Config
from ..data.measurements import Measurements
from ..errors import InputError


def on_entry_clock(data: Measurements, cfg: Config) -> tuple[Measurements, Config, float]:
    """(data from the entry on, on the crossing's clock; the configuration with its entry at t = 0; the
    entry time [s]). Unchanged, with 0, when the vehicle enters at t = 0."""
    te = float(cfg.vehicle.entry_time)
    if te == 0.0:
        return data, cfg, 0.0
    after = np.asarray(data.t, float) >= te
    if not after.any():
        raise InputError(
            "vehicle.entry_time",
            te,
            f"a time within the recording (its last sample is at t = {float(np.max(data.t)):g} s)",
        )
    kept = data.select(after)
    kept = dataclasses.replace(kept, t=kept.t - te)
    veh = dataclasses.replace(cfg.vehicle, entry_time=0.0)
    return kept, dataclasses.replace(cfg, vehicle=veh), te


@dataclasses.dataclass
class ShiftedPredictor:
    """A posterior predictor on the crossing's clock, read on the data's: predictor(x, t - entry time), and
    zero response before the entry (the girder at rest)."""

    inner: object
    entry_time: float

    def __call__(self, x, t, quantity: str = "deflection", n_draws: int = 200, rng=None):
        x, t = (np.asarray(a, float) for a in np.broadcast_arrays(x, t))
        x, tt = x.ravel(), t.ravel() - self.entry_time
        after = tt >= 0.0
        if after.any():
            r = np.asarray(self.inner(x[after], tt[after], quantity, n_draws, rng), float)
        else:  # only the draw count is needed
            r = np.asarray(self.inner(x[:1], np.zeros(1), quantity, n_draws, rng), float)[:, :0]
        out = np.zeros((r.shape[0], x.size))
        out[:, after] = r
        return out


def on_data_clock(post, entry_time: float):
    """The posterior `post` of data read on the entry clock, its predictor on the data's clock again."""
    if entry_time == 0.0:
        return post
    if post.predictor is not None:
        post.predictor = ShiftedPredictor(post.predictor, entry_time)
    post.info = {**post.info, "entry_time_s": entry_time}
    return post
