"""Posterior predictive draws and bands for the figures and tables, and the FE truth to compare with.

Two kinds of band are used and always named:
- the *response* band: quantiles of the noise-free response over posterior draws (what the structure
  does; compared with the FE truth);
- the *predictive* band: the response plus N(0, sigma^2) noise, sigma drawn from its posterior
  (what a sensor would read; compared with the data).
"""

from __future__ import annotations

import functools
import zlib
from collections.abc import Callable

import numpy as np

from ..config import Config
from ..physics.fem import fe_response
from .posterior import Posterior

#: the paper's Table 5 / Fig. 4 time instants [s]
PAPER_TIMES = (0.60, 1.22, 1.82)
#: posterior draws used for bands (the 5 % and 95 % quantiles of 200 draws are stable to a few %)
N_DRAWS = 200
LEVEL = 0.9


def report_rng(seed: int | None, purpose: str) -> np.random.Generator:
    """A generator for the report's predictive draws, a function of the run's seed and the purpose."""
    key = zlib.crc32(f"report/{purpose}".encode())
    return np.random.default_rng(np.random.SeedSequence(int(seed or 0), spawn_key=(key,)))


def span_times(cfg: Config, times=PAPER_TIMES) -> list[float]:
    """The time instants clipped to the crossing [0, T] (duplicates after clipping removed)."""
    T = cfg.duration
    out: list[float] = []
    for t in times:
        c = float(min(max(t, 0.0), T))
        if not any(abs(c - o) < 1e-12 for o in out):
            out.append(c)
    return out


def predict(
    post: Posterior,
    x: np.ndarray,
    t: np.ndarray,
    quantity: str,
    rng: np.random.Generator,
    n_draws: int = N_DRAWS,
    y: np.ndarray | float | None = None,
) -> np.ndarray:
    """Noise-free response draws (n, P) in SI: 'deflection' [m], 'moment' [N m], 'curvature' [1/m], or
    'strain' [-] = -y * curvature (y [m], + down). Raises ValueError if the posterior has no predictor."""
    pred: Callable | None = post.predictor
    if pred is None:
        raise ValueError(f"{post.method} has no predictor")
    x = np.asarray(x, float).ravel()
    t = np.broadcast_to(np.asarray(t, float), x.shape).ravel()
    if quantity == "strain":
        if y is None:
            raise ValueError("strain needs the fibre distance y")
        yy = np.broadcast_to(np.asarray(y, float), x.shape).ravel()
        return -yy[None, :] * np.asarray(pred(x, t, "curvature", n_draws, rng), float)
    return np.asarray(pred(x, t, quantity, n_draws, rng), float)


def add_noise(draws: np.ndarray, sigma_draws: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Response draws (n, P) plus Gaussian noise, one sigma drawn from its posterior per row."""
    s = rng.choice(np.asarray(sigma_draws, float).ravel(), size=draws.shape[0], replace=True)
    return draws + s[:, None] * rng.standard_normal(draws.shape)


def predictive_band(
    resp: np.ndarray,
    sigma_draws: np.ndarray,
    rng: np.random.Generator,
    level: float = LEVEL,
    min_rows: int = N_DRAWS,
) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) of the posterior predictive band: response draws (n, P) plus noise. With few
    response draws (a small ensemble) each is repeated, with fresh noise, to at least `min_rows` rows."""
    reps = max(1, -(-min_rows // max(resp.shape[0], 1)))
    _, lo, hi = band(add_noise(np.repeat(resp, reps, axis=0), sigma_draws, rng), level)
    return lo, hi


def band(draws: np.ndarray, level: float = LEVEL) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean, lower, upper) over draws (axis 0), equal-tailed at `level`."""
    a = (1.0 - level) / 2.0
    lo, hi = np.quantile(draws, [a, 1.0 - a], axis=0)
    return draws.mean(axis=0), lo, hi


def fe_truth(
    cfg: Config, x: np.ndarray, t: np.ndarray, quantity: str, y=None, load_factor: float = 1.0
) -> np.ndarray:
    """Finite-element reference at (x, t) with the configuration's (true) girder, SI units: the uniform pinned
    girder's (`physics.fem`), or with EI per segment or springs the real girder's (`physics.girder`); every
    axle load times `load_factor` (the crossing's true factor when the loads were uncertain)."""
    x = np.asarray(x, float).ravel()
    t = np.broadcast_to(np.asarray(t, float), x.shape).ravel()
    if quantity == "deflection":
        a_u, a_xx = 1.0, 0.0
    elif quantity == "moment":
        a_u, a_xx = 0.0, -_ei_at(cfg, x)
    elif quantity == "strain":
        a_u, a_xx = 0.0, -np.broadcast_to(np.asarray(y, float), x.shape)
    else:
        raise ValueError(f"quantity must be deflection, moment or strain, got {quantity!r}")
    if cfg.beam.ideal and load_factor == 1.0:
        return fe_response(cfg.beam, cfg.vehicle, x, t, a_u, a_xx)
    t_end = max(cfg.duration, float(t.max()))
    return _girder_crossing(cfg.beam, cfg.vehicle, float(load_factor), t_end).sample(
        x, t, a_u, a_xx
    )


def _ei_at(cfg: Config, x: np.ndarray) -> np.ndarray:
    seg = np.asarray(cfg.beam.segments, float)
    i = np.clip((x / cfg.beam.length * seg.size).astype(int), 0, seg.size - 1)
    return seg[i]


@functools.lru_cache(maxsize=4)
def _girder_crossing(beam, vehicle, load_factor: float, t_end: float):
    from ..physics.fem import FESettings
    from ..physics.girder import Girder, GirderFE

    fe = FESettings()
    girder = Girder.from_beam(beam, beam.segments, beam.rotational_stiffness)
    return GirderFE(girder, fe.n_elements).solve(vehicle, t_end, fe.n_steps, load_factor)


def with_predictor(posteriors: dict[str, Posterior]) -> dict[str, Posterior]:
    """The posteriors that can predict responses, in their original order."""
    return {k: p for k, p in posteriors.items() if p.predictor is not None}
