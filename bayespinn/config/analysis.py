"""What is analysed and how: the data's sampling (`DataSpec`, `Sensor`), the prior (`PriorSpec`), the
model the analysis infers (`ModelSpec`) and the whole problem (`Config`), with its identity and its
plain-dict form for manifests.

The bridge and the vehicle it holds are in `config.bridge`; how a configuration is resolved from the
preset and a TOML file is in `config.resolution`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

from ..errors import InputError
from .bridge import _CROSSING_DEFAULTS, Beam, Crossing, Road, Vehicle
from .checks import _check_int, _check_number

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
        from ..limits import check_limits

        check_limits(self)  # ranges the model and the machine carry (bayespinn.limits)

    @property
    def infers_load_factor(self) -> bool:
        """Whether the analysis infers a common axle-load factor (`model.load_factor`)."""
        return self.model.load_factor == "auto" and self.vehicle.load_rel_sd > 0

    @property
    def real_girder(self) -> bool:
        """Whether the analysis model is a real girder: EI per segment or a smooth EI field, springs at the
        supports or an inferred load factor (whatever the noise model). The PINN methods then fit the
        girder network (`uq.girder_pinn`) rather than the uniform, pinned one."""
        m = self.model
        return (
            m.EI_segments > 1
            or m.EI_field == "smooth"
            or m.supports != "pinned"
            or self.infers_load_factor
        )

    @property
    def ideal(self) -> bool:
        """The analysis model is a uniform, pinned girder under known loads with white noise: not a real
        girder (`real_girder`, the one test of which world this is) and i.i.d. noise."""
        return not self.real_girder and self.model.noise == "iid"

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
