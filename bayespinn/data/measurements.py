"""The measurement set: what a sensor file holds, in SI units, and its CSV form (the contract's format)."""

from __future__ import annotations

import csv
import io
import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError

KINDS = ("deflection", "strain")
REQUIRED = ("x", "t", "value", "kind")
OPTIONAL = ("y", "sensor", "value_true", "crossing")


@dataclass(frozen=True)
class Measurements:
    """Observations of a girder under a moving load.

    Attributes
    ----------
    x : array (P,), sensor position along the span [m]
    t : array (P,), time on the data's clock [s] (since the first axle entered, unless the vehicle's
        entry_time says when it did)
    value : array (P,), measured deflection [m] (positive down) or strain [-]
    kind : array (P,) of str, 'deflection' or 'strain'
    y : array (P,), fibre distance from the neutral axis [m] (+ down); NaN on deflection rows
    sensor : array (P,) of str, sensor name ('' when unnamed)
    value_true : array (P,) or None, the noise-free value of a synthetic file
    crossing : array (P,) of str or None, the crossing each row belongs to (a file of several
        crossings); None: the file is one crossing
    """

    x: np.ndarray
    t: np.ndarray
    value: np.ndarray
    kind: np.ndarray
    y: np.ndarray
    sensor: np.ndarray
    value_true: np.ndarray | None = None
    crossing: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.x.size)

    @property
    def is_strain(self) -> np.ndarray:
        """Boolean (P,): rows that are strains."""
        return self.kind == "strain"

    @property
    def weights(self) -> tuple[np.ndarray, np.ndarray]:
        """(a_u, a_xx) so that each observation is a_u u + a_xx u_xx (strain = -y u_xx)."""
        s = self.is_strain
        return (~s).astype(float), np.where(s, -np.nan_to_num(self.y), 0.0)

    @property
    def case(self) -> str:
        """'strain' if any row is a strain, else 'deflection'."""
        return "strain" if bool(self.is_strain.any()) else "deflection"

    def select(self, mask: np.ndarray) -> Measurements:
        """The rows where mask is true."""
        vt = None if self.value_true is None else self.value_true[mask]
        cr = None if self.crossing is None else self.crossing[mask]
        return Measurements(
            self.x[mask],
            self.t[mask],
            self.value[mask],
            self.kind[mask],
            self.y[mask],
            self.sensor[mask],
            vt,
            cr,
        )

    @property
    def crossing_names(self) -> tuple[str, ...]:
        """The crossings in the order they first appear (empty when the file is one crossing)."""
        if self.crossing is None:
            return ()
        _, first = np.unique(self.crossing, return_index=True)
        return tuple(str(self.crossing[i]) for i in sorted(first))

    def with_values(self, value: np.ndarray) -> Measurements:
        """The same rows with new measured values (e.g. a perturbed copy)."""
        return Measurements(
            self.x,
            self.t,
            np.asarray(value, float),
            self.kind,
            self.y,
            self.sensor,
            self.value_true,
            self.crossing,
        )

    def to_csv(self, path: str | Path) -> None:
        """Write the contract's measurement CSV atomically (a temp file renamed into place)."""
        cols = (
            list(REQUIRED)
            + ["y", "sensor"]
            + (["value_true"] if self.value_true is not None else [])
            + (["crossing"] if self.crossing is not None else [])
        )
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(cols)
        for i in range(len(self)):
            row = [
                repr(float(self.x[i])),
                repr(float(self.t[i])),
                repr(float(self.value[i])),
                self.kind[i],
            ]
            row.append("" if math.isnan(self.y[i]) else repr(float(self.y[i])))
            row.append(self.sensor[i])
            if self.value_true is not None:
                row.append(repr(float(self.value_true[i])))
            if self.crossing is not None:
                row.append(self.crossing[i])
            w.writerow(row)
        atomic_write_text(path, buf.getvalue())


def _umask_mode() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


#: ordinary permissions for written files (mkstemp would leave them owner-only)
_FILE_MODE = _umask_mode()


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write text to path through a temporary file in the same folder, so no half-written file remains."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)
        os.chmod(tmp, _FILE_MODE)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _float(cell: str, row: int, col: str, name: str) -> float:
    try:
        v = float(cell)
    except ValueError:
        raise InputError(f"{name} row {row}, column {col}", cell, "a number") from None
    if not math.isfinite(v):
        raise InputError(f"{name} row {row}, column {col}", cell, "a finite number")
    return v


def read_csv(path: str | Path, length: float | None = None) -> Measurements:
    """Read and validate a measurement CSV.

    Parameters
    ----------
    path : the file.
    length : span L [m]; when given, x must lie in [0, L].

    Raises
    ------
    InputError naming the row (1-based, header is row 1) and the column of the first bad cell.
    """
    p = Path(path)
    name = p.name
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise InputError("--data", str(path), "an existing measurement CSV file") from None
    except OSError as exc:
        raise InputError("--data", str(path), f"a readable file ({exc.strerror})") from None
    if b"\x00" in raw:
        raise InputError("--data", str(path), "a text CSV file (found binary data)")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise InputError("--data", str(path), "a UTF-8 text CSV file (found binary data)") from None
    rows = list(csv.reader(io.StringIO(text)))
    rows = [r for r in rows if any(c.strip() for c in r)]
    if not rows:
        raise InputError(
            "--data", str(path), "a CSV with a header row and at least one observation"
        )
    header = [c.strip() for c in rows[0]]
    for col in REQUIRED:
        if col not in header:
            raise InputError(
                f"{name} header",
                ",".join(header),
                f"a column named '{col}' (need {', '.join(REQUIRED)})",
            )
    if len(rows) < 2:
        raise InputError("--data", str(path), "at least one observation row after the header")
    pos = {c: header.index(c) for c in header}
    cols: dict[str, list] = {c: [] for c in REQUIRED + OPTIONAL}
    for r, row in enumerate(rows[1:], start=2):
        if len(row) != len(header):
            raise InputError(
                f"{name} row {r}", ",".join(row), f"{len(header)} cells like the header"
            )
        cell = {c: row[pos[c]].strip() for c in header}
        x = _float(cell["x"], r, "x", name)
        if x < 0 or (length is not None and x > length * (1 + 1e-12)):
            span = f"[0, {length:g}] m (the span)" if length is not None else "a position >= 0 m"
            raise InputError(f"{name} row {r}, column x", cell["x"], span)
        t = _float(cell["t"], r, "t", name)
        if t < 0:
            raise InputError(f"{name} row {r}, column t", cell["t"], "a time >= 0 s")
        v = _float(cell["value"], r, "value", name)
        kind = cell["kind"].lower()
        if kind not in KINDS:
            raise InputError(
                f"{name} row {r}, column kind", cell["kind"], "'deflection' or 'strain'"
            )
        ys = cell.get("y", "")
        if kind == "strain":
            if ys == "":
                raise InputError(
                    f"{name} row {r}, column y", ys, "the fibre distance y [m] on a strain row"
                )
            y = _float(ys, r, "y", name)
        else:
            y = _float(ys, r, "y", name) if ys else math.nan
        vt = cell.get("value_true", "")
        cols["x"].append(x)
        cols["t"].append(t)
        cols["value"].append(v)
        cols["kind"].append(kind)
        cols["y"].append(y)
        cols["sensor"].append(cell.get("sensor", ""))
        cols["value_true"].append(_float(vt, r, "value_true", name) if vt else math.nan)
        if "crossing" in cell:
            if cell["crossing"] == "":
                raise InputError(
                    f"{name} row {r}, column crossing", "", "the name of the row's crossing"
                )
            cols["crossing"].append(cell["crossing"])
    vt = np.array(cols["value_true"])
    return Measurements(
        x=np.array(cols["x"]),
        t=np.array(cols["t"]),
        value=np.array(cols["value"]),
        kind=np.array(cols["kind"], dtype=object).astype(str),
        y=np.array(cols["y"]),
        sensor=np.array(cols["sensor"], dtype=object).astype(str),
        value_true=None if np.isnan(vt).any() else vt,
        crossing=np.array(cols["crossing"], dtype=object).astype(str)
        if "crossing" in pos
        else None,
    )
