"""The run report's girder figures (`report.figures` lists them with the others):

- `fig_ei_span.png`: EI along the span, per equal segment or as a smooth field, posterior mean and 90 % band
  with the nominal, its damage threshold and the truth when known;
- `fig_ei_load.png`: the span-equivalent EI against the axle-load factor (their ridge), when the load factor
  is inferred.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..config import Config
from .canvas import TRUTH_STYLE, NotApplicable, _color, _new_figure, _save, _subtitle
from .units import name


def _girders(result) -> dict:
    """The methods whose posterior carries girder draws (EI per segment, springs, load factor)."""
    return {
        k: p.girder for k, p in result.posteriors.items() if getattr(p, "girder", None) is not None
    }


def ei_span_figure(result, cfg: Config, path: Path, rng: np.random.Generator) -> str:
    """EI per segment along the span: posterior mean and 90 % band, the nominal and the truth."""
    gs = {k: g for k, g in _girders(result).items() if g.n_segments > 1}
    fields = {
        k: p.field for k, p in result.posteriors.items() if getattr(p, "field", None) is not None
    }
    if not gs and not fields:
        raise NotApplicable("no method inferred EI along the span")
    fig = _new_figure(7.5, 4.2)
    ax = fig.subplots()
    for i, (key, f) in enumerate(fields.items()):
        ex = f.EI_x()
        x, mean, ci = (
            np.asarray(ex["x"]),
            np.asarray(ex["mean"]) / 1e9,
            np.asarray(ex["ci90"]) / 1e9,
        )
        ax.plot(x, mean, color=_color(key), lw=1.6, label=f"{name(key)}: mean")
        ax.fill_between(x, ci[:, 0], ci[:, 1], color=_color(key), alpha=0.25, label="90 % band")
        if i == 0:  # one nominal for every method
            ax.axhline(0.9 * f.EI_nominal / 1e9, color="0.4", ls=":", lw=1, label="90 % of nominal")
            ax.axhline(f.EI_nominal / 1e9, color="0.4", ls="-.", lw=1, label="nominal")
    t_x = (result.truth or {}).get("EI_x")
    if fields and t_x:
        ax.plot(t_x["x"], np.asarray(t_x["EI"]) / 1e9, label="truth", **TRUTH_STYLE)
    for key, g in gs.items():
        e = g.EI_segments.reshape(-1, g.n_segments) / 1e9
        lo, mean, hi = np.quantile(e, 0.05, axis=0), e.mean(0), np.quantile(e, 0.95, axis=0)
        edges = np.asarray(g.edges, float)
        ax.stairs(mean, edges, baseline=None, color=_color(key), lw=1.6, label=f"{name(key)}: mean")
        ax.stairs(
            hi, edges, baseline=lo, fill=True, color=_color(key), alpha=0.25, label="90 % band"
        )
        if not fields and key == next(iter(gs)):  # one nominal for every method
            ax.axhline(0.9 * g.EI_nominal / 1e9, color="0.4", ls=":", lw=1, label="90 % of nominal")
            ax.axhline(g.EI_nominal / 1e9, color="0.4", ls="-.", lw=1, label="nominal")
    truth = (result.truth or {}).get("EI_segments")
    if truth:
        S = len(truth)
        ax.stairs(
            np.asarray(truth) / 1e9,
            np.linspace(0, cfg.beam.length, S + 1),
            label="truth",
            **TRUTH_STYLE,
        )
    ax.set_xlabel("position along the span x (m)")
    ax.set_ylabel("EI (GN m²)")
    ax.legend(fontsize=7, loc="best")
    fig.suptitle(f"EI along the span ({_subtitle(result)})", fontsize=11)
    _save(fig, path)
    what = "EI(x), a smooth field" if fields else "EI of each equal segment"
    return (
        f"{what}: posterior mean (line) and 90 % credible band (shading); dotted: 90 % "
        "of the nominal EI, the damage threshold of P(damaged); dashed black: the truth where known."
    )


def ei_load_figure(result, cfg: Config, path: Path, rng: np.random.Generator) -> str:
    """Pair plot of the span-equivalent EI against the axle-load factor."""
    gs = {k: g for k, g in _girders(result).items() if g.load_factor is not None}
    if not gs:
        raise NotApplicable("no method inferred a load factor")
    fig = _new_figure(5.2, 4.6)
    ax = fig.subplots()
    for key, g in gs.items():
        ei = np.asarray(g.EI, float).ravel() / 1e9
        lf = np.asarray(g.load_factor, float).ravel()
        pick = rng.choice(ei.size, size=min(2000, ei.size), replace=False)
        ax.scatter(lf[pick], ei[pick], s=3, alpha=0.3, color=_color(key), label=name(key))
    t = result.truth or {}
    if t.get("load_factor") is not None and t.get("EI") is not None:
        ax.plot([t["load_factor"]], [t["EI"] / 1e9], "k*", ms=10, label="truth")
    ax.set_xlabel("axle-load factor")
    ax.set_ylabel("EI, span equivalent (GN m²)")
    ax.legend(fontsize=7, loc="best")
    fig.suptitle(f"EI against the load factor ({_subtitle(result)})", fontsize=11)
    _save(fig, path)
    return (
        "Posterior draws of EI against the common axle-load factor: along the ridge EI / load is what "
        "the quasi-static response fixes; the star marks the truth where known."
    )
