"""Per sensor: the measured series against each method's posterior predictive band, with the residuals
underneath, one row per crossing (`fig_sensor_<name>.png`). The first thing an engineer looks at to
believe a fit.

Strain gauges are time series: the band is drawn along time at the gauge. Deflection data are points
at random (x, t): they are grouped by position into `DEFLECTION_GROUPS` equal stretches of the span
(each plotted against time, the band as an interval at every point), because a point's neighbours in time
sit elsewhere on the span. Several crossings (a `crossing` column in the data) give one row each.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..uq import predictive as pv
from .canvas import FigureFile, SkipFigure, _color, _gauges_in_data, _new_figure, _save, _subtitle
from .units import DISPLAY, name

#: stretches of the span that group scattered deflection points
DEFLECTION_GROUPS = 4
#: most points drawn per panel (the band of a long series is evaluated at a subsample)
MAX_POINTS = 1500


def sensor_groups(data, length: float) -> list[tuple[str, str, np.ndarray]]:
    """(file tag, title, row mask) per sensor: each strain gauge, and the deflection points by stretch."""
    out = []
    for label, x, y, m in _gauges_in_data(data):
        flange = "bottom" if y > 0 else "top"
        out.append((label, f"{label}: strain at x = {x:.2f} m, {flange} flange", m))
    defl = ~np.asarray(data.is_strain, bool)
    if defl.any():
        edges = np.linspace(0.0, length, DEFLECTION_GROUPS + 1)
        idx = np.clip(np.searchsorted(edges, data.x, side="right") - 1, 0, DEFLECTION_GROUPS - 1)
        for k in range(DEFLECTION_GROUPS):
            m = defl & (idx == k)
            if m.any():
                out.append(
                    (
                        f"x{k + 1}",
                        f"deflection at x from {edges[k]:.2f} to {edges[k + 1]:.2f} m",
                        m,
                    )
                )
    return out


def crossings_of(data) -> list[tuple[str | None, np.ndarray]]:
    """(name or None, row mask) per crossing; one entry (None, all rows) without a `crossing` column."""
    cr = getattr(data, "crossing", None)
    if cr is None:
        return [(None, np.ones(len(data), bool))]
    cr = np.asarray(cr).astype(str)
    names = list(dict.fromkeys(cr.tolist()))
    return [(n, cr == n) for n in names]


def _tag(label: str) -> str:
    return re.sub(r"[^A-Za-z0-9_-]+", "_", label).strip("_") or "sensor"


def sensor_figure(result, rows: np.ndarray, title: str, path: Path, rng) -> str:
    """One sensor's figure: per crossing, the series with each method's 90 % predictive band over the
    residuals (measured minus posterior mean, in units of the posterior median sigma)."""
    data = result.data
    posts = pv.with_predictor(result.posteriors)
    if not posts:
        raise SkipFigure("no method has a posterior predictive (predictor is None)")
    strain = bool(np.asarray(data.is_strain)[rows].all())
    f, unit = DISPLAY["strain" if strain else "deflection"]
    crossings = [(n, m & rows) for n, m in crossings_of(data) if (m & rows).any()]
    fig = _new_figure(10.0, 3.6 * len(crossings) + 0.5)
    grid = fig.add_gridspec(2 * len(crossings), 1, height_ratios=[3, 1.3] * len(crossings))
    inside = {k: [0, 0] for k in posts}
    for c, (cname, m) in enumerate(crossings):
        ax, axr = fig.add_subplot(grid[2 * c]), fig.add_subplot(grid[2 * c + 1])
        ax.sharex(axr)
        ix = np.flatnonzero(m)
        if ix.size > MAX_POINTS:
            ix = ix[np.linspace(0, ix.size - 1, MAX_POINTS).astype(int)]
        ix = ix[np.argsort(data.t[ix], kind="stable")]
        t, v = data.t[ix], np.asarray(data.value, float)[ix]
        ax.plot(
            t, v * f, "o" if not strain else ".", ms=2.8, color="0.2", label="measured", zorder=3
        )
        for j, (key, p) in enumerate(posts.items()):
            q = "strain" if strain else "deflection"
            resp = pv.predict(p, data.x[ix], t, q, rng, y=data.y[ix] if strain else None)
            mean = resp.mean(axis=0)
            lo, hi = pv.predictive_band(resp, p.sigma, rng)
            inside[key][0] += int(np.sum((v >= lo) & (v <= hi)))
            inside[key][1] += v.size
            col = _color(key)
            if strain:
                ax.fill_between(t, lo * f, hi * f, color=col, alpha=0.22, lw=0)
                ax.plot(t, mean * f, color=col, lw=1.2, label=f"{name(key)}: mean, 90 % band")
            else:  # scattered points: an interval at each, side by side per method
                dt = (j - (len(posts) - 1) / 2) * 0.004 * max(float(np.ptp(data.t)), 1e-9)
                ax.vlines(t + dt, lo * f, hi * f, color=col, alpha=0.55, lw=1.4)
                ax.plot(
                    t + dt, mean * f, "_", ms=6, color=col, label=f"{name(key)}: mean, 90 % band"
                )
            sigma = float(np.median(np.asarray(p.sigma, float)))
            r = (v - mean) / sigma if sigma > 0 else v * np.nan
            axr.plot(
                t + (0 if strain else dt), r, ".", ms=2.5 if strain else 4, color=col, alpha=0.8
            )
        if not strain:
            ax.invert_yaxis()  # deflection positive down: the girder sags downwards on the plot
        for s in (-2.0, 0.0, 2.0):
            axr.axhline(s, color="black" if s == 0 else "grey", lw=0.8, ls="-" if s == 0 else ":")
        ax.set_ylabel(f"{'strain' if strain else 'deflection'} ({unit})")
        axr.set_ylabel("residual / σ")
        axr.set_xlabel("time t (s)")
        if cname is not None:
            ax.set_title(f"crossing {cname}", fontsize=9.5)
        ax.tick_params(labelbottom=False)
        if c == 0:
            ax.legend(fontsize=7.5, loc="best")
    fig.suptitle(f"{title} ({_subtitle(result)})", fontsize=11)
    _save(fig, path)
    share = "; ".join(f"{name(k)} {100 * h / max(n, 1):.0f} %" for k, (h, n) in inside.items())
    return (
        "Measured values (black) against each method's 90 % posterior predictive band (response plus "
        "noise) and mean; below, the residuals at that mean in units of the posterior median σ (dotted: "
        f"±2). About 90 % should fall inside the band: {share}."
    )


def sensor_figures(result, cfg, folder: Path) -> list[FigureFile]:
    """Every sensor's figure written into `folder` (file `fig_sensor_<tag>.png`), in sensor order."""
    out = []
    seed = result.summary.get("seed", 0)
    for tag, title, rows in sensor_groups(result.data, cfg.beam.length):
        fname = f"fig_sensor_{_tag(tag)}.png"
        caption = sensor_figure(result, rows, title, folder / fname, pv.report_rng(seed, fname))
        out.append(FigureFile(fname, title[0].upper() + title[1:], caption))
    return out
