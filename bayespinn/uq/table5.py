"""The paper's Table 5 with uncertainty (the metrics; `report.table5` formats them): deflection and moment along the span against the FE truth.

For a run on synthetic data and a method with a posterior predictive, at t = 0.60, 1.22 and 1.82 s
(clipped to the crossing) and at `n_points` interior points of the span (the supports, where every
model and the truth are exactly zero, are left out):

- RMSE = sqrt(mean_i (pred_i - truth_i)^2), pred the posterior predictive mean of the noise-free
  response; [m] for deflection, [N m] for moment (the Markdown shows mm and kN m);
- CV (%) = RMSE / mean_i |truth_i| x 100 (the paper's coefficient of variation of the error);
- NMB (%) = sum_i (pred_i - truth_i) / sum_i truth_i x 100 (normalised mean bias; the paper's "NBM");
- rmse_ci90: the equal-tailed 90 % interval of the RMSE of single posterior draws, the uncertainty the
  paper's point estimates do not show;
- coverage: the fraction of span points where the 90 % credible band of the response contains the FE
  truth (a calibrated band covers about 90 %; it is a band for the structure, noise not included).
"""

from __future__ import annotations

import numpy as np

from ..config import Config
from ..methods import REFERENCE_KEY
from . import predictive as pv

QUANTITIES = ("deflection", "moment")
#: interior span points (paper: not stated; 101 resolves the profiles to well below 1 % of the peak)
N_POINTS = 101


def _metrics(draws: np.ndarray, truth: np.ndarray, level: float) -> dict:
    mean, lo, hi = pv.band(draws, level)
    err = mean - truth
    rmse = float(np.sqrt(np.mean(err**2)))
    per_draw = np.sqrt(np.mean((draws - truth[None, :]) ** 2, axis=1))
    a = (1.0 - level) / 2.0
    denom_abs = float(np.mean(np.abs(truth)))
    denom = float(np.sum(truth))
    return {
        "rmse": rmse,
        "rmse_ci90": [float(v) for v in np.quantile(per_draw, [a, 1.0 - a])],
        "cv_pct": 100.0 * rmse / denom_abs if denom_abs > 0 else float("nan"),
        "nmb_pct": 100.0 * float(np.sum(err)) / denom if denom != 0 else float("nan"),
        "coverage": float(np.mean((truth >= lo) & (truth <= hi))),
        "max_abs_truth": float(np.max(np.abs(truth))),
    }


def table5(
    result,
    cfg: Config,
    method: str = REFERENCE_KEY,
    *,
    times=pv.PAPER_TIMES,
    n_points: int = N_POINTS,
    n_draws: int = pv.N_DRAWS,
    level: float = pv.LEVEL,
) -> dict:
    """Table 5 metrics for one method of a `pipeline.RunResult` (SI units; see the module docstring).

    Returns
    -------
    dict with method, level, n_points, n_draws, times [s] and rows: one per time, {"t": s,
    "deflection": {rmse [m], rmse_ci90 [m], cv_pct, nmb_pct, coverage, max_abs_truth [m]},
    "moment": {... [N m]}}.

    Raises
    ------
    ValueError when the truth is unknown (measured data) or the method has no predictor.
    """
    if result.truth is None:
        raise ValueError("Table 5 needs the truth: these are measured data")
    post = result.posteriors.get(method)
    if post is None or post.predictor is None:
        raise ValueError(f"{method} has no posterior predictive in this run")
    L = cfg.beam.length
    x = np.linspace(0.0, L, n_points + 2)[1:-1]
    rng = pv.report_rng(result.summary.get("seed", 0), f"table5/{method}")
    rows = []
    for t in pv.span_times(cfg, times):
        tt = np.full(x.size, t)
        row = {"t": t}
        for q in QUANTITIES:
            draws = pv.predict(post, x, tt, q, rng, n_draws)
            lf = (result.truth or {}).get("load_factor", 1.0)
            row[q] = _metrics(draws, pv.fe_truth(cfg, x, tt, q, load_factor=lf), level)
        rows.append(row)
    return {
        "schema": "bayespinn.table5/1",
        "method": method,
        "level": level,
        "n_points": n_points,
        "n_draws": n_draws,
        "times": [r["t"] for r in rows],
        "rows": rows,
    }
