"""What the crossing reference is asked and refuses: whether an analysis declares anything it infers, the
one-line refusals (of the PINN methods, which take a crossing as stated, and of what the reference does not
describe yet), and the data's rows split into crossings."""

from __future__ import annotations

import numpy as np

from ..config import Config
from ..data.measurements import Measurements
from ..errors import InputError


def needs_crossings(cfg: Config, data: Measurements | None = None) -> bool:
    """Whether the analysis declares anything the crossing reference infers or today's reference cannot
    read: a speed or entry-time sd, an entry time other than 0, inferred damping, fluctuating axle forces,
    [[crossing]] tables, or a crossing column with several names."""
    vehicles = [cfg.vehicle] + [c.vehicle for c in cfg.crossings]
    return (
        several_crossings(cfg, data)
        or cfg.model.damping == "inferred"
        or cfg.model.axle_forces == "fluctuating"
        or any(v.model == "sprung" for v in vehicles)
        or any(v.speed_sd > 0 or v.entry_time_sd > 0 or v.entry_time != 0 for v in vehicles)
    )


def several_crossings(cfg: Config, data: Measurements | None = None) -> bool:
    """Whether the analysis holds several crossings: [[crossing]] tables, or a crossing column with several
    names."""
    return bool(cfg.crossings) or (
        data is not None and data.crossing is not None and len(set(data.crossing)) > 1
    )


def refuse_crossings(cfg: Config, data: Measurements | None, display: str) -> None:
    """For a method that takes the crossing as stated (the PINN methods): InputError naming the first key
    that declares something to infer, rather than silently analysing with the stated values."""
    if not needs_crossings(cfg, data):
        return
    why = f"for {display}, which takes the crossing as stated; --method modal infers it"
    vehicles = [("vehicle", cfg.vehicle)] + [
        (f"crossing[{i}]", c.vehicle) for i, c in enumerate(cfg.crossings)
    ]
    for where, v in vehicles:
        if v.model == "sprung":
            raise InputError(f"{where}.model", v.model, f"'forces' {why}")
        if v.speed_sd > 0:
            raise InputError(f"{where}.speed_sd", v.speed_sd, f"0 {why}")
        if v.entry_time_sd > 0:
            raise InputError(f"{where}.entry_time_sd", v.entry_time_sd, f"0 {why}")
    if cfg.model.damping != "known":
        raise InputError("model.damping", cfg.model.damping, f"'known' {why}")
    if cfg.model.axle_forces != "constant":
        raise InputError("model.axle_forces", cfg.model.axle_forces, f"'constant' {why}")
    if several_crossings(cfg, data):
        raise InputError(
            "[[crossing]]", len(cfg.crossings) or "a crossing column", f"one crossing {why}"
        )
    # what is left is a stated entry time: the method reads the data on the crossing's clock
    # (`methods.clock`, `Method.posterior`)


def check_crossings(cfg: Config, data: Measurements) -> None:
    """Refuse what the crossing reference does not describe yet, one line naming the key."""
    m = cfg.model
    why = "with a speed, entry time, damping or axle forces to infer, or several crossings, yet"
    if m.EI_segments != 1:
        raise InputError(
            "model.EI_segments", m.EI_segments, f"1 (EI per segment is not supported {why})"
        )
    if m.supports != "pinned":
        raise InputError(
            "model.supports", m.supports, f"'pinned' (springs are not supported {why})"
        )
    if m.noise != "iid":
        raise InputError("model.noise", m.noise, f"'iid' (AR(1) noise is not supported {why})")
    if m.EI_field != "segments":
        raise InputError(
            "model.EI_field", m.EI_field, f"'segments' (a smooth EI field is not inferred {why})"
        )
    if cfg.infers_load_factor or any(c.vehicle.load_rel_sd > 0 for c in cfg.crossings):
        raise InputError(
            "vehicle.load_rel_sd",
            cfg.vehicle.load_rel_sd,
            f"0 (an uncertain load factor is not supported {why})",
        )
    if not cfg.beam.ideal:
        raise InputError("beam.EI", list(cfg.beam.segments), f"one EI and pinned supports {why}")
    split_crossings(cfg, data)


def split_crossings(cfg: Config, data: Measurements) -> list[tuple[str, np.ndarray, object]]:
    """(name, row indices, vehicle) per crossing: the [[crossing]] tables matched to the data's `crossing`
    column, or the whole file as one crossing of [vehicle]."""
    col = data.crossing
    if not cfg.crossings:
        if col is not None and len(set(col)) > 1:
            raise InputError(
                "[[crossing]]",
                "none",
                f"a table per crossing in the data ({', '.join(data.crossing_names)})",
            )
        name = str(col[0]) if col is not None and len(col) else "crossing"
        return [(name, np.arange(len(data)), cfg.vehicle)]
    if col is None:
        if len(cfg.crossings) == 1:
            return [(cfg.crossings[0].name, np.arange(len(data)), cfg.crossings[0].vehicle)]
        raise InputError(
            "data crossing column",
            "missing",
            "a crossing name per row for several [[crossing]] tables",
        )
    names = {c.name for c in cfg.crossings}
    unknown = sorted(set(map(str, col)) - names)
    if unknown:
        raise InputError(
            "data crossing column",
            unknown[0],
            "one of the [[crossing]] names " + ", ".join(sorted(names)),
        )
    out = []
    for c in cfg.crossings:
        rows = np.flatnonzero(col == c.name)
        if rows.size == 0:
            raise InputError(f"[[crossing]] {c.name}", c.name, "a crossing with rows in the data")
        out.append((c.name, rows, c.vehicle))
    return out
