"""What every report figure shares: the figure file record, the skip signals, a new matplotlib figure
(Agg, no pyplot state), atomic PNG writing, the method colours, the run's subtitle and the gauges in the data.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import methods
from ..config import snr_label
from .files import write_bytes

TRUTH_STYLE = {"color": "black", "ls": "--", "lw": 1.3}
DPI = 110


class SkipFigure(Exception):
    """Nothing to draw (e.g. no method has a predictor); the message says why."""


class NotApplicable(SkipFigure):
    """A figure of a quantity this run did not infer: left out without a note."""


@dataclass(frozen=True)
class FigureFile:
    """A figure written into the folder: file name, title and a caption with what it shows."""

    name: str
    title: str
    caption: str


def _color(key: str) -> str:
    return methods.colour(key)


def _new_figure(w: float, h: float):
    from matplotlib.figure import Figure

    return Figure(figsize=(w, h), dpi=DPI, layout="constrained")


def _save(fig, path: Path) -> None:
    """PNG written atomically, without the software tag (so the bytes depend only on the content)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, metadata={"Software": None})
    write_bytes(path, buf.getvalue())


def _subtitle(result) -> str:
    s = result.summary
    snr = f"SNR {snr_label(s.get('snr_db'))}" + (" dB" if s.get("snr_db") is not None else "")
    return f"{s['case']} case, {snr if result.truth is not None else 'measured data'}, seed {s['seed']}"


def _gauges_in_data(data) -> list[tuple[str, float, float, np.ndarray]]:
    """(label, x, y, row mask) for each distinct strain gauge in the data."""
    s = data.is_strain
    out = []
    keys = sorted(
        {
            (data.sensor[i], round(float(data.x[i]), 6), round(float(data.y[i]), 6))
            for i in np.flatnonzero(s)
        },
        key=lambda k: (k[0], k[1], k[2]),
    )
    for nm, x, y in keys:
        m = (
            s
            & (data.sensor == nm)
            & np.isclose(data.x, x, atol=1e-6)
            & np.isclose(data.y, y, atol=1e-6)
        )
        out.append((nm or f"x = {x:.2f} m, y = {y:+.3f} m", x, y, m))
    return out
