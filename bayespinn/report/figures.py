"""The run report's figures (PNG, matplotlib Agg, no pyplot state), written into the run folder.

- `fig_posteriors.png`: EI and sigma posteriors per method, 90 % intervals, truth when known;
- `fig_sensor_<name>.png`: per sensor, the series against each method's predictive band, residuals
  underneath, one row per crossing (`sensors`);
- `fig_data_fit.png`: the data against the posterior predictive (noise included);
- `fig_residuals.png`: standardised residuals at the posterior mean against t and x, per method, with
  the fit check's verdict (what a misfit alert points to);
- `fig_span_profiles.png`: deflection and moment along the span at t = 0.60, 1.22, 1.82 s with 90 %
  response bands and the FE truth when known (paper Fig. 4);
- `fig_gauges.png` (strain data): strain histories at every gauge, one not used for training flagged
  (paper Fig. 7);
- `fig_ei_span.png`, `fig_ei_load.png` (real girders): EI along the span, EI against the load factor
  (`girder_figures`).

Files stay SI; axes show GN m^2, mm, kN m and microstrain. Every figure is drawn by its own function;
`make_figures` catches a failing one, logs a warning and leaves it out, so the report is never lost.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..config import Config, Sensor
from ..uq import predictive as pv
from .canvas import (
    TRUTH_STYLE,
    FigureFile,
    NotApplicable,
    SkipFigure,
    _color,
    _gauges_in_data,
    _new_figure,
    _save,
    _subtitle,
)
from .girder_figures import ei_load_figure, ei_span_figure
from .residuals import residuals_figure
from .units import DISPLAY, name, sigma_unit

log = logging.getLogger(__name__)

#: points along the span / along time for the curves
N_SPAN, N_TIME = 161, 400


def _band(ax, s, mean, lo, hi, f: float, key: str, lw: float, mean_label: bool = True) -> None:
    """A method's 90 % band and mean along s, in display units (times f), in its colour."""
    ax.fill_between(
        s, lo * f, hi * f, color=_color(key), alpha=0.25, lw=0, label=f"{name(key)} 90 % band"
    )
    ax.plot(
        s, mean * f, color=_color(key), lw=lw, label=f"{name(key)} mean" if mean_label else None
    )


def _true_load(result) -> float:
    """The crossing's true axle-load factor (1 unless the loads were uncertain and drawn)."""
    return float((result.truth or {}).get("load_factor", 1.0))


# ---------------------------------------------------------------------------------------------- (a)
def posteriors_figure(result, cfg: Config, path: Path, rng: np.random.Generator) -> str:
    """EI and sigma posteriors: one row per method (histogram + KDE), 90 % interval, truth line."""
    from scipy.stats import gaussian_kde

    posts = result.posteriors
    if not posts:
        raise SkipFigure("no posterior to draw")
    fs, su = sigma_unit(result.summary["case"])
    fe, eu = DISPLAY["EI"]
    fig = _new_figure(10, 1.9 + 1.7 * len(posts))
    axes = fig.subplots(len(posts), 2, squeeze=False, sharex="col")
    truth = result.truth
    for i, (key, p) in enumerate(posts.items()):
        for j, (draws, f, unit, var) in enumerate(((p.EI, fe, eu, "EI"), (p.sigma, fs, su, "σ"))):
            ax = axes[i, j]
            d = np.asarray(draws, float).ravel() * f
            d = d[np.isfinite(d)]
            c = _color(key)
            lo, hi = np.quantile(d, [0.05, 0.95]) if d.size else (np.nan, np.nan)
            if d.size >= 5 and np.ptp(d) > 0:
                bins = np.histogram_bin_edges(d, bins="auto")
                bins = bins if bins.size <= 61 else np.linspace(d.min(), d.max(), 61)
                ax.hist(d, bins=bins, density=True, color=c, alpha=0.3)
                grid = np.linspace(d.min(), d.max(), 300)
                ax.plot(grid, gaussian_kde(d)(grid), color=c, lw=1.5)
            else:  # a handful of draws (small ensemble) or a point mass: show them as a rug
                for v in d:
                    ax.axvline(v, color=c, lw=1.5, alpha=0.8)
            ax.axvspan(lo, hi, color=c, alpha=0.08)
            for v in (lo, hi):
                ax.axvline(v, color=c, ls=":", lw=1)
            tv = None if truth is None else truth.get("EI" if var == "EI" else "sigma")
            if tv is not None and np.isfinite(tv) and tv > 0:
                ax.axvline(tv * f, label="truth", **TRUTH_STYLE)
            ax.set_yticks([])
            ax.set_title(
                f"{name(key)}: {var} mean {d.mean():.4g}, 90 % [{lo:.4g}, {hi:.4g}] {unit}",
                fontsize=9,
            )
            if i == len(posts) - 1:
                ax.set_xlabel(f"{'EI' if var == 'EI' else 'noise sd σ'} ({unit})")
    if truth is not None:
        axes[0, 0].legend(loc="upper right", fontsize=8)
    fig.suptitle(f"Posteriors of EI and σ ({_subtitle(result)})", fontsize=11)
    _save(fig, path)
    if truth is None:
        return (
            "Posterior histograms and kernel density estimates per method; dotted lines and shading: "
            "equal-tailed 90 % credible interval. Measured data: the truth is unknown."
        )
    return (
        "Posterior histograms and kernel density estimates per method; dotted lines and shading: "
        "equal-tailed 90 % credible interval; dashed black line: the true value."
    )


# ---------------------------------------------------------------------------------------------- (b)
def data_fit_figure(result, cfg: Config, path: Path, rng: np.random.Generator) -> str:
    """Data against the posterior predictive (90 % band, noise included), per method with a predictor."""
    posts = pv.with_predictor(result.posteriors)
    if not posts:
        raise SkipFigure("no method has a posterior predictive (predictor is None)")
    data = result.data
    if data.is_strain.any():
        return _strain_fit(result, posts, path, rng)
    f, unit = DISPLAY["deflection"]
    fig = _new_figure(max(4.6 * len(posts) + 0.6, 7.0), 4.8)
    axes = fig.subplots(1, len(posts), squeeze=False)[0]
    notes = []
    for ax, (key, p) in zip(axes, posts.items(), strict=True):
        resp = pv.predict(p, data.x, data.t, "deflection", rng)
        mean = resp.mean(axis=0)
        lo, hi = pv.predictive_band(resp, p.sigma, rng)
        inside = float(np.mean((data.value >= lo) & (data.value <= hi)))
        y = data.value * f
        ax.vlines(
            y, lo * f, hi * f, color=_color(key), alpha=0.6, lw=0.8, label="90 % predictive band"
        )
        ax.plot(y, mean * f, "o", ms=3, color=_color(key), label="posterior mean response")
        lim = [min(y.min(), (lo * f).min()), max(y.max(), (hi * f).max())]
        ax.plot(lim, lim, color="black", lw=1, label="measured = predicted")
        ax.set_xlabel(f"measured deflection ({unit}, + down)")
        ax.set_ylabel(f"predicted deflection ({unit})")
        ax.set_title(
            f"{name(key)}: {100 * inside:.0f} % of {len(data)} points in the 90 % band", fontsize=9
        )
        ax.legend(fontsize=8, loc="upper left")
        notes.append(f"{name(key)}: {100 * inside:.1f} % of the points inside")
    fig.suptitle(f"Data against the posterior predictive ({_subtitle(result)})", fontsize=11)
    _save(fig, path)
    return (
        "Measured against predicted deflection; bars: 90 % posterior predictive band (response plus "
        "measurement noise, σ from its posterior). About 90 % of the points should fall inside: "
        + "; ".join(notes)
        + "."
    )


def _strain_fit(result, posts, path: Path, rng: np.random.Generator) -> str:
    data = result.data
    f, unit = DISPLAY["strain"]
    gauges = _gauges_in_data(data)
    ncol = 2 if len(gauges) > 1 else 1
    nrow = -(-len(gauges) // ncol)
    fig = _new_figure(6.0 * ncol, 3.0 * nrow + 0.6)
    axes = fig.subplots(nrow, ncol, squeeze=False).ravel()
    hits = {k: [0, 0] for k in posts}
    for ax, (label, x, y, m) in zip(axes, gauges, strict=False):
        order = np.argsort(data.t[m])
        t, v = data.t[m][order], data.value[m][order]
        ax.plot(t, v * f, ".", ms=2.5, color="0.35", label="measured", zorder=1)
        for key, p in posts.items():
            resp = pv.predict(p, np.full(t.size, x), t, "strain", rng, y=y)
            mean = resp.mean(axis=0)
            lo, hi = pv.predictive_band(resp, p.sigma, rng)
            hits[key][0] += int(np.sum((v >= lo) & (v <= hi)))
            hits[key][1] += v.size
            _band(ax, t, mean, lo, hi, f, key, lw=1.2, mean_label=False)
        ax.set_title(f"{label} (x = {x:.2f} m, {'bottom' if y > 0 else 'top'} flange)", fontsize=9)
        ax.set_xlabel("time t (s)")
        ax.set_ylabel(f"strain ({unit})")
    for ax in axes[len(gauges) :]:
        ax.set_visible(False)
    axes[0].legend(fontsize=7, loc="best")
    fig.suptitle(f"Strain data against the posterior predictive ({_subtitle(result)})", fontsize=11)
    _save(fig, path)
    notes = "; ".join(
        f"{name(k)}: {100 * h / max(n, 1):.1f} % of the samples inside"
        for k, (h, n) in hits.items()
    )
    return (
        "Strain time history at each gauge of the data; shading: 90 % posterior predictive band "
        "(response plus noise), line: posterior mean of the noise-free response. About 90 % should fall inside: "
        + notes
        + "."
    )


# ---------------------------------------------------------------------------------------------- (c)
def span_profiles_figure(result, cfg: Config, path: Path, rng: np.random.Generator) -> str:
    """Deflection and moment along the span at the paper's instants, 90 % response band, FE truth."""
    posts = pv.with_predictor(result.posteriors)
    if not posts:
        raise SkipFigure("no method has a posterior predictive (predictor is None)")
    times = pv.span_times(cfg)
    L = cfg.beam.length
    x = np.linspace(0.0, L, N_SPAN)
    fig = _new_figure(4.2 * len(times) + 0.4, 6.6)
    axes = fig.subplots(2, len(times), squeeze=False, sharex=True)
    for j, t in enumerate(times):
        for i, q in enumerate(("deflection", "moment")):
            f, unit = DISPLAY[q]
            ax = axes[i, j]
            for key, p in posts.items():
                mean, lo, hi = pv.band(pv.predict(p, x, np.full(x.size, t), q, rng))
                _band(ax, x, mean, lo, hi, f, key, lw=1.3)
            if result.truth is not None:
                ax.plot(
                    x,
                    pv.fe_truth(cfg, x, np.full(x.size, t), q, load_factor=_true_load(result)) * f,
                    label="FE truth",
                    **TRUTH_STYLE,
                )
            if q == "deflection":
                ax.invert_yaxis()  # positive down: the girder sags downwards on the plot
                ax.set_title(f"t = {t:.2f} s", fontsize=10)
            ax.set_ylabel(
                f"{'deflection u' if q == 'deflection' else 'moment M'} ({unit}{', + down' if q == 'deflection' else ', sagging +'})"
            )
            if i == 1:
                ax.set_xlabel("position along the span x (m)")
    axes[0, 0].legend(fontsize=7, loc="best")
    fig.suptitle(f"Deflection and moment along the span ({_subtitle(result)})", fontsize=11)
    _save(fig, path)
    shown = ", ".join(f"{t:.2f}" for t in times)
    truth = (
        "dashed black: the finite-element truth."
        if result.truth is not None
        else "measured data: no FE truth is shown (the true EI is unknown)."
    )
    return (
        f"Deflection (top) and bending moment (bottom) along the span at t = {shown} s (paper Fig. 4); "
        f"shading: 90 % credible band of the noise-free response, line: posterior mean; {truth}"
    )


# ---------------------------------------------------------------------------------------------- (d)
def _all_gauges(cfg: Config, data) -> list[tuple[Sensor, np.ndarray]]:
    """The configured gauges and any other gauge of the data, each with its data-row mask."""
    in_data = _gauges_in_data(data)
    names = {s.name for s in cfg.sensors}
    out, used = [], set()
    for s in cfg.sensors:
        mask = np.zeros(len(data), bool)
        for i, (label, x, y, m) in enumerate(in_data):
            same_place = abs(x - s.x) < 1e-6 and abs(y - s.y) < 1e-6
            # a gauge named like a configured one is that one; an unnamed gauge matches by place
            if label == s.name or (label not in names and same_place):
                mask |= m
                used.add(i)
        out.append((s, mask))
    for i, (label, x, y, m) in enumerate(in_data):
        if i not in used:
            out.append((Sensor(label, x, y), m))
    return out


def gauges_figure(result, cfg: Config, path: Path, rng: np.random.Generator) -> str:
    """Strain histories at every gauge (S1-S4 of cfg.sensors): 90 % response band, data where the gauge
    was used for training, FE truth when known; gauges without data are flagged 'not used for training'."""
    data = result.data
    if not (data.is_strain.any() or cfg.case == "strain"):
        raise SkipFigure("deflection data: no strain gauges")
    posts = pv.with_predictor(result.posteriors)
    if not posts:
        raise SkipFigure("no method has a posterior predictive (predictor is None)")
    gauges = _all_gauges(cfg, data)
    f, unit = DISPLAY["strain"]
    T = cfg.duration
    t = np.linspace(0.0, T, N_TIME)
    ncol = 2 if len(gauges) > 1 else 1
    nrow = -(-len(gauges) // ncol)
    fig = _new_figure(6.0 * ncol, 3.0 * nrow + 0.6)
    axes = fig.subplots(nrow, ncol, squeeze=False).ravel()
    held_out = []
    for ax, (s, m) in zip(axes, gauges, strict=False):
        if m.any():
            ax.plot(
                data.t[m],
                data.value[m] * f,
                ".",
                ms=2,
                color="0.45",
                label="measured (used for training)",
            )
        else:
            held_out.append(s.name)
        for key, p in posts.items():
            mean, lo, hi = pv.band(pv.predict(p, np.full(t.size, s.x), t, "strain", rng, y=s.y))
            _band(ax, t, mean, lo, hi, f, key, lw=1.2)
        if result.truth is not None:
            ax.plot(
                t,
                pv.fe_truth(
                    cfg, np.full(t.size, s.x), t, "strain", y=s.y, load_factor=_true_load(result)
                )
                * f,
                label="FE truth",
                **TRUTH_STYLE,
            )
        flange = "bottom" if s.y > 0 else "top"
        tag = "" if m.any() else " (not used for training)"
        ax.set_title(
            f"{s.name}: x = {s.x:.2f} m, {flange} flange{tag}",
            fontsize=9,
            color="black" if m.any() else "#a04000",
        )
        ax.set_xlabel("time t (s)")
        ax.set_ylabel(f"strain ({unit})")
        ax.legend(fontsize=7, loc="best")
    for ax in axes[len(gauges) :]:
        ax.set_visible(False)
    fig.suptitle(f"Strain histories at the gauges ({_subtitle(result)})", fontsize=11)
    _save(fig, path)
    held = (
        f"Gauges not used for training (a genuine out-of-sample check): {', '.join(held_out)}."
        if held_out
        else "Every gauge shown was used for training."
    )
    return (
        "Strain time histories at each gauge (paper Fig. 7); shading: 90 % credible band of the "
        "noise-free strain, line: posterior mean"
        + ("; dashed black: the finite-element truth. " if result.truth is not None else ". ")
        + held
    )


#: (file name, title, function), in report order
FIGURES = (
    ("fig_posteriors.png", "Posteriors of EI and σ", posteriors_figure),
    ("fig_residuals.png", "Residuals: does the model fit?", residuals_figure),
    ("fig_data_fit.png", "Data against the posterior predictive", data_fit_figure),
    (
        "fig_span_profiles.png",
        "Deflection and moment along the span (paper Fig. 4)",
        span_profiles_figure,
    ),
    ("fig_gauges.png", "Strain histories at the gauges (paper Fig. 7)", gauges_figure),
    ("fig_ei_span.png", "EI along the span", ei_span_figure),
    ("fig_ei_load.png", "EI against the axle-load factor", ei_load_figure),
)


def make_figures(result, cfg: Config, folder: str | Path) -> tuple[list[FigureFile], list[str]]:
    """Draw every figure that applies into `folder`.

    Returns the figures written and notes on those left out (nothing to draw, or a failure, which is
    also logged as a warning). Never raises for a figure's sake.
    """
    folder = Path(folder)
    written, notes = [], []
    skipped_predictor = [name(k) for k, p in result.posteriors.items() if p.predictor is None]
    if skipped_predictor:
        notes.append(
            f"No posterior predictive for {', '.join(skipped_predictor)} (no predictor): "
            "left out of the response figures."
        )
    seed = result.summary.get("seed", 0)
    for fname, title, func in FIGURES:
        try:
            caption = func(result, cfg, folder / fname, pv.report_rng(seed, fname))
            written.append(FigureFile(fname, title, caption))
        except SkipFigure as why:
            log.debug("figure %s not drawn: %s", fname, why)
            quiet = isinstance(why, NotApplicable) or (
                fname == "fig_gauges.png" and "deflection data" in str(why)
            )
            if not quiet:
                notes.append(f"{title}: not drawn ({why}).")
        except Exception as exc:  # a figure must never lose the report
            log.warning(
                "warning: figure %s failed and is left out of the report: %s: %s",
                fname,
                type(exc).__name__,
                exc,
            )
            notes.append(f"{title}: left out, drawing it failed ({type(exc).__name__}: {exc}).")
            (folder / fname).unlink(missing_ok=True)
    at = next((i + 1 for i, f in enumerate(written) if f.name == "fig_residuals.png"), len(written))
    written[at:at] = _sensor_figures(result, cfg, folder, notes)
    return written, notes


def _sensor_figures(result, cfg: Config, folder: Path, notes: list[str]) -> list[FigureFile]:
    """The per-sensor figures (`sensors.sensor_figures`); a failure costs a note, never the report."""
    from .sensors import sensor_figures

    try:
        return sensor_figures(result, cfg, folder)
    except SkipFigure as why:
        log.debug("sensor figures not drawn: %s", why)
        return []
    except Exception as exc:  # a figure must never lose the report
        log.warning(
            "warning: the per-sensor figures failed and are left out of the report: %s: %s",
            type(exc).__name__,
            exc,
        )
        notes.append(f"Per-sensor figures: left out, drawing them failed ({type(exc).__name__}).")
        for f in folder.glob("fig_sensor_*.png"):
            f.unlink(missing_ok=True)
        return []
