"""Configuration: frozen, self-validating dataclasses and their resolution.

Resolution order is *preset < TOML file < flags*. The preset is the Exeter bascule bridge east girder of
the paper (Table 3) with the vehicle of the chosen case study. Every value is SI: metres, seconds,
newtons, kilograms, EI in N m^2.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from .errors import InputError

CASES = ("deflection", "strain")
SUPPORTS = ("pinned", "springs")
LOAD_FACTOR = ("auto", "off")
NOISE_MODELS = ("iid", "ar1")
DAMPING_MODELS = ("known", "inferred")
AXLE_FORCE_MODELS = ("constant", "fluctuating")
EI_FIELDS = ("segments", "smooth")
#: the fields added for real crossings to [model] and [prior], at their defaults (left out of `identity`)
_CROSSING_MODEL_DEFAULTS = {"damping": "known", "axle_forces": "constant", "EI_field": "segments"}
_CROSSING_PRIOR_DEFAULTS = {"damping_median": 0.01, "damping_log_sd": 0.7}
#: how `simulate` models each axle: constant moving forces, or a sprung mass on a spring-damper
VEHICLE_MODELS = ("forces", "sprung")
#: ISO 8608 road classes: the geometric-mean Gd(n0) of each class [m^3] at n0 = 0.1 cycles/m
ROAD_CLASSES = {"A": 16e-6, "B": 64e-6, "C": 256e-6, "D": 1024e-6}
#: the largest relative sd of a stated speed that the analysis accepts
MAX_SPEED_SD = 0.2
#: the largest relative sd of the axle loads: beyond it a normal load factor would go negative too often
MAX_LOAD_REL_SD = 0.2

#: Exeter bascule girder (paper Table 3): E = 205 GPa, I = 50.42e8 mm^4.
EXETER_EI = 205e9 * 50.42e8 * 1e-12  # = 1.03361e9 N m^2
EXETER_SPEED = 7.115  # m/s, from 17.28 m + 6.50 m crossed in 3.342 s
#: Four-axle test truck (paper section 3.1), 55 % carried by the east girder.
TRUCK_AXLE_LOADS = (67.2e3, 67.2e3, 89.8e3, 89.8e3)  # N, whole truck
TRUCK_SPACINGS = (2.00, 3.10, 1.40)  # m
EAST_GIRDER_SHARE = 0.55


def _check_number(name: str, value: Any, *, positive: bool = False, nonneg: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
        raise InputError(name, value, "a number")
    v = float(value)
    if not math.isfinite(v):
        raise InputError(name, value, "a finite number")
    if positive and v <= 0:
        raise InputError(name, value, "a finite number > 0")
    if nonneg and v < 0:
        raise InputError(name, value, "a finite number >= 0")
    return v


def _check_int(name: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise InputError(name, value, f"an integer >= {minimum}")
    if value < minimum:
        raise InputError(name, value, f"an integer >= {minimum}")
    return int(value)


def equivalent_ei(profile) -> float:
    """The span-averaged flexibility's equivalent of EI over equal segments: n / sum(1 / EI_i) [N m^2]."""
    p = np.asarray(profile, float)
    return float(p.size / np.sum(1.0 / p))


def _spring(name: str, value: Any) -> float:
    if isinstance(value, str):
        if value.strip().lower() == "fixed":
            return math.inf
        raise InputError(name, value, "a number of N m/rad >= 0 or 'fixed'")
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
        raise InputError(name, value, "a number of N m/rad >= 0 or 'fixed'")
    v = float(value)
    if math.isnan(v) or v < 0:
        raise InputError(name, value, "a number of N m/rad >= 0 or 'fixed'")
    return v


@dataclass(frozen=True)
class Beam:
    """An Euler-Bernoulli girder: simply supported and uniform by default.

    Attributes
    ----------
    length : float, span L [m]
    EI : float, flexural rigidity [N m^2] (the truth for synthetic data). Given as a list, EI per equal
        segment from the left support: it is then kept in `EI_profile`, and EI itself is the span-averaged
        flexibility's equivalent n / sum(1 / EI_i)
    mass_per_length : float, mu [kg/m]
    section_depth : float, overall depth [m]; flange fibres sit at y = -depth/2 (top), +depth/2 (bottom)
    damping_ratio : float, modal damping ratio zeta [-], 0 by default as in the paper
    rotational_stiffness : (left, right) rotational spring at each support [N m/rad]; 0 = pin (default),
        math.inf (TOML "fixed") = clamped
    EI_profile : tuple of segment EIs [N m^2], empty for a uniform girder (set through `EI`)
    """

    length: float = 17.28
    EI: float = EXETER_EI
    mass_per_length: float = 289.0
    section_depth: float = 0.9266
    damping_ratio: float = 0.0
    rotational_stiffness: tuple[float, float] = (0.0, 0.0)
    EI_profile: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        for name in ("length", "mass_per_length", "section_depth"):
            object.__setattr__(
                self, name, _check_number(f"beam.{name}", getattr(self, name), positive=True)
            )
        ei = self.EI
        if isinstance(ei, list | tuple | np.ndarray):
            if len(ei) < 1:
                raise InputError("beam.EI", list(ei), "a number > 0 or a non-empty list of them")
            prof = tuple(_check_number(f"beam.EI[{i}]", v, positive=True) for i, v in enumerate(ei))
            object.__setattr__(self, "EI_profile", () if len(prof) == 1 else prof)
            object.__setattr__(self, "EI", prof[0] if len(prof) == 1 else equivalent_ei(prof))
        else:
            v = _check_number("beam.EI", ei, positive=True)
            prof = tuple(
                _check_number(f"beam.EI[{i}]", p, positive=True)
                for i, p in enumerate(self.EI_profile)
            )
            if len(prof) == 1:
                prof = ()
            if prof and not math.isclose(v, equivalent_ei(prof), rel_tol=1e-12):
                raise InputError(
                    "beam.EI",
                    ei,
                    f"the segments' equivalent {equivalent_ei(prof):.6g} (a girder with EI per segment "
                    "takes a list for EI)",
                )
            object.__setattr__(self, "EI", v)
            object.__setattr__(self, "EI_profile", prof)
        z = _check_number("beam.damping_ratio", self.damping_ratio, nonneg=True)
        if z >= 1:
            raise InputError("beam.damping_ratio", self.damping_ratio, "a number in [0, 1)")
        object.__setattr__(self, "damping_ratio", z)
        k = self.rotational_stiffness
        if isinstance(k, str) or not isinstance(k, list | tuple) or len(k) != 2:
            raise InputError(
                "beam.rotational_stiffness", k, "a list [left, right] of N m/rad >= 0 or 'fixed'"
            )
        object.__setattr__(
            self,
            "rotational_stiffness",
            tuple(_spring(f"beam.rotational_stiffness[{i}]", v) for i, v in enumerate(k)),
        )

    @property
    def segments(self) -> tuple[float, ...]:
        """EI per equal segment [N m^2] (one value for a uniform girder)."""
        return self.EI_profile or (self.EI,)

    @property
    def ideal(self) -> bool:
        """Uniform EI and pinned supports: the girder the closed-form modal model and the PINN describe."""
        return not self.EI_profile and self.rotational_stiffness == (0.0, 0.0)

    def natural_frequency(self, n: int = 1, EI: float | None = None) -> float:
        """Circular natural frequency of mode n [rad/s] (of the uniform, pinned girder)."""
        ei = self.EI if EI is None else EI
        return (n * math.pi / self.length) ** 2 * math.sqrt(ei / self.mass_per_length)


@dataclass(frozen=True)
class Axle:
    """One axle: load [N] and offset [m] behind the first axle."""

    load: float
    offset: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "load", _check_number("vehicle.axles.load", self.load, positive=True)
        )
        object.__setattr__(
            self, "offset", _check_number("vehicle.axles.offset", self.offset, nonneg=True)
        )


@dataclass(frozen=True)
class Vehicle:
    """Axles crossing at constant speed; the first axle enters the span at `entry_time` on the data's
    clock (0 by default: the clock starts with the entry).

    model : how `simulate` makes the axle forces: "forces" (constant moving forces) or "sprung" (each
        axle a body mass on a spring-damper over a massless contact point, static load = the axle load)
    body_frequency : bounce frequency of a sprung axle [Hz]
    body_damping : damping ratio of its suspension [-]
    speed_sd : relative sd of the stated speed; > 0: the analysis infers the speed
    entry_time : time on the data's clock when the first axle enters the span [s]
    entry_time_sd : sd of the stated entry time [s]; > 0: the analysis infers it
    """

    speed: float = EXETER_SPEED
    axles: tuple[Axle, ...] = (Axle(37000.0, 0.0),)
    #: relative sd of the true axle loads around the stated ones (one common factor); 0 = known exactly
    load_rel_sd: float = 0.0
    model: str = "forces"
    body_frequency: float = 2.5
    body_damping: float = 0.1
    speed_sd: float = 0.0
    entry_time: float = 0.0
    entry_time_sd: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "speed", _check_number("vehicle.speed", self.speed, positive=True))
        if self.model not in VEHICLE_MODELS:
            raise InputError(
                "vehicle.model", self.model, "one of " + ", ".join(map(repr, VEHICLE_MODELS))
            )
        object.__setattr__(
            self,
            "body_frequency",
            _check_number("vehicle.body_frequency", self.body_frequency, positive=True),
        )
        zb = _check_number("vehicle.body_damping", self.body_damping, nonneg=True)
        if zb >= 1:
            raise InputError("vehicle.body_damping", self.body_damping, "a number in [0, 1)")
        object.__setattr__(self, "body_damping", zb)
        ss = _check_number("vehicle.speed_sd", self.speed_sd, nonneg=True)
        if ss > MAX_SPEED_SD:
            raise InputError("vehicle.speed_sd", self.speed_sd, f"a number in [0, {MAX_SPEED_SD}]")
        object.__setattr__(self, "speed_sd", ss)
        for name in ("entry_time", "entry_time_sd"):
            object.__setattr__(
                self, name, _check_number(f"vehicle.{name}", getattr(self, name), nonneg=True)
            )
        r = _check_number("vehicle.load_rel_sd", self.load_rel_sd, nonneg=True)
        if r > MAX_LOAD_REL_SD:
            raise InputError(
                "vehicle.load_rel_sd", self.load_rel_sd, f"a number in [0, {MAX_LOAD_REL_SD}]"
            )
        object.__setattr__(self, "load_rel_sd", r)
        axles = tuple(self.axles)
        if not axles:
            raise InputError("vehicle.axles", list(axles), "at least one axle")
        if not all(isinstance(a, Axle) for a in axles):
            raise InputError("vehicle.axles", axles, "a list of {load, offset} tables")
        object.__setattr__(self, "axles", axles)

    @property
    def loads(self) -> np.ndarray:
        """Axle loads [N], shape (J,)."""
        return np.array([a.load for a in self.axles], dtype=float)

    @property
    def offsets(self) -> np.ndarray:
        """Axle offsets behind the first axle [m], shape (J,)."""
        return np.array([a.offset for a in self.axles], dtype=float)

    @property
    def delays(self) -> np.ndarray:
        """Time at which each axle enters the span [s], shape (J,)."""
        return self.offsets / self.speed

    def duration(self, length: float) -> float:
        """T: first axle entering to last axle leaving [s]."""
        return (length + float(self.offsets.max())) / self.speed

    @property
    def realistic(self) -> bool:
        """Whether this vehicle needs the independent vehicle-bridge simulator (`bayespinn.vbi`): sprung
        axles, or a recording that starts before the entry."""
        return self.model != "forces" or self.entry_time > 0.0


#: the Vehicle fields added for real crossings, with their defaults (left out of `Config.identity`)
_CROSSING_DEFAULTS = {
    "model": "forces",
    "body_frequency": 2.5,
    "body_damping": 0.1,
    "speed_sd": 0.0,
    "entry_time": 0.0,
    "entry_time_sd": 0.0,
}


def _roughness(value: Any) -> float:
    if isinstance(value, str):
        key = value.strip().upper()
        if key in ROAD_CLASSES:
            return ROAD_CLASSES[key]
        raise InputError(
            "road.roughness", value, "Gd(n0) in m^3 >= 0 or an ISO 8608 class 'A', 'B', 'C', 'D'"
        )
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
        raise InputError(
            "road.roughness", value, "Gd(n0) in m^3 >= 0 or an ISO 8608 class 'A', 'B', 'C', 'D'"
        )
    v = float(value)
    if not math.isfinite(v) or v < 0:
        raise InputError(
            "road.roughness", value, "Gd(n0) in m^3 >= 0 or an ISO 8608 class 'A', 'B', 'C', 'D'"
        )
    return v


@dataclass(frozen=True)
class Road:
    """The road surface `simulate` drives on (ISO 8608).

    roughness : Gd(n0) [m^3], the displacement PSD at n0 = 0.1 cycles/m (waviness 2); a class letter
        "A".."D" is stored as that class's geometric-mean value (16e-6, 64e-6, 256e-6, 1024e-6 m^3)
    approach : length of rough road before the span [m], so that a sprung vehicle arrives bouncing
    """

    roughness: float = 0.0
    approach: float = 30.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "roughness", _roughness(self.roughness))
        object.__setattr__(
            self, "approach", _check_number("road.approach", self.approach, nonneg=True)
        )


@dataclass(frozen=True)
class Crossing:
    """One crossing of a multi-crossing file: its name (the CSV's `crossing` column) and its vehicle."""

    name: str
    vehicle: Vehicle

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip() or "," in self.name:
            raise InputError("crossing.name", self.name, "a non-empty name without commas")
        if not isinstance(self.vehicle, Vehicle):
            raise InputError(f"crossing {self.name}.vehicle", self.vehicle, "a Vehicle")


@dataclass(frozen=True)
class Sensor:
    """A strain gauge: name, position along the span x [m], fibre distance y [m] (+ down)."""

    name: str
    x: float
    y: float


@dataclass(frozen=True)
class DataSpec:
    """How synthetic data are sampled.

    n_points : random (x, t) deflection samples (deflection case)
    sample_rate : strain time-series rate [Hz] (strain case)
    sensors : strain gauges; empty means the paper's S1-S4 layout for the beam
    """

    n_points: int = 100
    sample_rate: float = 200.0
    sensors: tuple[Sensor, ...] = ()
    #: AR(1) coefficient of the simulated noise between consecutive samples of one sensor (0: white)
    noise_ar1: float = 0.0

    def __post_init__(self) -> None:
        a = _check_number("data.noise_ar1", self.noise_ar1)
        if not -1.0 < a < 1.0:
            raise InputError("data.noise_ar1", self.noise_ar1, "a number in (-1, 1)")
        object.__setattr__(self, "noise_ar1", a)
        object.__setattr__(self, "n_points", _check_int("data.n_points", self.n_points, 2))
        object.__setattr__(
            self, "sample_rate", _check_number("data.sample_rate", self.sample_rate, positive=True)
        )
        object.__setattr__(self, "sensors", tuple(self.sensors))


@dataclass(frozen=True)
class PriorSpec:
    """Log-normal prior on EI: median [N m^2] and sd of log(EI); on each support's rotational stiffness:
    median [N m/rad] and sd of its log (with `model.supports = "springs"`)."""

    EI_median: float = 1.0e9
    EI_log_sd: float = 0.5
    k_median: float = 1.0e8
    k_log_sd: float = 2.0
    #: log-normal prior on the damping ratio (`model.damping = "inferred"`): measured damping of short
    #: steel and composite road bridges lies mostly between 0.5 % and 3 % of critical, so a median of 1 %
    #: with log-sd 0.7 puts 90 % of the prior on [0.32 %, 3.2 %] without excluding 0.2 % or 6 %
    damping_median: float = 0.01
    damping_log_sd: float = 0.7

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "EI_median", _check_number("prior.EI_median", self.EI_median, positive=True)
        )
        object.__setattr__(
            self, "EI_log_sd", _check_number("prior.EI_log_sd", self.EI_log_sd, positive=True)
        )
        zm = _check_number("prior.damping_median", self.damping_median, positive=True)
        if zm >= 1:
            raise InputError("prior.damping_median", self.damping_median, "a number in (0, 1)")
        object.__setattr__(self, "damping_median", zm)
        object.__setattr__(
            self,
            "damping_log_sd",
            _check_number("prior.damping_log_sd", self.damping_log_sd, positive=True),
        )
        for name in ("k_median", "k_log_sd"):
            object.__setattr__(
                self, name, _check_number(f"prior.{name}", getattr(self, name), positive=True)
            )


@dataclass(frozen=True)
class ModelSpec:
    """What the analysis infers, independent of the truth that `simulate` used.

    EI_segments : EI inferred per segment, n equal segments from the left support (1 = uniform EI)
    supports : "pinned", or "springs": a rotational stiffness at each support inferred
    load_factor : "auto" (infer a common axle-load factor when vehicle.load_rel_sd > 0) or "off"
    EI_nominal : the design EI [N m^2] that damage is judged against (None: the prior's EI_median)
    noise : "iid" (white Gaussian noise) or "ar1" (AR(1) per sensor series; its coefficient inferred)
    damping : "known" (the beam's damping_ratio) or "inferred" (prior `prior.damping_median`,
        `damping_log_sd`)
    axle_forces : "constant" (the stated axle loads) or "fluctuating" (each axle's dynamic force a
        Gaussian process in time, its scale and time scale inferred, integrated out)
    EI_field : "segments" (EI_segments equal segments) or "smooth" (EI(x) a smooth field)
    """

    EI_segments: int = 1
    supports: str = "pinned"
    load_factor: str = "auto"
    EI_nominal: float | None = None
    noise: str = "iid"
    damping: str = "known"
    axle_forces: str = "constant"
    EI_field: str = "segments"

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "EI_segments", _check_int("model.EI_segments", self.EI_segments, 1)
        )
        for name, allowed in (
            ("supports", SUPPORTS),
            ("load_factor", LOAD_FACTOR),
            ("noise", NOISE_MODELS),
            ("damping", DAMPING_MODELS),
            ("axle_forces", AXLE_FORCE_MODELS),
            ("EI_field", EI_FIELDS),
        ):
            if getattr(self, name) not in allowed:
                raise InputError(
                    f"model.{name}", getattr(self, name), "one of " + ", ".join(map(repr, allowed))
                )
        if self.EI_nominal is not None:
            object.__setattr__(
                self,
                "EI_nominal",
                _check_number("model.EI_nominal", self.EI_nominal, positive=True),
            )

    @property
    def ideal(self) -> bool:
        """Uniform EI, pinned supports, i.i.d. noise: the model every method describes."""
        return self.EI_segments == 1 and self.supports == "pinned" and self.noise == "iid"


@dataclass(frozen=True)
class Config:
    """Everything that defines a problem: the beam, the vehicle, the sampling and the prior."""

    case: str = "deflection"
    beam: Beam = field(default_factory=Beam)
    vehicle: Vehicle = field(default_factory=Vehicle)
    data: DataSpec = field(default_factory=DataSpec)
    prior: PriorSpec = field(default_factory=PriorSpec)
    model: ModelSpec = field(default_factory=ModelSpec)
    road: Road = field(default_factory=Road)
    #: several crossings in one file; empty: one crossing described by `vehicle`
    crossings: tuple[Crossing, ...] = ()

    def __post_init__(self) -> None:
        if self.case not in CASES:
            raise InputError("--case", self.case, "one of " + ", ".join(CASES))
        if not isinstance(self.road, Road):
            raise InputError("[road]", self.road, "a Road")
        cr = tuple(self.crossings)
        if not all(isinstance(c, Crossing) for c in cr):
            raise InputError("[[crossing]]", cr, "a list of crossing tables")
        names = [c.name for c in cr]
        if len(set(names)) != len(names):
            dup = sorted(n for n in names if names.count(n) > 1)[0]
            raise InputError("crossing.name", dup, "a name that no other crossing has")
        object.__setattr__(self, "crossings", cr)
        for s in self.sensors:
            if not 0.0 <= s.x <= self.beam.length:
                raise InputError(
                    f"data.sensors {s.name}.x", s.x, f"a position in [0, {self.beam.length}] m"
                )
        from .limits import check_limits

        check_limits(self)  # ranges the model and the machine carry (bayespinn.limits)

    @property
    def infers_load_factor(self) -> bool:
        """Whether the analysis infers a common axle-load factor (`model.load_factor`)."""
        return self.model.load_factor == "auto" and self.vehicle.load_rel_sd > 0

    @property
    def real_girder(self) -> bool:
        """Whether the analysis model is a real girder: EI per segment, springs at the supports or an
        inferred load factor (whatever the noise model). The PINN methods then fit the girder network
        (`uq.girder_pinn`) rather than the uniform, pinned one."""
        m = self.model
        return m.EI_segments > 1 or m.supports != "pinned" or self.infers_load_factor

    @property
    def ideal(self) -> bool:
        """The analysis model is a uniform, pinned girder under known loads with white noise."""
        return self.model.ideal and not self.infers_load_factor

    def identity(self) -> dict:
        """`dataclasses.asdict` of this configuration without the real-girder and noise fields at their
        defaults: what a configuration of the uniform, pinned, known-load, white-noise model was before
        those fields existed, so that fingerprints of studies made then still match."""
        from dataclasses import asdict

        d = asdict(self)
        if d["beam"]["rotational_stiffness"] == (0.0, 0.0):
            del d["beam"]["rotational_stiffness"]
        if not d["beam"]["EI_profile"]:
            del d["beam"]["EI_profile"]
        if d["vehicle"]["load_rel_sd"] == 0.0:
            del d["vehicle"]["load_rel_sd"]
        if d["data"]["noise_ar1"] == 0.0:
            del d["data"]["noise_ar1"]
        for k, default in (
            ("k_median", 1.0e8),
            ("k_log_sd", 2.0),
            *_CROSSING_PRIOR_DEFAULTS.items(),
        ):
            if d["prior"][k] == default:
                del d["prior"][k]
        if self.model == ModelSpec():
            del d["model"]
        else:
            for k, default in _CROSSING_MODEL_DEFAULTS.items():
                if d["model"][k] == default:
                    del d["model"][k]
        for k, default in _CROSSING_DEFAULTS.items():
            if d["vehicle"][k] == default:
                del d["vehicle"][k]
        if self.road == Road():
            del d["road"]
        if not self.crossings:
            del d["crossings"]
        return d

    @property
    def realistic(self) -> bool:
        """Whether `simulate` needs the independent vehicle-bridge simulator (`bayespinn.vbi`): sprung
        axles, a rough road, a recording that starts before the entry, or several crossings."""
        return (
            self.vehicle.realistic
            or self.road.roughness > 0.0
            or bool(self.crossings)
            or any(c.vehicle.realistic for c in self.crossings)
        )

    @property
    def duration(self) -> float:
        """T [s]: first axle in to last axle out."""
        return self.vehicle.duration(self.beam.length)

    @property
    def sensors(self) -> tuple[Sensor, ...]:
        """Strain gauges: the configured ones, else the paper's S1-S4 layout scaled to the span."""
        if self.data.sensors:
            return self.data.sensors
        L, h = self.beam.length, self.beam.section_depth / 2
        return (
            Sensor("S1", L / 3, -h),
            Sensor("S2", L / 2, -h),
            Sensor("S3", L / 3, +h),
            Sensor("S4", 2 * L / 3, +h),
        )

    def to_dict(self) -> dict:
        """Plain-dict form for manifests (SI units)."""
        return {
            "case": self.case,
            "beam": {
                **{
                    f.name: getattr(self.beam, f.name)
                    for f in fields(Beam)
                    if f.name not in ("EI_profile", "rotational_stiffness")
                },
                "EI": list(self.beam.EI_profile) if self.beam.EI_profile else self.beam.EI,
                "rotational_stiffness": [
                    "fixed" if math.isinf(k) else k for k in self.beam.rotational_stiffness
                ],
            },
            "vehicle": {
                "speed": self.vehicle.speed,
                "axles": [{"load": a.load, "offset": a.offset} for a in self.vehicle.axles],
                "load_rel_sd": self.vehicle.load_rel_sd,
                **_vehicle_extras(self.vehicle),
            },
            "data": {
                "n_points": self.data.n_points,
                "sample_rate": self.data.sample_rate,
                "sensors": [{"name": s.name, "x": s.x, "y": s.y} for s in self.sensors],
                "noise_ar1": self.data.noise_ar1,
            },
            "prior": {f.name: getattr(self.prior, f.name) for f in fields(PriorSpec)},
            "model": {f.name: getattr(self.model, f.name) for f in fields(ModelSpec)},
            **(
                {"road": {"roughness": self.road.roughness, "approach": self.road.approach}}
                if self.road != Road()
                else {}
            ),
            **(
                {
                    "crossings": [
                        {
                            "name": c.name,
                            "speed": c.vehicle.speed,
                            "axles": [
                                {"load": a.load, "offset": a.offset} for a in c.vehicle.axles
                            ],
                            "load_rel_sd": c.vehicle.load_rel_sd,
                            **_vehicle_extras(c.vehicle, everything=True),
                        }
                        for c in self.crossings
                    ]
                }
                if self.crossings
                else {}
            ),
        }


def _vehicle_extras(vehicle: Vehicle, everything: bool = False) -> dict:
    """The real-crossing fields of a vehicle for `Config.to_dict`: those off their defaults (all of them
    with `everything`), so manifests of configurations without them read as before."""
    return {
        k: getattr(vehicle, k)
        for k, default in _CROSSING_DEFAULTS.items()
        if everything or getattr(vehicle, k) != default
    }


def truck_vehicle(speed: float = EXETER_SPEED, share: float = EAST_GIRDER_SHARE) -> Vehicle:
    """The paper's four-axle test truck, the girder's share of each axle."""
    offsets = np.concatenate([[0.0], np.cumsum(TRUCK_SPACINGS)])
    return Vehicle(
        speed,
        tuple(Axle(share * p, float(o)) for p, o in zip(TRUCK_AXLE_LOADS, offsets, strict=True)),
    )


def preset(case: str = "deflection") -> Config:
    """The Exeter bascule bridge preset for a case study."""
    if case not in CASES:
        raise InputError("--case", case, "one of " + ", ".join(CASES))
    vehicle = Vehicle() if case == "deflection" else truck_vehicle()
    return Config(case=case, vehicle=vehicle)


_SECTIONS = {
    "beam": {f.name for f in fields(Beam)} - {"EI_profile"},
    "vehicle": {"speed", "axles", "load_rel_sd", *_CROSSING_DEFAULTS},
    "road": {f.name for f in fields(Road)},
    "crossing": {"name", "speed", "axles", "load_rel_sd", *_CROSSING_DEFAULTS},
    "data": {"n_points", "sample_rate", "sensors", "noise_ar1"},
    "prior": {f.name for f in fields(PriorSpec)},
    "model": {f.name for f in fields(ModelSpec)},
}


def _table(doc: dict, name: str) -> dict:
    t = doc.get(name, {})
    return _check_keys(t, name, f"[{name}]")


def _check_keys(t: Any, name: str, label: str) -> dict:
    if not isinstance(t, dict):
        raise InputError(label, t, "a TOML table")
    unknown = set(t) - _SECTIONS[name]
    if unknown:
        key = sorted(unknown)[0]
        raise InputError(
            f"{name}.{key}", t[key], "one of the keys " + ", ".join(sorted(_SECTIONS[name]))
        )
    return t


def _build(cls, name: str, base, values: dict):
    try:
        return replace(base, **values)
    except TypeError as exc:  # pragma: no cover - guarded by the key check above
        raise InputError(name, values, str(exc)) from None


def _axles(raw: Any) -> tuple[Axle, ...]:
    if not isinstance(raw, list) or not raw:
        raise InputError(
            "vehicle.axles", raw, "a non-empty list of { load = N, offset = m } tables"
        )
    out = []
    for i, a in enumerate(raw):
        if not isinstance(a, dict) or "load" not in a or set(a) - {"load", "offset"}:
            raise InputError(f"vehicle.axles[{i}]", a, "a table { load = N, offset = m }")
        load = _check_number(f"vehicle.axles[{i}].load", a["load"], positive=True)
        off = _check_number(f"vehicle.axles[{i}].offset", a.get("offset", 0.0), nonneg=True)
        out.append(Axle(load, off))
    if min(a.offset for a in out) != 0.0:
        raise InputError(
            "vehicle.axles", raw, "the first axle at offset 0 (offsets are behind the first axle)"
        )
    return tuple(out)


def _sensors(raw: Any) -> tuple[Sensor, ...]:
    if not isinstance(raw, list):
        raise InputError("data.sensors", raw, "a list of { name, x, y } tables")
    out = []
    for i, s in enumerate(raw):
        if not isinstance(s, dict) or set(s) != {"name", "x", "y"}:
            raise InputError(f"data.sensors[{i}]", s, "a table { name = 'S1', x = m, y = m }")
        out.append(
            Sensor(
                str(s["name"]),
                _check_number(f"data.sensors[{i}].x", s["x"]),
                _check_number(f"data.sensors[{i}].y", s["y"]),
            )
        )
    return tuple(out)


def load_toml(path: str | Path) -> dict:
    """Read a configuration TOML into a dict; bad files raise `InputError`."""
    p = Path(path)
    try:
        text = p.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise InputError("--config", str(path), "an existing TOML file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(
            "--config", str(path), f"a readable UTF-8 TOML file ({exc.__class__.__name__})"
        ) from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError("--config", str(path), f"valid TOML ({exc})") from None
    unknown = set(doc) - set(_SECTIONS)
    if unknown:
        key = sorted(unknown)[0]
        raise InputError(f"[{key}]", doc[key], "one of the tables " + ", ".join(sorted(_SECTIONS)))
    return doc


def resolve(case: str = "deflection", toml: str | Path | dict | None = None) -> Config:
    """Preset for `case`, overridden by a TOML file (path) or an already parsed dict."""
    cfg = preset(case)
    if toml is None:
        return cfg
    doc = load_toml(toml) if not isinstance(toml, dict) else toml
    beam_t = _table(doc, "beam")
    beam = _build(Beam, "beam", cfg.beam, beam_t)
    veh_t = dict(_table(doc, "vehicle"))
    if "axles" in veh_t:
        veh_t["axles"] = _axles(veh_t["axles"])
    vehicle = _build(Vehicle, "vehicle", cfg.vehicle, veh_t)
    data_t = dict(_table(doc, "data"))
    if "sensors" in data_t:
        data_t["sensors"] = _sensors(data_t["sensors"])
    data = _build(DataSpec, "data", cfg.data, data_t)
    prior = _build(PriorSpec, "prior", cfg.prior, _table(doc, "prior"))
    model = _build(ModelSpec, "model", cfg.model, _table(doc, "model"))
    road = _build(Road, "road", cfg.road, _table(doc, "road"))
    crossings = _crossings(doc.get("crossing", []), vehicle)
    return Config(
        case=case, beam=beam, vehicle=vehicle, data=data, prior=prior, model=model, road=road,
        crossings=crossings,
    )  # fmt: skip


def _crossings(raw: Any, vehicle: Vehicle) -> tuple[Crossing, ...]:
    """`[[crossing]]` tables: each crossing's full Vehicle, the keys it gives over `[vehicle]`'s."""
    if isinstance(raw, dict):
        raw = [raw]
    if not isinstance(raw, list):
        raise InputError("[[crossing]]", raw, "an array of crossing tables")
    out = []
    for i, t in enumerate(raw):
        t = dict(_check_keys(t, "crossing", f"[[crossing]] {i}"))
        name = t.pop("name", f"c{i}")
        if not isinstance(name, str):
            raise InputError(f"crossing[{i}].name", name, "a name (a string)")
        try:
            if "axles" in t:
                t["axles"] = _axles(t["axles"])
            out.append(Crossing(name, _build(Vehicle, f"crossing {name}", vehicle, t)))
        except InputError as exc:
            raise InputError(f"crossing {name}: {exc.field}", exc.value, exc.expected) from None
    return tuple(out)


def parse_snr(value: str | float | None, field_name: str = "--snr") -> float | None:
    """`clean` -> None (sigma = 0); otherwise a finite number of dB > 0."""
    if value is None:
        return None
    if isinstance(value, str):
        s = value.strip().lower()
        if s == "clean":
            return None
        try:
            v = float(s)
        except ValueError:
            raise InputError(field_name, value, "'clean' or a finite number of dB > 0") from None
    else:
        v = float(value)
    if not math.isfinite(v) or v <= 0:
        raise InputError(field_name, value, "'clean' or a finite number of dB > 0")
    return v


def snr_label(snr_db: float | None) -> str:
    """'clean' or the dB value without trailing zeros, for folder names and reports."""
    return "clean" if snr_db is None else f"{snr_db:g}"
