"""The fit check's statistics and their parametric bootstrap (`uq.fitcheck` explains what they are for).

The residuals are read in series: each named sensor's samples of one crossing, in time order, and the
unnamed (scattered) points of one crossing together, in time order. Every statistic is a function of a few
sums per series, so the same sums give the statistic of all the data, of one crossing or of one sensor:

* smooth structure: per series an orthonormal smooth basis in two bands; for a sensor's series the cosines
  cos(pi j (t - t0) / D) over its record (D long), j < `LOW_COLUMNS` (the crossing's own time scale: a
  wrong speed or entry time, a support, a softer segment) and `LOW_COLUMNS` <= j < `SERIES_COLUMNS` (up to
  about 5 Hz over a 3 s crossing: a vehicle bouncing on its suspension); for scattered points the products
  of Legendre polynomials of degree <= `SCATTER_DEGREE` in x/L and t/T. Per band the F ratio of the
  residuals' energy in the band per column to their energy outside the basis per remaining sample,
  standardised as (F - 1) sqrt(k / 2); the statistic is the larger band's.
* serial correlation: under white noise the pooled lag-1 autocorrelation times sqrt(n) (one-sided); under
  AR(1) noise, where the whitened residuals' lag-1 autocorrelation is zero by construction, the
  portmanteau n sum_{l <= LAGS} r_l^2 of the whitened residuals.
* one sensor: the largest log ratio of one sensor's (whitened) residual variance to the other sensors'.

Under AR(1) noise the residuals are whitened with the coefficient re-estimated from them (pooled
conditional least squares, `estimate_ar1`), so that what is compared is what AR(1) with the fitted
coefficient would leave; the smooth basis itself is not whitened (for smooth functions the whitening
filter is nearly a constant gain, and the bootstrap calibrates whatever small difference remains).

The null distribution is a parametric bootstrap of the fitted model: innovations z ~ N(0, 1), the fit's
share of them removed through its hat matrix (`hat_directions`: for a linear-Gaussian model the posterior
covariance of the mean prediction is sigma^2 times the hat matrix, so its leading directions and
leverages come from the posterior's own prediction draws), coloured by AR(1) at the fitted coefficient,
the coefficient refitted and the statistic recomputed. The observed residuals and the replicates are then
exchangeable under the fitted model, so a p-value is a rank among them (`rank_p`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

#: cosine columns per sensor series: the low band, and all bands together
LOW_COLUMNS = 8
SERIES_COLUMNS = 32
#: scattered points: Legendre degree in x/L and in t/T
SCATTER_DEGREE = 3
#: a basis needs at least this many residuals per column to leave the noise room
MIN_ROWS_PER_COLUMN = 4
#: lags of the portmanteau statistic under AR(1) noise
LAGS = 5
#: the fitted coefficient's bound (as `uq.ar1.RHO_MAX`)
RHO_MAX = 0.999
#: hat-matrix directions: at most this many, each with leverage at least MIN_LEVERAGE
MAX_DIRECTIONS = 10
MIN_LEVERAGE = 0.02
#: replicates simulated per pass (bounds the memory of a long record)
CHUNK = 256


@dataclass(frozen=True)
class Series:
    """One series of the residuals: rows in time order, its sensor ('' for scattered points), its
    crossing, and its smooth basis's two bands (orthonormal columns, (rows, k))."""

    rows: np.ndarray
    sensor: str
    crossing: str
    low: np.ndarray
    mid: np.ndarray


def _legendre(u: np.ndarray, degree: int) -> np.ndarray:
    return np.polynomial.legendre.legvander(np.clip(u, -1.0, 1.0), degree)


def _orthonormal(B: np.ndarray) -> np.ndarray:
    """Orthonormal columns spanning B's columns in order (rank-deficient columns dropped)."""
    if B.shape[1] == 0:
        return B
    Q, R = np.linalg.qr(B)
    d = np.abs(np.diag(R))
    return Q[:, d > 1e-10 * max(d.max(), 1e-300)]


def _cosine_bands(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = t.size
    k = min(SERIES_COLUMNS, n // MIN_ROWS_PER_COLUMN)
    span = float(t.max() - t.min())
    if k == 0 or span <= 0:
        return np.zeros((n, 0)), np.zeros((n, 0))
    u = (t - t.min()) / span
    B = np.cos(np.pi * np.outer(u, np.arange(k)))
    Q, R = np.linalg.qr(B)
    d = np.abs(np.diag(R))
    keep = d > 1e-10 * d.max()
    low = min(LOW_COLUMNS, k)
    return Q[:, :low][:, keep[:low]], Q[:, low:][:, keep[low:]]


def _scatter_band(x: np.ndarray, t: np.ndarray, length: float, t0: float, t1: float) -> np.ndarray:
    n = x.size
    for degree in range(SCATTER_DEGREE, 0, -1):
        if n >= MIN_ROWS_PER_COLUMN * (degree + 1) ** 2:
            Px = _legendre(2.0 * x / length - 1.0, degree)
            Pt = _legendre(2.0 * (t - t0) / max(t1 - t0, 1e-300) - 1.0, degree)
            return _orthonormal((Px[:, :, None] * Pt[:, None, :]).reshape(n, -1))
    return np.zeros((n, 0))


def layout(x, t, sensor, crossing, length: float, duration: float) -> list[Series]:
    """The series of a measurement set (module docstring); series of fewer than 3 rows are left out."""
    x, t = np.asarray(x, float), np.asarray(t, float)
    sensor = np.asarray(sensor).astype(str)
    crossing = np.full(t.size, "") if crossing is None else np.asarray(crossing).astype(str)
    single = np.unique(crossing).size <= 1
    out = []
    for c in dict.fromkeys(crossing.tolist()):
        in_c = crossing == c
        for name in dict.fromkeys(sensor[in_c].tolist()):
            rows = np.flatnonzero(in_c & (sensor == name))
            rows = rows[np.argsort(t[rows], kind="stable")]
            if rows.size < 3:
                continue
            tr = t[rows]
            if name:
                low, mid = _cosine_bands(tr)
            else:  # scattered points: one crossing's time window (the stated duration for one crossing)
                t0 = min(0.0, tr.min()) if single else tr.min()
                t1 = max(duration, tr.max()) if single else tr.max()
                low, mid = _scatter_band(x[rows], tr, length, t0, t1), np.zeros((rows.size, 0))
            out.append(Series(rows, name, c, low, mid))
    return out


def order_of(series: list[Series]) -> tuple[np.ndarray, list[slice]]:
    """The rows of all series, series after series, and each series' slice of that order: the
    bootstrap works in this order, where every series is a contiguous block."""
    order = np.concatenate([s.rows for s in series])
    stops = np.cumsum([s.rows.size for s in series])
    return order, [slice(int(b - s.rows.size), int(b)) for s, b in zip(series, stops, strict=True)]


def estimate_ar1(e: np.ndarray, blocks: list[slice]) -> np.ndarray:
    """The AR(1) coefficient of residuals e (R, n) in series order, pooled over the blocks:
    sum e_k e_(k-1) / sum e_(k-1)^2 (conditional least squares), bounded by RHO_MAX."""
    num = np.zeros(e.shape[0])
    den = np.zeros(e.shape[0])
    for b in blocks:
        eb = e[:, b]
        num += np.einsum("ij,ij->i", eb[:, 1:], eb[:, :-1])
        den += np.einsum("ij,ij->i", eb[:, :-1], eb[:, :-1])
    return np.clip(num / np.where(den > 0, den, 1.0), -RHO_MAX, RHO_MAX)


def whiten(e: np.ndarray, rho: np.ndarray, blocks: list[slice]) -> np.ndarray:
    """Innovations of residuals e (R, n) in series order under coefficients rho (R,): u_1 = e_1 and
    u_k = (e_k - rho e_(k-1)) / sqrt(1 - rho^2) along each block."""
    rho = np.asarray(rho, float)[:, None]
    c = 1.0 / np.sqrt(1.0 - rho**2)
    u = e.copy()
    for b in blocks:
        eb = e[:, b]
        u[:, b][:, 1:] = (eb[:, 1:] - rho * eb[:, :-1]) * c
    return u


def colour(z: np.ndarray, rho: float, blocks: list[slice]) -> np.ndarray:
    """Stationary AR(1) series of unit marginal variance from innovations z (R, n) in series order:
    whiten's inverse."""
    x = z.copy()
    c = math.sqrt(1.0 - rho * rho)
    for b in blocks:
        zb = z[:, b]
        x[:, b][:, 1:] = lfilter([c], [1.0, -rho], zb[:, 1:], axis=1, zi=rho * zb[:, :1])[0]
    return x


def hat_directions(
    draws: np.ndarray, sigma: float, rho: float | None, blocks: list[slice]
) -> tuple[np.ndarray, np.ndarray]:
    """The fit's leading hat-matrix directions (n, r) and leverages (r,) in the whitened metric, from
    prediction draws (d, n) in series order at posterior draws: cov(prediction) / sigma^2 (module
    docstring), through the eigenvectors of the draws' small (d, d) Gram matrix."""
    d, n = draws.shape
    if d < 2 or not (sigma > 0):
        return np.zeros((n, 0)), np.zeros(0)
    D = draws - draws.mean(axis=0)
    if rho is not None:
        D = whiten(D, np.full(d, rho), blocks)
    D = D / (sigma * math.sqrt(d - 1))
    h, W = np.linalg.eigh(D @ D.T)
    keep = np.flatnonzero(h >= MIN_LEVERAGE)[::-1][:MAX_DIRECTIONS]
    if keep.size == 0:
        return np.zeros((n, 0)), np.zeros(0)
    U = D.T @ W[:, keep] / np.sqrt(h[keep])
    return U, np.minimum(h[keep], 1.0)


@dataclass
class Sums:
    """Per-series sums (R, S) of residual sets (R of them) from which every statistic follows."""

    energy: np.ndarray
    low: np.ndarray
    mid: np.ndarray
    centred: np.ndarray
    lagged: np.ndarray  # (R, S, LAGS)
    timing: np.ndarray  # (R, crossings): energy in each crossing's timing band

    @classmethod
    def of(cls, u: np.ndarray, series: list[Series], blocks: list[slice], timing: list) -> Sums:
        """The sums of residual sets u (R, n) in series order; timing: per crossing (slice, columns)."""
        R, S = u.shape[0], len(series)
        out = cls(
            *(np.zeros((R, S)) for _ in range(4)),
            np.zeros((R, S, LAGS)),
            np.zeros((R, len(timing))),
        )
        for c, (b, G) in enumerate(timing):
            out.timing[:, c] = np.sum((u[:, b] @ G) ** 2, axis=1)
        for j, (s, b) in enumerate(zip(series, blocks, strict=True)):
            us = u[:, b]
            out.energy[:, j] = np.sum(us**2, axis=1)
            out.low[:, j] = np.sum((us @ s.low) ** 2, axis=1)
            out.mid[:, j] = np.sum((us @ s.mid) ** 2, axis=1)
            d = us - us.mean(axis=1, keepdims=True)
            out.centred[:, j] = np.sum(d**2, axis=1)
            for lag in range(1, min(LAGS, s.rows.size - 1) + 1):
                out.lagged[:, j, lag - 1] = np.sum(d[:, lag:] * d[:, :-lag], axis=1)
        return out

    @classmethod
    def concat(cls, parts: list[Sums]) -> Sums:
        return cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in cls.__annotations__))


def smooth_statistic(
    sums: Sums, series: list[Series], g: np.ndarray, timing: list, crossings: list[str]
) -> tuple[np.ndarray, np.ndarray]:
    """Smooth structure in the series g (boolean (S,)): the largest band's standardised F ratio (R,), or
    -inf where no band has columns, and each band's (R, len(BANDS)), -inf for a band without columns."""
    sel = [s for s, k in zip(series, g, strict=True) if k]
    n = sum(s.rows.size for s in sel)
    kl = sum(s.low.shape[1] for s in sel)
    km = sum(s.mid.shape[1] for s in sel)
    inside = {s.crossing for s in sel}
    tc = [j for j, c in enumerate(crossings) if c in inside]
    kt = sum(timing[j][1].shape[1] for j in tc)
    R = sums.energy.shape[0]
    bands = np.full((R, len(BANDS)), -np.inf)
    if kl + km + kt == 0 or n - kl - km <= 0:
        return bands.max(axis=1), bands
    el, em = sums.low[:, g].sum(1), sums.mid[:, g].sum(1)
    et = sums.timing[:, tc].sum(1)
    rest = np.maximum(sums.energy[:, g].sum(1) - el - em, 1e-300) / (n - kl - km)
    for i, (e, k) in enumerate(((et, kt), (el, kl), (em, km))):
        if k:
            bands[:, i] = (e / k / rest - 1.0) * math.sqrt(k / 2.0)
    return bands.max(axis=1), bands


#: the smooth statistic's bands, as `smooth_statistic` indexes them
BANDS = ("timing", "low", "mid")


def timing_band(
    directions: np.ndarray,
    rows: np.ndarray,
    hat: np.ndarray,
    rho: float | None,
    blocks: list[slice],
) -> np.ndarray:
    """One crossing's timing band: orthonormal columns (rows, k) in the whitened metric spanning the
    directions (n, 2) in series order (the response shifted and stretched in time), less the fit's hat
    directions (n, r): what a stated speed or entry time that is off leaves in the residuals."""
    D = directions.T.copy()
    if rho is not None:
        D = whiten(D, np.full(D.shape[0], rho), blocks)
    D = D.T
    if hat.shape[1]:
        D = D - hat @ (hat.T @ D)
    D = D[rows]
    norms = np.linalg.norm(D, axis=0)
    D = D[:, norms > 1e-9 * max(norms.max(), 1e-300)] if norms.size else D
    return _orthonormal(D)


def autocorrelations(sums: Sums, g: np.ndarray) -> np.ndarray:
    """Pooled autocorrelations at lags 1..LAGS (R, LAGS) of the series g."""
    den = sums.centred[:, g].sum(1)
    return sums.lagged[:, g, :].sum(1) / np.where(den > 0, den, 1.0)[:, None]


def serial_statistic(sums: Sums, series: list[Series], g: np.ndarray, ar1: bool) -> np.ndarray:
    """Serial correlation in the series g: sqrt(n) r_1 (white noise) or n sum r_l^2 (AR(1))."""
    n = sum(s.rows.size for s, k in zip(series, g, strict=True) if k)
    r = autocorrelations(sums, g)
    return n * np.sum(r**2, axis=1) if ar1 else math.sqrt(n) * r[:, 0]


def sensor_statistic(
    sums: Sums, series: list[Series], g: np.ndarray
) -> tuple[np.ndarray, list[str]]:
    """One sensor worse than the rest, in the series g: per named sensor (over crossings) the log ratio of
    its residual variance to the others' (R, sensors), and the sensors' names; none below two sensors."""
    names = list(dict.fromkeys(s.sensor for s, k in zip(series, g, strict=True) if k and s.sensor))
    if len(names) < 2:
        return np.zeros((sums.energy.shape[0], 0)), []
    cols = []
    total_e = sums.energy[:, g].sum(1)
    total_n = sum(s.rows.size for s, k in zip(series, g, strict=True) if k)
    for name in names:
        m = g & np.array([s.sensor == name for s in series])
        e, n = (
            sums.energy[:, m].sum(1),
            sum(s.rows.size for s, k in zip(series, m, strict=True) if k),
        )
        cols.append(np.log(e / n) - np.log(np.maximum(total_e - e, 1e-300) / (total_n - n)))
    return np.stack(cols, axis=1), names


def rank_p(values: np.ndarray) -> np.ndarray:
    """Upper-tail p-values of each of the R exchangeable values (R, J) among its column:
    #{values >= it} / R (the observed set is row 0; R - 1 replicates give a resolution of 1 / R)."""
    R = values.shape[0]
    out = np.empty_like(values, dtype=float)
    for j in range(values.shape[1]):
        col = np.nan_to_num(values[:, j], nan=-np.inf)
        srt = np.sort(col)
        out[:, j] = (R - np.searchsorted(srt, col, side="left")) / R
    return out


def bootstrap_sums(
    e: np.ndarray,
    series: list[Series],
    directions: tuple[np.ndarray, np.ndarray],
    rho: float | None,
    replicates: int,
    rng: np.random.Generator,
    timing: list,
) -> tuple[Sums, float | None]:
    """The sums of the observed residuals e (n,) (row 0) and of `replicates` residual sets of the fitted
    model (module docstring), and the coefficient the observed residuals were whitened with. `directions`
    are in series order (`hat_directions` of draws in that order); timing: per crossing (slice of the
    series order, `timing_band` columns)."""
    order, blocks = order_of(series)
    V, h = directions
    e = e[None, order]
    rho_obs = None
    if rho is not None:
        rho_obs = float(estimate_ar1(e, blocks)[0])
        e = whiten(e, np.array([rho_obs]), blocks)
    parts = [Sums.of(e, series, blocks, timing)]
    done = 0
    while done < replicates:
        m = min(CHUNK, replicates - done)
        z = rng.standard_normal((m, order.size))
        if h.size:
            z = z - ((z @ V) * h) @ V.T
        if rho is not None:
            x = colour(z, rho, blocks)
            z = whiten(x, estimate_ar1(x, blocks), blocks)
        parts.append(Sums.of(z, series, blocks, timing))
        done += m
    return Sums.concat(parts), rho_obs
