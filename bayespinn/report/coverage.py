"""The coverage pages' figure: per study, the rank ECDF of the true EI with its simultaneous band (ArviZ),
beside the study's hit count against its binomial acceptance region.

A calibrated posterior puts the truth's rank among its draws uniformly on [0, 1]; the ECDF of the ranks
minus the uniform CDF then stays inside ArviZ's simultaneous band (`plot_ecdf(..., difference=True,
confidence_bands=...)`) with the band's probability. The hit count answers the narrower question the
table asks (does the 90 % interval hold the truth 90 % of the time); the ECDF shows how a posterior misses
when it does: tilted (biased) or humped (too wide) or troughed (too narrow). Both sit in one row per study,
so the page reads the count and its shape together.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from .canvas import _new_figure, _save
from .units import name


def rank_ecdf_figure(
    studies: list[tuple[dict, np.ndarray]],
    path: str | Path,
    band: float = 0.99,
    false_failure: float = 0.01,
    label=None,
) -> Path:
    """Write the figure for `studies`: (row, ranks) pairs, a row holding `method`, `snr_db`, `hits`,
    `replicates` and `level` (a coverage study's table row), ranks in [0, 1]. `band`: the simultaneous
    band's probability; `false_failure`: the acceptance region's; `label(row)`: a panel's title (default:
    method and SNR). Returns the PNG's path."""
    from scipy import stats

    from ..uq.arviz_import import import_arviz
    from ..uq.coverage import binomial_acceptance

    az = import_arviz()

    if not studies:
        raise ValueError("no study to draw")
    n = len(studies)
    fig = _new_figure(10.0, 2.5 * n + 0.6)
    grid = fig.add_gridspec(n, 2, width_ratios=[3.2, 1.0])
    points = np.linspace(0.0, 1.0, 101)  # evaluation points independent of the ranks
    for i, (row, ranks) in enumerate(studies):
        ax, axh = fig.add_subplot(grid[i, 0]), fig.add_subplot(grid[i, 1])
        ranks = np.asarray(ranks, float)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            az.plot_ecdf(
                ranks,
                cdf=stats.uniform(0, 1).cdf,
                difference=True,
                confidence_bands="optimized",
                ci_prob=band,
                eval_points=points,
                random_state=0,
                ax=ax,
            )
        ax.axhline(0.0, color="0.6", lw=0.6)
        title = label(row) if label else f"{name(row['method'])}, {row.get('snr_db'):g} dB"
        ax.set_title(f"{title}: rank ECDF - uniform, {100 * band:.0f} % band", fontsize=9)
        ax.set_ylabel("ECDF - uniform", fontsize=8)
        if i == n - 1:
            ax.set_xlabel("rank of the true EI among the posterior draws")
        hits, reps, level = int(row["hits"]), int(row["replicates"]), float(row["level"])
        lo, hi = binomial_acceptance(reps, level, false_failure)
        ok = lo <= hits <= hi
        axh.axvspan(lo, hi, color="#2e7d32" if ok else "#c0392b", alpha=0.18, lw=0)
        axh.axvline(level * reps, color="0.4", ls=":", lw=1)
        axh.plot([hits], [0.5], "o", ms=9, color="#2e7d32" if ok else "#c0392b")
        axh.set_xlim(min(lo, hits) - 0.06 * reps, max(hi, hits) + 0.03 * reps)
        axh.set_ylim(0, 1)
        axh.set_yticks([])
        axh.set_title(
            f"{hits} / {reps} hits, region [{lo}, {hi}]" + ("" if ok else ": MISSES"), fontsize=9
        )
        if i == n - 1:
            axh.set_xlabel(f"hits of the {100 * level:g} % interval", fontsize=8)
    fig.suptitle(
        "Coverage: the truth's rank ECDF (left) beside the hit count and its acceptance region "
        f"({100 * (1 - false_failure):g} %, right)",
        fontsize=10,
    )
    path = Path(path)
    _save(fig, path)
    return path
