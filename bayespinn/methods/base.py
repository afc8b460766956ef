"""The base of every method: `Method` (a class per method, built from frozen, validated `Settings`) and
the settings' checks. Method modules import this, never the registry package (`bayespinn.methods`),
whose `__init__` imports every built-in method to register it."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

from ..errors import InputError
from ..options import NOISE_PRIORS, PROFILES, RunOptions

if TYPE_CHECKING:
    from ..config import Config
    from ..data.measurements import Measurements
    from ..uq.posterior import Posterior


@dataclass(frozen=True)
class Settings:
    """What every built-in method is built from; each method extends it with its own fields.

    profile : "smoke", "fast" or "paper" (network size, steps and sampler lengths)
    noise_prior : "vague" (log-uniform sigma) or "snr" (log-normal around the stated SNR's sigma)
    snr_db : the nominal SNR [dB] the `snr` noise prior is centred on, or None
    """

    profile: str = "fast"
    noise_prior: str = "vague"
    snr_db: float | None = None

    def __post_init__(self) -> None:
        check_choice("profile", self.profile, PROFILES)
        check_choice("noise_prior", self.noise_prior, NOISE_PRIORS)
        if self.snr_db is not None and not _real(self.snr_db):
            raise InputError("snr_db", self.snr_db, "a level in dB, or None")


def check_choice(field: str, value, choices: Iterable[str]) -> None:
    choices = tuple(choices)
    if value not in choices:
        raise InputError(field, value, " or ".join(", ".join(choices).rsplit(", ", 1)))


def check_device(device) -> None:
    if not (isinstance(device, str) and device.split(":")[0] in ("cpu", "cuda")):
        raise InputError(
            "device", device, "cpu or cuda ('auto' is resolved by options.resolve_device)"
        )


def _real(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and v == v


class Method:
    """Base class of an inference method.

    Class attributes: `name` (CLI), `key` (summary.json and the posterior file), `display` (reports),
    `colour` (figures), `reference` (True for the exact reference the others are judged against),
    `Settings` (its frozen settings class) and `modules` (the modules whose code decides its numbers;
    default: the class's own module).
    """

    name: ClassVar[str]
    key: ClassVar[str]
    display: ClassVar[str]
    colour: ClassVar[str] = "#555555"
    reference: ClassVar[bool] = False
    Settings: ClassVar[type] = Settings
    modules: ClassVar[tuple[str, ...]] = ()
    #: whether the method describes real girders: EI per segment, springs at the supports and an uncertain
    #: load factor (`[model]`); a method that does not is refused such a configuration by `check`
    real_girders: ClassVar[bool] = False
    #: whether the method infers what a real crossing leaves uncertain (speed, entry time, damping, axle
    #: forces; several crossings); a method that does not is refused such a configuration by `check`
    real_crossings: ClassVar[bool] = False

    def __init__(self, settings=None, *, progress: bool = False, executor=None, **fields):
        if settings is None:
            settings = self.Settings(**fields)
        elif fields:
            settings = dataclasses.replace(settings, **fields)
        if not isinstance(settings, self.Settings):
            raise InputError(
                "settings", type(settings).__name__, f"{self.Settings.__name__} for {self.name}"
            )
        self.settings = settings
        self.progress = progress
        self.executor = executor

    @classmethod
    def from_options(cls, opts: RunOptions) -> Method:
        """The method built from the command line's options (the fields its settings have)."""
        names = {f.name for f in dataclasses.fields(cls.Settings)}
        values = {k: getattr(opts, k) for k in names if hasattr(opts, k)}
        return cls(cls.Settings(**values), progress=opts.progress, executor=opts.executor)

    @classmethod
    def code_modules(cls) -> tuple[str, ...]:
        return cls.modules or (cls.__module__,)

    def check(self, data: Measurements, config: Config) -> None:
        """Refuse, before any method runs, an analysis model this method cannot describe (`InputError`,
        exit 2, naming the field), rather than silently analyse it as a uniform, pinned, known-load girder
        with white noise."""
        m = config.model
        if m.noise != "iid":
            raise InputError("model.noise", m.noise, "'iid' (this method has no AR(1) likelihood)")
        if not self.real_crossings:  # a speed, entry time, damping or forces to infer, or crossings
            from ..crossings import refuse_crossings

            refuse_crossings(config, data, self.display)
        if self.real_girders:
            return
        why = f"for {self.display}, which describes uniform, pinned girders under known loads"
        if m.EI_segments != 1:
            raise InputError(
                "model.EI_segments", m.EI_segments, f"1 {why}; --method modal infers it"
            )
        if m.supports != "pinned":
            raise InputError(
                "model.supports", m.supports, f"'pinned' {why}; --method modal infers it"
            )
        if config.infers_load_factor:
            raise InputError(
                "vehicle.load_rel_sd",
                config.vehicle.load_rel_sd,
                f"0, or [model] load_factor = 'off', {why}; --method modal infers it",
            )

    def infer(self, data: Measurements, config: Config, *, seed) -> Posterior:
        """The posterior on `data`; a method that takes the crossing as stated (not `real_crossings`) is
        given the data on the crossing's clock, its first axle entering at t = 0 (`posterior` sees to it)."""
        raise NotImplementedError

    def posterior(self, data: Measurements, config: Config, *, seed) -> Posterior:
        """`infer` on the data as recorded. A method that takes the crossing as stated reads a recording that
        starts before the entry on the crossing's clock, and predicts on the data's (`methods.clock`)."""
        if self.real_crossings:
            return self.infer(data, config, seed=seed)
        from .clock import on_data_clock, on_entry_clock

        d, c, te = on_entry_clock(data, config)
        return on_data_clock(self.infer(d, c, seed=seed), te)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.settings!r})"
