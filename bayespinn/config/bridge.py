"""The bridge and what crosses it: the girder (`Beam`), the vehicle and its axles, the road and the
crossings of a multi-crossing file, with the paper's Exeter girder and test truck as defaults.

These are the physical sections of a configuration (`[beam]`, `[vehicle]`, `[road]`, `[[crossing]]`),
apart from what the analysis infers about them (`config.analysis`). Every value is SI.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InputError
from .checks import _check_number

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


def truck_vehicle(speed: float = EXETER_SPEED, share: float = EAST_GIRDER_SHARE) -> Vehicle:
    """The paper's four-axle test truck, the girder's share of each axle."""
    offsets = np.concatenate([[0.0], np.cumsum(TRUCK_SPACINGS)])
    return Vehicle(
        speed,
        tuple(Axle(share * p, float(o)) for p, o in zip(TRUCK_AXLE_LOADS, offsets, strict=True)),
    )
