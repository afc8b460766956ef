"""Synthetic measurements for the two case studies, with white Gaussian noise at a given SNR (Eq. 17-18).

The truth comes from the converged finite-element reference with point loads (`physics.fem`).
SNR (dB) = 10 log10(mean(value_true^2) / sigma^2), over all samples of the file; `None` means clean.
"""

from __future__ import annotations

import math
import zlib

import numpy as np

from .. import seeding
from ..config import Config, _check_number
from ..errors import InputError
from ..physics.fem import FESettings, fe_response
from .measurements import Measurements


def sigma_for_snr(value_true: np.ndarray, snr_db: float | None) -> float:
    """Noise standard deviation (units of the values) that gives snr_db over these samples."""
    if snr_db is None:
        return 0.0
    power = float(np.mean(np.asarray(value_true) ** 2))
    return float(np.sqrt(power / 10.0 ** (snr_db / 10.0)))


def realised_snr(value: np.ndarray, value_true: np.ndarray) -> float:
    """The SNR [dB] that a noisy file actually has."""
    noise = np.asarray(value) - np.asarray(value_true)
    return float(10.0 * np.log10(np.mean(np.asarray(value_true) ** 2) / np.mean(noise**2)))


def sample_layout(cfg: Config, seed: int | np.random.SeedSequence) -> Measurements:
    """Where and when the sensors read, without values (value and value_true are zero).

    deflection: `cfg.data.n_points` points uniform over [0, L] x [0, T] (the paper's random 100);
    strain: each gauge of `cfg.sensors` sampled at `cfg.data.sample_rate` over [0, T].
    """
    L, T = cfg.beam.length, cfg.duration
    if cfg.case == "deflection":
        r = seeding.rng(seed, "points")
        n = cfg.data.n_points
        x, t = r.uniform(0.0, L, n), r.uniform(0.0, T, n)
        kind = np.full(n, "deflection")
        y = np.full(n, np.nan)
        sensor = np.full(n, "")
    else:
        times = np.arange(0.0, T + 1e-12, 1.0 / cfg.data.sample_rate)
        S = cfg.sensors
        x = np.concatenate([np.full(times.size, s.x) for s in S])
        t = np.tile(times, len(S))
        y = np.concatenate([np.full(times.size, s.y) for s in S])
        kind = np.full(x.size, "strain")
        sensor = np.concatenate([np.full(times.size, s.name) for s in S])
    z = np.zeros(x.size)
    return Measurements(x, t, z, kind.astype(str), y, sensor.astype(str), z.copy())


#: largest relative sd of the axle loads that `draw_load_factor` accepts
LOAD_REL_SD_MAX = 0.2


def _stream(seed: int | np.random.SeedSequence, name: str) -> np.random.SeedSequence:
    """An independent named SeedSequence under a root seed (as `seeding.stream`, for a name that is
    not one of its registered streams)."""
    key = zlib.crc32(name.encode())
    if isinstance(seed, np.random.SeedSequence):
        return np.random.SeedSequence(seed.entropy, spawn_key=tuple(seed.spawn_key) + (key,))
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise InputError("seed", seed, "an integer >= 0 or a numpy SeedSequence")
    return np.random.SeedSequence(int(seed), spawn_key=(key,))


def check_load_rel_sd(load_rel_sd: float) -> float:
    """load_rel_sd as a float in [0, LOAD_REL_SD_MAX]; InputError('vehicle.load_rel_sd') otherwise."""
    v = _check_number("vehicle.load_rel_sd", load_rel_sd, nonneg=True)
    if v > LOAD_REL_SD_MAX:
        raise InputError("vehicle.load_rel_sd", load_rel_sd, f"a number in [0, {LOAD_REL_SD_MAX}]")
    return v


def draw_load_factor(load_rel_sd: float, seed: int | np.random.SeedSequence) -> float:
    """The true common factor on every axle load of one crossing: 1 + load_rel_sd z, z ~ N(0, 1),
    redrawn until positive (a normal truncated to > 0). Exactly 1.0 when load_rel_sd = 0.
    A function of the seed (its own "load_factor" stream, independent of the points and the noise)."""
    sd = check_load_rel_sd(load_rel_sd)
    r = np.random.default_rng(_stream(seed, "load_factor"))
    if sd == 0.0:
        return 1.0
    while True:
        lf = 1.0 + sd * float(r.standard_normal())
        if lf > 0.0:
            return lf


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


def ar1_noise(z: np.ndarray, layout: Measurements, phi: float) -> np.ndarray:
    """Unit-variance AR(1) noise from i.i.d. standard normals z: e_k = phi e_(k-1) + sqrt(1 - phi^2) z_k along
    each sensor's series in time order (strain gauges), or along all points in time order (scattered
    deflection points: one instrument read at increasing times). Stationary from the first sample."""
    if phi == 0.0:
        return z
    out = np.empty_like(z)
    keys = layout.sensor if np.any(layout.sensor != "") else np.full(len(z), "")
    c = math.sqrt(1.0 - phi * phi)
    for name in np.unique(keys):
        idx = np.flatnonzero(keys == name)
        idx = idx[np.argsort(layout.t[idx], kind="stable")]
        e = z[idx[0]]
        out[idx[0]] = e
        for i in idx[1:]:
            e = phi * e + c * z[i]
            out[i] = e
    return out


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
