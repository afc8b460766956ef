"""Resolution of a configuration: the preset (the Exeter bascule bridge east girder of the paper,
Table 3, with the vehicle of the chosen case study), overridden by a TOML file, whose tables and keys are
checked here; and the SNR flag's parsing and label.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

from ..errors import InputError
from .analysis import CASES, Config, DataSpec, ModelSpec, PriorSpec, Sensor
from .bridge import _CROSSING_DEFAULTS, Axle, Beam, Crossing, Road, Vehicle, truck_vehicle
from .checks import _check_number


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
