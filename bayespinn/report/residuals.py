"""The residual figure: what the fit check judges, drawn (standardised residuals at the posterior mean
prediction against time and position, per method, titled with its verdict)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..config import Config
from .canvas import NotApplicable, _gauges_in_data, _new_figure, _save, _subtitle
from .units import name


def residuals_figure(result, cfg: Config, path: Path, rng: np.random.Generator) -> str:
    """Standardised residuals at the posterior mean prediction (what the fit check judges), against time
    and position, one row per method with a fit check; each row titled with its verdict."""
    from ..uq.fitcheck import mean_prediction

    checks = {k: m["fit_check"] for k, m in result.summary["methods"].items() if m.get("fit_check")}
    if not checks:
        raise NotApplicable("no method has a fit check")
    data = result.data
    gauges = _gauges_in_data(data) if data.is_strain.any() else [("points", 0, 0, ~data.is_strain)]
    fig = _new_figure(9.0, 2.9 * len(checks) + 0.6)
    axes = fig.subplots(len(checks), 2, squeeze=False)
    for row, (key, fc) in zip(axes, checks.items(), strict=True):
        post = result.posteriors[key]
        seed = result.summary.get("seed")
        mu = mean_prediction(post, data, seed=seed if isinstance(seed, int) else 0)
        sigma = float(np.median(post.sigma))
        r = (np.asarray(data.value, float) - mu) / sigma
        for label, _, _, rows in gauges:
            order = np.argsort(data.t[rows], kind="stable")
            style = (
                {"lw": 0.7} if data.is_strain.any() else {"ls": "none", "marker": "o", "ms": 2.5}
            )
            row[0].plot(data.t[rows][order], r[rows][order], label=label, **style)
            row[1].plot(data.x[rows], r[rows], "o", ms=2.5, label=label)
        for ax, xl in zip(row, ("time t (s)", "position x (m)"), strict=True):
            ax.axhline(0.0, color="black", lw=0.8)
            for s in (-2.0, 2.0):
                ax.axhline(s, color="grey", lw=0.8, ls=":")
            ax.set_xlabel(xl)
            ax.set_ylabel("residual / σ")
        row[0].set_title(
            f"{name(key)}: {fc['verdict']} (p = {fc['p_value']:.2g}, lag-1 autocorrelation "
            f"{fc['residual_autocorr']:+.2f})",
            fontsize=9,
        )
        if len(gauges) > 1:
            row[0].legend(fontsize=7, loc="upper right", ncol=2)
    fig.suptitle(f"Residuals at the posterior mean prediction ({_subtitle(result)})", fontsize=11)
    _save(fig, path)
    return (
        "Measured minus the posterior mean prediction, in units of the posterior median σ, against time "
        "and position; dotted: ±2. Under the model these are white noise: a smooth shape (a support, a "
        "softer segment, a missing axle) or runs of one sign (noise correlated in time) are what the fit "
        "check flags."
    )
