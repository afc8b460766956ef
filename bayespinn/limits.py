"""What the model and the machine can carry: ranges for inputs that are well-typed but outside physical
sense, checked when a configuration is built (`Config.__post_init__` calls `check_limits`), so a typo
costs one line naming the field and the range (exit 2), not a hung terminal or a meaningless file.

Every range follows from the model's assumptions or from a budget of the machine, with the girder at hand:

* **Samples** (`[data] n_points`; for strain, gauges x crossing duration x `sample_rate`). What a run
  holds per sample: the PINN methods train on every sample at every step and keep each hidden layer's
  values and gradients for it, `ENSEMBLE_MEMBERS` (5) x `PINN_WIDTH` (64) x `PINN_DEPTH` (5) x 2 float64
  = 25.6 kB; the fit check's bootstrap chunk (256 replicates) and the posterior predictive (200 draws)
  hold less. A laptop that should stay usable gives that `MEMORY_BUDGET` (1 GiB), so n <= 1 GiB /
  25.6 kB = 41 943; the PINNs' time, linear in n too, then stays within hours on two cores. At least
  `MIN_SAMPLES_PER_GAUGE` (10) samples per gauge: an influence line sampled n times over the crossing
  misses its peak by at most about 1/n of it, so fewer than 10 samples say nothing within 10 %.
* **Sample rate** (strain): at most one sample per time step of the finite-element reference, n_steps /
  T (its 12 000 steps over the crossing): faster samples only interpolate between steps.
* **Crossing duration** T = (span + last axle offset) / speed, hence **speed**: the time integration
  takes `FE_STEPS` steps over the crossing and needs `STEPS_PER_PERIOD` (20) steps per period of the
  girder's first mode T1 (Newmark's average-acceleration rule then lengthens that period by about
  (pi / 20)^2 / 12 = 0.2 %), so T <= 12 000 x T1 / 20 = 600 T1; and the girder responds to a load only
  when the load stays on it for at least half a period, T >= T1 / 2 (a faster "crossing" is an impulse
  the data cannot tell EI from). T1 = 2 L^2 / pi x sqrt(mu / EI), the pinned uniform girder's first
  period with the configured EI, mass per length and span: those three enter every speed range.
* **Span and depth**: Euler-Bernoulli beam theory neglects shear deformation, which adds
  pi^2 E I / (kappa G A L^2) to the first mode's deflection. Even for the least shear-flexible section, a
  solid rectangle (I / A = d^2 / 12, kappa = 5/6, E / G = 2.6), that is 2.6 (d / L)^2: over 10 % below a
  span-to-depth ratio of `MIN_SLENDERNESS` (5), so depth <= span / 5 (I-girders need more).
* **EI and mass** (linear theory): the model is linear, which holds while deflections stay small against
  the span: the axles' static midspan deflection sum(P) L^3 / (48 EI) (every axle at midspan, an
  overestimate) and the self-weight's 5 mu g L^4 / (384 EI) each at most L / `MAX_DEFLECTION_RATIO`
  (20). The terms small-deflection theory drops are of order (w / L)^2, 0.25 % at L / 20: below the
  noise of any recording. (Serviceability limits such as L / 800 are design rules, not where the model
  fails, and bridges under test can be more flexible.) Hence a lower bound on EI and an upper bound on
  the mass per length.
* **Frequencies and damping ratios**: a sprung axle's bounce frequency is resolved by the time
  integration only up to n_steps / (20 T) (the same rule as the girder's mode); a damping ratio is in
  [0, 1) (an underdamped oscillator, which the modal solution assumes).

Each crossing of a multi-crossing configuration is checked as its own vehicle.
"""

from __future__ import annotations

import math

from .errors import InputError

#: bytes a run's per-sample arrays may take together
MEMORY_BUDGET = 2**30
#: the PINN's per-sample state: ensemble members (`--members` default), hidden width and depth
#: (`pinn.settings.TrainSettings` defaults; a test keeps them equal), values and gradients
ENSEMBLE_MEMBERS, PINN_WIDTH, PINN_DEPTH = 5, 64, 5
BYTES_PER_SAMPLE = ENSEMBLE_MEMBERS * PINN_WIDTH * PINN_DEPTH * 2 * 8
#: the most samples a run takes
MAX_SAMPLES = MEMORY_BUDGET // BYTES_PER_SAMPLE
#: fewest samples per strain gauge over a crossing (influence-line peak within 10 %)
MIN_SAMPLES_PER_GAUGE = 10
#: time steps of the finite-element reference over a crossing (`physics.fem.FESettings.n_steps`)
FE_STEPS = 12000
#: time steps per period the integration needs to follow a mode
STEPS_PER_PERIOD = 20
#: span-to-depth ratio below which shear deformation exceeds 10 % (Euler-Bernoulli's validity)
MIN_SLENDERNESS = 5.0
#: deflections at most span / this (linear theory)
MAX_DEFLECTION_RATIO = 20.0
G = 9.81  # m/s^2


def first_period(beam) -> float:
    """T1 [s]: the first natural period of the pinned uniform girder with the beam's EI, mu and L."""
    return 2.0 * beam.length**2 / math.pi * math.sqrt(beam.mass_per_length / beam.EI)


def speed_range(beam, vehicle) -> tuple[float, float]:
    """(lowest, highest) speed [m/s] whose crossing the model carries (module docstring)."""
    travel = beam.length + float(vehicle.offsets.max())
    T1 = first_period(beam)
    return travel / (FE_STEPS * T1 / STEPS_PER_PERIOD), travel / (T1 / 2.0)


def _memory_reason() -> str:
    return (
        f"the PINN methods hold {BYTES_PER_SAMPLE / 1e3:.1f} kB per sample, "
        f"{MEMORY_BUDGET // 2**20} MiB at that count"
    )


def _g(v: float) -> str:
    return f"{v:.3g}"


def check_vehicle(beam, vehicle, where: str = "vehicle") -> float:
    """The speed, the crossing duration and a sprung axle's frequency; returns the duration T [s]."""
    lo, hi = speed_range(beam, vehicle)
    T1 = first_period(beam)
    if not lo <= vehicle.speed <= hi:
        T = vehicle.duration(beam.length)
        raise InputError(
            f"{where}.speed",
            vehicle.speed,
            f"a speed in [{_g(lo)}, {_g(hi)}] m/s for this girder: the crossing (now {_g(T)} s) must "
            f"last between half the first natural period ({_g(T1 / 2)} s, from beam.EI, "
            f"mass_per_length and length) and the {_g(FE_STEPS * T1 / STEPS_PER_PERIOD)} s that "
            f"{FE_STEPS} time steps resolve at {STEPS_PER_PERIOD} steps per period",
        )
    T = vehicle.duration(beam.length)
    f_max = FE_STEPS / (STEPS_PER_PERIOD * T)
    if getattr(vehicle, "model", "forces") == "sprung":
        f = float(getattr(vehicle, "body_frequency", 0.0))
        if not 0.0 < f <= f_max:
            raise InputError(
                f"{where}.body_frequency",
                f,
                f"a frequency in (0, {_g(f_max)}] Hz: what {FE_STEPS} time steps over this "
                f"{_g(T)} s crossing resolve at {STEPS_PER_PERIOD} steps per period",
            )
        z = float(getattr(vehicle, "body_damping", 0.0))
        if not 0.0 <= z < 1.0:
            raise InputError(f"{where}.body_damping", z, "a damping ratio in [0, 1)")
    return T


def check_limits(cfg) -> None:
    """InputError naming the first field of `cfg` outside what the model and the machine carry."""
    beam = cfg.beam
    L = beam.length
    if beam.section_depth > L / MIN_SLENDERNESS:
        raise InputError(
            "beam.section_depth",
            beam.section_depth,
            f"a depth <= {_g(L / MIN_SLENDERNESS)} m (span / {MIN_SLENDERNESS:g}: below that "
            "slenderness Euler-Bernoulli theory misses over 10 % of the deflection to shear)",
        )
    if not 0.0 <= beam.damping_ratio < 1.0:
        raise InputError("beam.damping_ratio", beam.damping_ratio, "a damping ratio in [0, 1)")
    EI = min((beam.EI, *beam.EI_profile))
    vehicles = [("vehicle", cfg.vehicle)] + [
        (f"crossing {c.name}", c.vehicle) for c in getattr(cfg, "crossings", ())
    ]
    load = max(float(v.loads.sum()) for _, v in vehicles)
    ei_min = MAX_DEFLECTION_RATIO * load * L**2 / 48.0
    if EI < ei_min:
        raise InputError(
            "beam.EI",
            EI,
            f"EI >= {_g(ei_min)} N m^2: the axles' static deflection sum(P) L^3 / (48 EI) must stay "
            f"below span / {MAX_DEFLECTION_RATIO:g}, where linear beam theory holds",
        )
    mu_max = 384.0 * EI / (5.0 * G * L**3 * MAX_DEFLECTION_RATIO)
    if beam.mass_per_length > mu_max:
        raise InputError(
            "beam.mass_per_length",
            beam.mass_per_length,
            f"a mass <= {_g(mu_max)} kg/m: the self-weight's deflection 5 mu g L^4 / (384 EI) must "
            f"stay below span / {MAX_DEFLECTION_RATIO:g}, where linear beam theory holds",
        )
    durations = [check_vehicle(beam, v, where) for where, v in vehicles]
    n = cfg.data.n_points
    if cfg.case == "deflection" and n > MAX_SAMPLES:
        raise InputError(
            "data.n_points",
            n,
            f"an integer in [2, {MAX_SAMPLES}]: {_memory_reason()}",
        )
    if cfg.case == "strain":
        T = max(durations)
        rate = cfg.data.sample_rate
        lo, hi = MIN_SAMPLES_PER_GAUGE / min(durations), FE_STEPS / T
        if not lo <= rate <= hi:
            raise InputError(
                "data.sample_rate",
                rate,
                f"a rate in [{_g(lo)}, {_g(hi)}] Hz: at least {MIN_SAMPLES_PER_GAUGE} samples per gauge "
                f"over the crossing, at most one per time step of the {FE_STEPS}-step reference",
            )
        gauges = len(cfg.sensors)
        total = gauges * sum(int(math.floor(t * rate)) + 1 for t in durations)
        if total > MAX_SAMPLES:
            raise InputError(
                "data.sample_rate",
                rate,
                f"a rate giving at most {MAX_SAMPLES} samples ({gauges} gauges x crossing at "
                f"{_g(rate)} Hz give {total}): {_memory_reason()}",
            )
