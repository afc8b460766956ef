"""Does the model fit? A check of each method's residuals for structure the model says cannot be there.

Every interval is conditional on the model (a uniform pinned beam, exactly known loads, white Gaussian
noise). Where the data contradict it, the residuals y - mu at the posterior mean prediction mu keep a trace
of what the model cannot explain: a smooth shape (a support that resists rotation, a softer segment, a
missing axle) or a correlation between consecutive samples of a gauge (smoothed or baseline-adjusted
records). Under the model the residuals are white noise of an unknown sd (less the few directions the fit
spent), so two scale-free statistics have known distributions whatever sigma is:

* smooth structure: the share of the residuals' energy in a fixed smooth basis, F = ||Q'e||^2 / ||e||^2
  (Q an orthonormal basis of k smooth functions: products of Legendre polynomials of degree <= 3 in x/L
  and t/T for scattered deflection points; per gauge, Legendre polynomials of degree <= 7 in t/T for strain
  series). White noise gives Beta(k/2, (n - k)/2);
* serial correlation: the lag-1 autocorrelation of the residuals of each gauge's time series, pooled over
  gauges (scattered points: in time order). White noise gives about N(-1/n, 1/n).

The p-value of each is that of the observed residuals among `REPLICATES` replicates of white noise
through the same statistic (a posterior predictive check whose replicated residual is scale-free, so it
does not depend on which sigma was drawn), and the verdict combines them by Bonferroni: `misfit` when
m x min p < `FALSE_ALARM`. Because a fitted prediction has spent some directions of the noise, the observed
statistics of a well-specified model are, if anything, smaller than those of white noise: the false-alarm
rate is at most `FALSE_ALARM` (0.01) by construction; `studies/fitcheck.py` measures it.

With an AR(1) noise model (`[model] noise = "ar1"`) the residuals are first whitened with the posterior median
coefficient (`uq.ar1.AR1Noise.whiten`): under that model the innovations, not the residuals, are white, and
both statistics are applied to them.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from ..data.measurements import Measurements

log = logging.getLogger(__name__)

#: the verdict fires when the Bonferroni-combined p-value falls below this
FALSE_ALARM = 0.01
#: white-noise replicates per statistic (p-value resolution 1 / REPLICATES)
REPLICATES = 2000
#: posterior draws averaged into the mean prediction
DRAWS = 200
#: smooth basis: Legendre degrees in x/L and t/T for scattered points, in t/T per strain gauge
SCATTER_DEGREE = 3
SERIES_DEGREE = 7
#: a basis needs at least this many residuals per column to leave the noise room
MIN_ROWS_PER_COLUMN = 4


def _legendre(u: np.ndarray, degree: int) -> np.ndarray:
    """Legendre polynomials P_0..P_degree at u in [-1, 1], columns."""
    return np.polynomial.legendre.legvander(np.clip(u, -1.0, 1.0), degree)


def _series(data: Measurements) -> list[np.ndarray]:
    """Row indices of each time series in time order: each strain gauge's, or all scattered points."""
    sensor = np.asarray(data.sensor).astype(str)
    strain = np.asarray(data.kind) == "strain"
    out = []
    for name in dict.fromkeys(sensor[strain]):
        rows = np.flatnonzero(strain & (sensor == name))
        out.append(rows[np.argsort(data.t[rows], kind="stable")])
    rest = np.flatnonzero(~strain)
    if rest.size:
        out.append(rest[np.argsort(data.t[rest], kind="stable")])
    return [r for r in out if r.size >= 3]


def smooth_basis(data: Measurements, length: float, duration: float) -> np.ndarray | None:
    """Orthonormal columns (n, k) spanning the smooth functions the check looks for, or None when the data
    are too few to leave the noise room (fewer than MIN_ROWS_PER_COLUMN rows per column)."""
    n = len(data)
    strain = np.asarray(data.kind) == "strain"
    xi = 2.0 * np.asarray(data.x, float) / length - 1.0
    tau = 2.0 * np.asarray(data.t, float) / max(duration, 1e-300) - 1.0
    blocks = []
    rest = np.flatnonzero(~strain)
    if rest.size:
        Px, Pt = _legendre(xi[rest], SCATTER_DEGREE), _legendre(tau[rest], SCATTER_DEGREE)
        B = np.zeros((n, Px.shape[1] * Pt.shape[1]))
        B[rest] = (Px[:, :, None] * Pt[:, None, :]).reshape(rest.size, -1)
        blocks.append(B)
    sensor = np.asarray(data.sensor).astype(str)
    for name in dict.fromkeys(sensor[strain]):
        rows = np.flatnonzero(strain & (sensor == name))
        B = np.zeros((n, SERIES_DEGREE + 1))
        B[rows] = _legendre(tau[rows], SERIES_DEGREE)
        blocks.append(B)
    if not blocks:
        return None
    B = np.concatenate(blocks, axis=1)
    if n < MIN_ROWS_PER_COLUMN * B.shape[1]:
        return None
    Q, R = np.linalg.qr(B)
    keep = np.abs(np.diag(R)) > 1e-10 * np.abs(np.diag(R)).max()
    return Q[:, keep]


def smooth_share(Q: np.ndarray, e: np.ndarray) -> np.ndarray:
    """||Q'e||^2 / ||e||^2 for residual vectors e (n,) or (r, n)."""
    e = np.atleast_2d(e)
    return np.sum((e @ Q) ** 2, axis=1) / np.sum(e**2, axis=1)


def lag1(series: list[np.ndarray], e: np.ndarray) -> np.ndarray:
    """Pooled lag-1 autocorrelation of each series' residuals (mean removed per series), for e (n,) or
    (r, n): sum over series of sum_i d_i d_{i+1} / sum over series of sum_i d_i^2."""
    e = np.atleast_2d(e)
    num = np.zeros(e.shape[0])
    den = np.zeros(e.shape[0])
    for rows in series:
        d = e[:, rows]
        d = d - d.mean(axis=1, keepdims=True)
        num += np.sum(d[:, 1:] * d[:, :-1], axis=1)
        den += np.sum(d**2, axis=1)
    return num / np.where(den > 0, den, 1.0)


def mean_prediction(
    post, data: Measurements, draws: int = DRAWS, seed: int = 0
) -> np.ndarray | None:
    """The posterior mean of the noise-free prediction at the data points (data units), or None."""
    if post.predictor is None or len(data) == 0:
        return None
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(7,)))
    strain = np.asarray(data.kind) == "strain"
    mu = np.empty(len(data))
    for quantity, rows in (("deflection", ~strain), ("curvature", strain)):
        if rows.any():
            r = np.asarray(post.predictor(data.x[rows], data.t[rows], quantity, draws, rng), float)
            m = r.mean(axis=0)
            mu[rows] = -data.y[rows] * m if quantity == "curvature" else m
    return mu


def _noise_ar1(post) -> float | None:
    """The posterior median of the AR(1) noise coefficient, or None for a white-noise model."""
    r = getattr(post, "noise_ar1", None)
    return None if r is None else float(np.median(r))


def check(
    post, data: Measurements, length: float, duration: float, *, seed: int = 0
) -> dict | None:
    """The fit check of one method's posterior on the data it explains (module docstring): the contract's
    `fit_check` entry, or None when the method has no predictor or the data are too few to check."""
    mu = mean_prediction(post, data, seed=seed)
    if mu is None or not np.all(np.isfinite(mu)):
        return None
    e = np.asarray(data.value, float) - mu
    rho_noise = _noise_ar1(post)
    if rho_noise is not None:  # AR(1) noise model: its innovations are what must be white
        from .ar1 import AR1Noise

        e = AR1Noise.of(data).whiten(e, rho_noise)
    n = e.size
    Q = smooth_basis(data, length, duration)
    series = _series(data)
    if Q is None and not series:
        return None
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(11,)))
    noise = rng.standard_normal((REPLICATES, n))
    p, stats = {}, {}
    if Q is not None:
        obs = float(smooth_share(Q, e)[0])
        rep = smooth_share(Q, noise)
        stats["smooth_share"] = obs
        stats["smooth_share_white"] = float(Q.shape[1] / n)
        p["smooth_structure"] = float((1 + np.sum(rep >= obs)) / (1 + REPLICATES))
    rho = float(lag1(series, e)[0]) if series else float("nan")
    if series:
        rep = lag1(series, noise)
        p["serial_correlation"] = float((1 + np.sum(rep >= rho)) / (1 + REPLICATES))
    combined = min(1.0, len(p) * min(p.values()))
    sigma = float(np.median(post.sigma)) if np.isfinite(post.sigma).any() else float("nan")
    std = e / sigma if sigma > 0 else e * math.nan
    return {
        "verdict": "misfit" if combined < FALSE_ALARM else "fits",
        "p_value": combined,
        "statistic": (
            "residuals at the posterior mean prediction against white noise: "
            + " and ".join(
                {
                    "smooth_structure": f"their energy share in {Q.shape[1] if Q is not None else 0} "
                    "smooth functions of x and t",
                    "serial_correlation": "their lag-1 autocorrelation in time order",
                }[k]
                for k in p
            )
            + f"; Bonferroni over {len(p)}, misfit below {FALSE_ALARM:g}"
        ),
        "residual_autocorr": rho,
        "p_values": p,
        **stats,
        "standardised_residual_rms": float(np.sqrt(np.mean(std**2))),
        **({"noise_ar1": rho_noise, "whitened": True} if rho_noise is not None else {}),
        "false_alarm": FALSE_ALARM,
    }
