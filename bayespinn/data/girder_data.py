"""Synthetic measurements of a real girder (segment-wise EI, bearing springs, an uncertain axle load).

The truth comes from time integration of the girder's Hermite finite-element model
(`physics.girder.GirderFE.solve`, Newmark average acceleration) with as many steps as the existing FE
truth (`physics.fem.FESettings`: 96 elements, 12 000 steps over the crossing), sampled at a layout's
points with the layout's weights (deflection: u; strain: -y u_xx). White Gaussian noise is added at
snr_db exactly as `data.synthetic` defines it: sigma from `sigma_for_snr` over all samples of the
file, the noise from the seed's "noise" stream, so a uniform pinned girder gets the same noise
vector as `synthetic.simulate` with the same layout and seed.

Layouts come from `synthetic.sample_layout` with a `Config` that carries the girder's geometry
(`layout_config`): random (x, t) deflection points or strain gauges sampled at a rate.

The true common axle-load factor of a crossing (`draw_load_factor`) is *normal*, 1 + load_rel_sd z
with z ~ N(0, 1), truncated to positive values (by redrawing; never needed for load_rel_sd <= 0.2,
where a non-positive draw has probability below 3e-7); `uq.girder_posterior` uses the same truncated
normal as the prior of the inferred load factor.
"""

from __future__ import annotations

import numpy as np

from .. import seeding
from ..config import Beam, Config, DataSpec, Sensor, Vehicle, _check_number
from ..errors import InputError
from ..physics.fem import FESettings
from ..physics.girder import Girder, GirderFE
from .measurements import Measurements
from .noise import (  # noqa: F401 (re-exported)
    LOAD_REL_SD_MAX,
    check_load_rel_sd,
    draw_load_factor,
    sigma_for_snr,
)


def field_truth(cfg: Config, x: np.ndarray) -> dict:
    """The truth of a smooth-field analysis (`[model] EI_field = "smooth"`) of the girder `cfg.beam`
    describes: `EI` (L / integral dx / EI) and `EI_x` {"x", "EI"}, the true EI at the points x [m] (the
    summary's `EI_x` points; at a segment edge, the segment to the right)."""
    b = cfg.beam
    girder = Girder.from_beam(b, b.segments, b.rotational_stiffness)
    x = np.asarray(x, float)
    return {"EI": equivalent_EI(girder), "EI_x": {"x": x.tolist(), "EI": girder.ei_at(x).tolist()}}


def equivalent_EI(girder: Girder) -> float:
    """The span-averaged flexibility's equivalent L / integral dx / EI [N m^2] (equal segments:
    the harmonic mean of the segment values)."""
    ei = np.asarray(girder.EI, float)
    return float(ei.size / np.sum(1.0 / ei))


def layout_config(
    girder: Girder,
    vehicle: Vehicle,
    case: str = "deflection",
    *,
    n_points: int = 100,
    sample_rate: float = 200.0,
    sensors: tuple[Sensor, ...] = (),
) -> Config:
    """A `Config` with the girder's length, mass, depth and damping (EI: `equivalent_EI`) and the
    vehicle, for `synthetic.sample_layout`: `n_points` random deflection points, or the strain
    gauges (default: the paper's S1-S4 layout scaled to the span and depth) at `sample_rate` Hz."""
    if not isinstance(girder, Girder):
        raise InputError("girder", girder, "a Girder")
    if not isinstance(vehicle, Vehicle):
        raise InputError("vehicle", vehicle, "a Vehicle")
    beam = Beam(
        length=girder.length,
        EI=equivalent_EI(girder),
        mass_per_length=girder.mass_per_length,
        section_depth=girder.section_depth,
        damping_ratio=girder.damping_ratio,
    )
    data = DataSpec(n_points=n_points, sample_rate=sample_rate, sensors=tuple(sensors))
    return Config(case=case, beam=beam, vehicle=vehicle, data=data)


def simulate_girder(
    girder: Girder,
    vehicle: Vehicle,
    layout: Measurements,
    snr_db: float | None,
    seed: int | np.random.SeedSequence = 0,
    *,
    load_factor: float = 1.0,
    n_steps: int = FESettings().n_steps,
    n_elements: int = FESettings().n_elements,
) -> Measurements:
    """Noisy measurements of `girder` under `vehicle` (every axle load times `load_factor`) at the
    layout's points.

    Parameters
    ----------
    girder : the true girder (segment EI, bearing springs).
    vehicle : the stated axles; the true loads are `load_factor` times them.
    layout : where and when (x, t), and what (kind, y): e.g. `synthetic.sample_layout(layout_config(...))`.
    snr_db : SNR in dB over all samples (`synthetic.sigma_for_snr`); None: clean.
    seed : root seed; the noise is its "noise" stream, as in `synthetic.simulate`.
    load_factor : the true common axle-load factor (> 0).
    n_steps, n_elements : Newmark steps over [0, max(T, max t)] and FE elements.

    Returns
    -------
    Measurements with value (noisy) and value_true (noise-free).
    """
    if not isinstance(girder, Girder):
        raise InputError("girder", girder, "a Girder")
    if not isinstance(vehicle, Vehicle):
        raise InputError("vehicle", vehicle, "a Vehicle")
    if not isinstance(layout, Measurements) or len(layout) == 0:
        raise InputError("layout", layout, "a non-empty Measurements layout")
    if snr_db is not None:
        snr_db = _check_number("--snr", snr_db, positive=True)
    lf = _check_number("load_factor", load_factor, positive=True)
    x = np.asarray(layout.x, float)
    if x.min() < 0 or x.max() > girder.length:
        raise InputError("layout.x", [float(x.min()), float(x.max())], f"[0, {girder.length}] m")
    t = np.asarray(layout.t, float)
    if t.min() < 0:
        raise InputError("layout.t", float(t.min()), "times >= 0 s")
    T = vehicle.duration(girder.length)
    t_end = max(T, float(t.max()))
    resp = GirderFE(girder, n_elements).solve(vehicle, t_end, n_steps, load_factor=lf)
    a_u, a_xx = layout.weights
    vt = resp.sample(x, t, a_u, a_xx)
    sigma = sigma_for_snr(vt, snr_db)
    noise = seeding.rng(seed, "noise").standard_normal(vt.size) * sigma
    return Measurements(x, t, vt + noise, layout.kind, layout.y, layout.sensor, vt)


def girder_truth(girder: Girder, n_segments: int | None = None, load_factor: float = 1.0) -> dict:
    """The contract's `truth` entries of a synthetic girder, for an analysis with `n_segments` equal
    segments (default: the girder's own): `EI` (L / integral dx / EI), `EI_segments` (each analysis
    segment's own L_s / integral_s dx / EI), `rotational_stiffness` [left, right] (math.inf: clamped)
    and `load_factor`. Values are SI floats (an infinite spring stays math.inf)."""
    if not isinstance(girder, Girder):
        raise InputError("girder", girder, "a Girder")
    S = girder.n_segments if n_segments is None else n_segments
    if isinstance(S, bool) or not isinstance(S, int | np.integer) or S < 1:
        raise InputError("model.EI_segments", n_segments, "an integer >= 1")
    lf = _check_number("load_factor", load_factor, positive=True)
    # exact flexibility integral per analysis segment: overlap lengths with the true segments
    true_edges = girder.segment_edges()
    edges = np.linspace(0.0, girder.length, int(S) + 1)
    inv = 1.0 / np.asarray(girder.EI, float)
    segs = []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        overlap = np.clip(np.minimum(true_edges[1:], b) - np.maximum(true_edges[:-1], a), 0.0, None)
        segs.append(float((b - a) / np.sum(overlap * inv)))
    return {
        "EI": equivalent_EI(girder),
        "EI_segments": segs,
        "rotational_stiffness": [float(k) for k in girder.rotational_stiffness],
        "load_factor": lf,
    }
