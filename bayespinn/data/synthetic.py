"""Synthetic measurements for the two case studies, with white Gaussian noise at a given SNR (Eq. 17-18).

The truth comes from the converged finite-element reference with point loads (`physics.fem`).
SNR (dB) = 10 log10(mean(value_true^2) / sigma^2), over all samples of the file; `None` means clean.
"""

from __future__ import annotations

import numpy as np

from .. import seeding
from ..config import Config
from ..physics.fem import FESettings, fe_response
from .layout import layout_over
from .measurements import Measurements
from .noise import (  # noqa: F401 (re-exported: the names `simulate`'s users have always imported here)
    LOAD_REL_SD_MAX,
    _stream,
    ar1_noise,
    check_load_rel_sd,
    draw_load_factor,
    realised_snr,
    sigma_for_snr,
)


def sample_layout(cfg: Config, seed: int | np.random.SeedSequence) -> Measurements:
    """Where and when the sensors read, without values (value and value_true are zero).

    deflection: `cfg.data.n_points` points uniform over [0, L] x [0, T] (the paper's random 100);
    strain: each gauge of `cfg.sensors` sampled at `cfg.data.sample_rate` over [0, T].
    """
    return layout_over(cfg, cfg.duration, seeding.rng(seed, "points"))


#: largest relative sd of the axle loads that `draw_load_factor` accepts
def true_load_factor(cfg: Config, seed: int | np.random.SeedSequence = 0) -> float:
    """The crossing's true common axle-load factor: 1 with exactly known loads, else a draw with relative sd
    `vehicle.load_rel_sd` (`girder_data.draw_load_factor`), a function of the seed."""
    if cfg.vehicle.load_rel_sd == 0.0:
        return 1.0
    return draw_load_factor(cfg.vehicle.load_rel_sd, seed)


def true_values(
    cfg: Config, layout: Measurements, fe: FESettings | None = None, load_factor: float = 1.0
) -> np.ndarray:
    """Noise-free values at the layout's points from the finite-element reference: the uniform pinned
    girder's (`physics.fem`), or for EI per segment or springs at the supports the real girder's
    (`physics.girder`, the same elements and steps); every axle load times `load_factor`."""
    a_u, a_xx = layout.weights
    fe = fe or FESettings()
    if cfg.beam.ideal and load_factor == 1.0:
        return fe_response(cfg.beam, cfg.vehicle, layout.x, layout.t, a_u, a_xx, fe)
    from ..physics.girder import Girder, GirderFE

    b = cfg.beam
    girder = Girder(
        b.length, b.segments, b.mass_per_length, b.section_depth, b.damping_ratio,
        b.rotational_stiffness,
    )  # fmt: skip
    t = np.asarray(layout.t, float)
    t_end = max(cfg.duration, float(t.max()))
    resp = GirderFE(girder, fe.n_elements).solve(cfg.vehicle, t_end, fe.n_steps, load_factor)
    return resp.sample(layout.x, t, a_u, a_xx)


def simulate(
    cfg: Config,
    snr_db: float | None,
    seed: int | np.random.SeedSequence = 0,
    fe: FESettings | None = None,
) -> Measurements:
    """A synthetic measurement set for `cfg.case` at `snr_db` (None: clean), a function of the seed.

    The truth is the girder `cfg.beam` describes (EI per segment, springs at the supports) under the stated
    axles times the crossing's true load factor (`true_load_factor`); the noise is white, or AR(1) with
    `data.noise_ar1` along each sensor's series (`ar1_noise`), with the sd that gives `snr_db`.

    Realistic crossings (`cfg.realistic`: sprung axles, a rough road, a recording that starts before the
    entry, or several `[[crossing]]` tables) come from the independent vehicle-bridge simulator
    (`bayespinn.vbi.simulate`, its own discretisation and time integration; `fe` does not apply)."""
    if cfg.realistic:
        from ..vbi import simulate as vbi_simulate

        return vbi_simulate(cfg, snr_db, seed)
    layout = sample_layout(cfg, seed)
    vt = true_values(cfg, layout, fe, true_load_factor(cfg, seed))
    sigma = sigma_for_snr(vt, snr_db)
    z = seeding.rng(seed, "noise").standard_normal(vt.size)
    noise = ar1_noise(z, layout, cfg.data.noise_ar1) * sigma
    return Measurements(layout.x, layout.t, vt + noise, layout.kind, layout.y, layout.sensor, vt)
