"""Realistic synthetic crossings: the independent simulator turned into a measurement file.

A crossing's recording runs on the data's clock from t = 0 to entry_time + T (T = (L + last offset) /
speed, the first axle entering at entry_time); the girder is at rest, and reads zero, before the entry.
The layout follows the existing rules over that window: `data.n_points` random (x, t) deflection points,
or each strain gauge at `data.sample_rate` from t = 0. Each crossing has its own road-profile draw,
points and true load factor from streams of the root seed; the noise is one white (or AR(1) per sensor
and crossing) draw over the whole file, its sd giving the SNR over all samples of the file.

With no `[[crossing]]` tables the file is the one crossing `[vehicle]` describes and has no `crossing`
column; with them, every crossing goes into one file, its rows named in the `crossing` column.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import seeding
from ..config import Axle, Config, Vehicle, replace
from ..data.layout import layout_over
from ..data.measurements import Measurements
from ..data.noise import _stream, ar1_noise, draw_load_factor, sigma_for_snr
from ..errors import InputError
from .beam import SimBeam
from .road import flat_road, iso8608_road
from .solver import Crossing as Solved
from .solver import solve


@dataclass(frozen=True)
class VBISettings:
    """Discretisation of the simulator: elements, steps over the span crossing, and generalized-alpha's
    spectral radius. The defaults are converged far below any noise level used (docs/simulator.md)."""

    n_elements: int = 192
    n_steps: int = 8000
    rho_inf: float = 0.8

    def __post_init__(self) -> None:
        if isinstance(self.n_steps, bool) or not isinstance(self.n_steps, int) or self.n_steps < 10:
            raise InputError("vbi n_steps", self.n_steps, "an integer >= 10")
        if not 0.0 <= float(self.rho_inf) <= 1.0:
            raise InputError("vbi rho_inf", self.rho_inf, "a number in [0, 1]")


def crossings_of(cfg: Config) -> tuple[tuple[str | None, Vehicle], ...]:
    """(name, vehicle) of each crossing: the `[[crossing]]` tables, else (None, cfg.vehicle)."""
    if cfg.crossings:
        return tuple((c.name, c.vehicle) for c in cfg.crossings)
    return ((None, cfg.vehicle),)


def window(cfg: Config, vehicle: Vehicle) -> float:
    """The recording's end on the data's clock: entry_time + T [s]."""
    return vehicle.entry_time + vehicle.duration(cfg.beam.length)


def layout(cfg: Config, vehicle: Vehicle, seed) -> Measurements:
    """Where and when the sensors read over [0, entry_time + T] (values zero); the same points as
    `data.synthetic.sample_layout` when entry_time = 0."""
    return layout_over(cfg, window(cfg, vehicle), np.random.default_rng(seed))


def simulate_crossing(
    cfg: Config,
    vehicle: Vehicle,
    road_seed,
    settings: VBISettings | None = None,
    beam: SimBeam | None = None,
) -> Solved:
    """Solve one crossing of `vehicle` over `cfg.beam` on a road drawn from `road_seed` (ISO 8608,
    `cfg.road.roughness`) covering the approach and the span."""
    s = settings or VBISettings()
    beam = beam or SimBeam(cfg.beam, s.n_elements)
    approach = cfg.road.approach
    lead = approach + float(vehicle.offsets.max())
    if cfg.road.roughness > 0.0:
        road = iso8608_road(
            cfg.road.roughness, -lead - 1.0, lead + cfg.beam.length + 2.0, road_seed
        )
    else:
        road = flat_road()
    t0 = vehicle.entry_time
    return solve(
        beam, vehicle, road, t0, t0 + vehicle.duration(cfg.beam.length), s.n_steps, approach,
        s.rho_inf,
    )  # fmt: skip


def _scaled(vehicle: Vehicle, factor: float) -> Vehicle:
    if factor == 1.0:
        return vehicle
    axles = tuple(Axle(a.load * factor, a.offset) for a in vehicle.axles)
    return replace(vehicle, axles=axles)


def _sub(seed, name: str, index: int) -> np.random.SeedSequence:
    """The index-th child of the named stream `name` (one not registered in `seeding.STREAMS`)."""
    ss = _stream(seed, name)
    return np.random.SeedSequence(ss.entropy, spawn_key=tuple(ss.spawn_key) + (int(index),))


def simulate(
    cfg: Config,
    snr_db: float | None,
    seed: int | np.random.SeedSequence = 0,
    settings: VBISettings | None = None,
) -> Measurements:
    """A synthetic measurement file of every crossing of `cfg` made by the independent simulator.

    Streams of the root seed: crossing i's points are `seeding.child(seed, "points", i)` (the "points"
    stream itself for a single crossing), its road "road"/i and its true load factor "load_factor"
    (single crossing, as `data.synthetic`) or "load_factor"/i; the noise is the "noise" stream."""
    s = settings or VBISettings()
    beam = SimBeam(cfg.beam, s.n_elements)
    named = bool(cfg.crossings)
    parts, names = [], []
    for i, (name, vehicle) in enumerate(crossings_of(cfg)):
        if named:
            pts, lf_seed = seeding.child(seed, "points", i), _sub(seed, "load_factor", i)
        else:
            pts, lf_seed = seeding.stream(seed, "points"), seed
        road_seed = _sub(seed, "road", i)
        lf = 1.0 if vehicle.load_rel_sd == 0.0 else draw_load_factor(vehicle.load_rel_sd, lf_seed)
        lay = layout(cfg, vehicle, pts)
        solved = simulate_crossing(cfg, _scaled(vehicle, lf), road_seed, s, beam)
        a_u, a_xx = lay.weights
        parts.append((lay, solved.sample(lay.x, lay.t, a_u, a_xx)))
        names.append(name)
    x = np.concatenate([p[0].x for p in parts])
    t = np.concatenate([p[0].t for p in parts])
    kind = np.concatenate([p[0].kind for p in parts])
    y = np.concatenate([p[0].y for p in parts])
    sensor = np.concatenate([p[0].sensor for p in parts])
    vt = np.concatenate([p[1] for p in parts])
    sigma = sigma_for_snr(vt, snr_db)
    z = seeding.rng(seed, "noise").standard_normal(vt.size)
    noise = np.empty_like(vt)
    start = 0
    for lay, _ in parts:
        sl = slice(start, start + len(lay))
        noise[sl] = ar1_noise(z[sl], lay, cfg.data.noise_ar1)
        start += len(lay)
    crossing = None
    if named:
        crossing = np.concatenate(
            [np.full(len(p[0]), n) for p, n in zip(parts, names, strict=True)]
        ).astype(str)
    return Measurements(x, t, vt + noise * sigma, kind, y, sensor, vt, crossing)
