"""Does the model fit? A check of each method's residuals for what the model says cannot be there, naming
what the data contradict so that a user knows what to do.

Every interval is conditional on the model (the girder as declared, the stated loads, white or AR(1)
Gaussian noise of one sd for every sensor). Where the data contradict it, the residuals y - mu at the
posterior mean prediction mu keep a trace of what the model cannot explain. Three statistics look for the
three traces a user can act on (`uq.fitcheck_stats` defines them):

* `smooth_structure`: residual energy in a smooth basis in time (and position, for scattered points) at the
  crossing's own time scales, beyond what the fitted noise model leaves there: the model's shape misses the
  response (a wrong speed or entry time, a bouncing vehicle, a support or a stiffness the model lacks).
  Under AR(1) noise this is what AR(1) with the fitted coefficient cannot explain: AR(1) noise alone gives
  the low band no more than its share, however strong its coefficient;
* `serial_correlation`: consecutive residuals correlated where the model assumes white noise (filtered,
  smoothed or baseline-adjusted records), or, under AR(1), whitened residuals still correlated over several
  samples;
* `one_sensor`: one sensor's residuals much larger than the others' (a gauge off its calibration, its
  position, or its fixing).

With several crossings (the data's `crossing` labels) the same statistics are taken per crossing, and the
worst crossing's, taken over crossings, is a statistic too, so one bad crossing among many is not diluted.

Calibration: a parametric bootstrap of the fitted model (`REPLICATES` residual sets: the fitted noise
model's noise at its fitted sd and coefficient, less the share the fit itself absorbs, the AR(1)
coefficient refitted), not white noise. The observed residuals and the replicates are exchangeable under
the fitted model, so each statistic's p-value is its rank, with resolution 1 / (REPLICATES + 1); the
combined p-value is the rank of the smallest p-value among the replicates' smallest (min-p), so the
verdict `misfit` (combined p < `FALSE_ALARM`) fires on data the model describes at the rate FALSE_ALARM,
whatever the number of statistics. `studies/fitcheck_calibration.py` measures that rate for each method.
"""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np

from ..data.measurements import Measurements
from . import fitcheck_stats as fs
from .fitcheck_text import detail, statistic_text

log = logging.getLogger(__name__)

#: the verdict fires when the combined p-value falls below this
FALSE_ALARM = 0.01
#: parametric-bootstrap replicates (p-value resolution 1 / (REPLICATES + 1))
REPLICATES = 999
#: posterior draws averaged into the mean prediction (their spread gives the fit's hat matrix)
DRAWS = 200
#: posterior draws (the same for both) of the predictions a time step apart whose difference gives the
#: timing band's directions, and that step [s]
TIMING_DRAWS = 32
TIME_STEP = 1e-3
#: the reasons a misfit can name, in the order a user should act on them
REASONS = ("smooth_structure", "serial_correlation", "one_sensor")


def prediction_draws(
    post, data: Measurements, draws: int = DRAWS, seed: int = 0
) -> np.ndarray | None:
    """Noise-free predictions (draws, P) at the data points (data units) for posterior draws, or None."""
    if post.predictor is None or len(data) == 0:
        return None
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(7,)))
    strain = np.asarray(data.kind) == "strain"
    parts = []
    for quantity, rows in (("deflection", ~strain), ("curvature", strain)):
        if rows.any():
            r = np.atleast_2d(
                np.asarray(post.predictor(data.x[rows], data.t[rows], quantity, draws, rng), float)
            )
            parts.append((rows, -data.y[rows] * r if quantity == "curvature" else r))
    # a predictor may return fewer draws than asked (an ensemble: a whole number per member) or one
    # row (a point prediction): use what every quantity has
    n = min((r.shape[0] for _, r in parts if r.shape[0] > 1), default=1)
    out = np.empty((n, len(data)))
    for rows, r in parts:
        out[:, rows] = r[:n] if r.shape[0] > 1 else np.broadcast_to(r, (n, int(rows.sum())))
    return out


def mean_prediction(
    post, data: Measurements, draws: int = DRAWS, seed: int = 0
) -> np.ndarray | None:
    """The posterior mean of the noise-free prediction at the data points (data units), or None."""
    d = prediction_draws(post, data, draws, seed)
    return None if d is None else d.mean(axis=0)


def time_derivative(
    post, data: Measurements, groups: np.ndarray, seed: int = 0
) -> np.ndarray | None:
    """d mu / dt of the posterior mean prediction at the data points, by a central difference of TIME_STEP
    (one-sided at each crossing's first and last sample: groups labels the rows by crossing), the same
    posterior draws on both sides; None without a predictor."""
    t = np.asarray(data.t, float)
    lo, hi = t.copy(), t.copy()
    for c in np.unique(groups):
        m = groups == c
        lo[m] = np.maximum(t[m] - TIME_STEP, t[m].min())
        hi[m] = np.minimum(t[m] + TIME_STEP, t[m].max())
    plus = mean_prediction(post, dataclasses.replace(data, t=hi), TIMING_DRAWS, seed)
    minus = mean_prediction(post, dataclasses.replace(data, t=lo), TIMING_DRAWS, seed)
    if plus is None or minus is None:
        return None
    return (plus - minus) / np.where(hi > lo, hi - lo, np.inf)


def _timing(post, data, series, order, blocks, hat, rho, seed, cross) -> list:
    """Per crossing of the series (in their order): its slice of the series order and its timing band."""
    groups = np.full(len(data), "") if cross is None else cross
    d = time_derivative(post, data, groups, seed)
    out = []
    start = 0
    t = np.asarray(data.t, float)
    for c in dict.fromkeys(s.crossing for s in series):
        size = sum(s.rows.size for s in series if s.crossing == c)
        sl = slice(start, start + size)
        start += size
        if d is None or not np.all(np.isfinite(d)):
            out.append((sl, np.zeros((size, 0))))
            continue
        m = groups == c
        D = np.stack([np.where(m, d, 0.0), np.where(m, (t - t[m].min()) * d, 0.0)], axis=1)
        out.append((sl, fs.timing_band(D[order], sl, hat, rho, blocks)))
    return out


def _noise_ar1(post) -> float | None:
    """The posterior median of the AR(1) noise coefficient, or None for a white-noise model."""
    r = getattr(post, "noise_ar1", None)
    return None if r is None else float(np.median(r))


def crossings_of(data: Measurements) -> np.ndarray | None:
    """The data's crossing labels (str), or None for one crossing (no `crossing` column, or one label)."""
    c = getattr(data, "crossing", None)
    if c is None:
        return None
    c = np.asarray(c).astype(str)
    return c if np.unique(c).size > 1 else None


class _Statistics:
    """The statistics of the observed residuals (row 0) and of the replicates, by name; names of the
    form `<reason>` (all data), `<reason>@<crossing>` and `<reason>@worst` (several crossings)."""

    def __init__(
        self, sums: fs.Sums, series: list[fs.Series], ar1: bool, crossings: list[str], timing: list
    ):
        self.values: dict[str, np.ndarray] = {}
        self.bands: dict[str, float] = {}
        self.sensor_names: dict[str, list[str]] = {}
        self.sensor_ratios: dict[str, np.ndarray] = {}
        groups = {"": np.ones(len(series), bool)}
        if len(crossings) > 1:
            for c in crossings:
                groups["@" + c] = np.array([s.crossing == c for s in series])
        for tag, g in groups.items():
            if not g.any():
                continue
            v, bands = fs.smooth_statistic(sums, series, g, timing, crossings)
            self._add("smooth_structure" + tag, v)
            if tag == "":  # each band's own p-value, to say which kind of shape the residuals keep
                cols = [j for j in range(bands.shape[1]) if np.isfinite(bands[0, j])]
                if cols:
                    P = fs.rank_p(bands[:, cols])[0]
                    self.bands = {fs.BANDS[j]: float(q) for j, q in zip(cols, P, strict=True)}
            self._add("serial_correlation" + tag, fs.serial_statistic(sums, series, g, ar1))
            ratios, names = fs.sensor_statistic(sums, series, g)
            if names:
                self._add("one_sensor" + tag, ratios.max(axis=1))
                self.sensor_names[tag], self.sensor_ratios[tag] = names, ratios[0]
        if len(crossings) > 1:  # the worst crossing, per reason, is a statistic of its own: the
            # largest of the crossings' statistics standardised by their replicates' mean and sd
            for reason in REASONS:
                cols = [k for k in self.values if k.startswith(reason + "@")]
                if cols:
                    V = np.stack([self.values[k] for k in cols], axis=1)
                    ref = np.where(np.isfinite(V[1:]), V[1:], np.nan)
                    z = (V - np.nanmean(ref, axis=0)) / np.maximum(np.nanstd(ref, axis=0), 1e-300)
                    self.values[reason + "@worst"] = np.nanmax(
                        np.nan_to_num(z, neginf=-1e300), axis=1
                    )

    def _add(self, name: str, v: np.ndarray) -> None:
        if np.isfinite(v[0]):
            self.values[name] = v


def check(
    post, data: Measurements, length: float, duration: float, *, seed: int = 0
) -> dict | None:
    """The fit check of one method's posterior on the data it explains (module docstring): the contract's
    `fit_check` entry, or None when the method has no predictor or the data are too few to check.

    Keys: verdict, p_value (combined), statistic, residual_autocorr (lag-1, of the whitened residuals under
    AR(1)), reasons (what a misfit contradicts: "smooth_structure", "serial_correlation",
    "one_sensor:<name>", "crossing:<name>"; empty when the data fit), detail (one sentence saying so),
    p_values per reason, p_value_resolution and p_value_se (Monte Carlo), replicates; with several
    crossings by_crossing {name: {verdict, p_value, reasons}} and worst_crossing."""
    draws = prediction_draws(post, data, seed=seed)
    if draws is None or not np.all(np.isfinite(draws)):
        return None
    mu = draws.mean(axis=0)
    e = np.asarray(data.value, float) - mu
    rho_fit = _noise_ar1(post)
    cross = crossings_of(data)
    series = fs.layout(data.x, data.t, data.sensor, cross, length, duration)
    if not series:
        return None
    sig = np.asarray(post.sigma, float)
    sigma = float(np.median(sig[np.isfinite(sig)])) if np.isfinite(sig).any() else float("nan")
    order, blocks = fs.order_of(series)
    directions = fs.hat_directions(draws[:, order], sigma, rho_fit, blocks)
    timing = _timing(post, data, series, order, blocks, directions[0], rho_fit, seed, cross)
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(11,)))
    sums, rho_white = fs.bootstrap_sums(e, series, directions, rho_fit, REPLICATES, rng, timing)
    crossings = list(dict.fromkeys(s.crossing for s in series))
    st = _Statistics(sums, series, rho_fit is not None, crossings, timing)
    if not st.values:
        return None
    names = list(st.values)
    P = fs.rank_p(np.stack([st.values[k] for k in names], axis=1))
    p = dict(zip(names, P[0], strict=True))
    # the combined p-value (min-p): the verdict's statistics are those of all the data and the worst crossing
    top = [j for j, k in enumerate(names) if "@" not in k or k.endswith("@worst")]
    pmin = P[:, top].min(axis=1)
    combined = float(np.mean(pmin <= pmin[0]))
    floor = float(np.mean(pmin <= pmin.min()))
    B = REPLICATES
    g = np.ones(len(series), bool)
    rho1 = float(fs.autocorrelations(sums, g)[0, 0])
    n_basis = sum(s.low.shape[1] + s.mid.shape[1] for s in series)
    n_timing = sum(G.shape[1] for _, G in timing)
    n_used = sum(s.rows.size for s in series)
    smooth_e = float(sums.low[0].sum() + sums.mid[0].sum())
    std = e / sigma if sigma > 0 else e * math.nan
    verdict = "misfit" if combined < FALSE_ALARM else "fits"
    by_crossing = _by_crossing(P, names, crossings, st) if len(crossings) > 1 else {}
    reasons = _reasons(p, st, verdict, by_crossing)
    out = {
        "verdict": verdict,
        "p_value": combined,
        "statistic": statistic_text(
            list(st.values), rho_fit is not None, len(crossings), n_basis, n_timing, B, FALSE_ALARM
        ),
        "residual_autocorr": rho1,
        "reasons": reasons,
        "detail": "",
        "p_values": {k: float(v) for k, v in p.items() if "@" not in k},
        "p_value_resolution": 1.0 / (B + 1),
        "p_value_floor": floor,
        "p_value_se": math.sqrt(max(combined * (1 - combined), 1.0 / (B + 1)) / B),
        "replicates": B,
        "null": "ar1" if rho_fit is not None else "white",
        "hat_directions": int(directions[1].size),
        "smooth_share": smooth_e / max(float(sums.energy[0].sum()), 1e-300),
        "smooth_share_white": n_basis / max(n_used, 1),
        "smooth_bands": st.bands,
        "smooth_band": min(st.bands, key=st.bands.get) if st.bands else None,
        "standardised_residual_rms": float(np.sqrt(np.mean(std**2))),
        **(
            {"noise_ar1": rho_fit, "whitening_ar1": rho_white, "whitened": True}
            if rho_fit is not None
            else {}
        ),
        "false_alarm": FALSE_ALARM,
    }
    if "" in st.sensor_names:
        names_s, ratios = st.sensor_names[""], st.sensor_ratios[""]
        j = int(np.argmax(ratios))
        out["worst_sensor"] = {"name": names_s[j], "variance_ratio": float(math.exp(ratios[j]))}
    if len(crossings) > 1:
        out["by_crossing"] = by_crossing
        worst = min(out["by_crossing"], key=lambda c: out["by_crossing"][c]["p_value"])
        out["worst_crossing"] = worst
        if "smooth_structure@worst" in p:
            out["p_values"]["worst_crossing"] = float(
                min(p[r + "@worst"] for r in REASONS if r + "@worst" in p)
            )
    out["detail"] = detail(out)
    return out


def _reasons(p: dict, st: _Statistics, verdict: str, by_crossing: dict) -> list[str]:
    """What a misfit contradicts: each reason whose own p-value (all data, or the worst crossing) is
    below FALSE_ALARM, in REASONS order; the one sensor and the worst crossing named, and when the worst
    crossing is what fails, its own reasons too."""
    if verdict != "misfit":
        return []
    out = []
    for r in REASONS:
        if min(p.get(r, 1.0), p.get(r + "@worst", 1.0)) >= FALSE_ALARM:
            continue
        if r == "one_sensor":
            tag = "" if p.get("one_sensor", 1.0) < FALSE_ALARM else _worst_tag(p, "one_sensor")
            if tag in st.sensor_names:
                ratios = st.sensor_ratios[tag]
                out.append(f"one_sensor:{st.sensor_names[tag][int(np.argmax(ratios))]}")
        else:
            out.append(r)
    worst = [k for k in p if k.endswith("@worst") and p[k] < FALSE_ALARM]
    if worst:
        tag = _worst_tag(p, min(worst, key=p.get).split("@")[0])
        own = by_crossing.get(tag[1:], {}).get("reasons", [])
        out += [r for r in own if r not in out and r.split(":")[0] not in out]
        out.append(f"crossing:{tag[1:]}")
    if not out:  # the combined p fell below the rate through the smallest p-value: name its reason
        k = min(p, key=p.get).split("@")[0]
        out.append(k)
    return out


def _worst_tag(p: dict, reason: str) -> str:
    tags = [k[len(reason) :] for k in p if k.startswith(reason + "@") and not k.endswith("@worst")]
    return min(tags, key=lambda t: p[reason + t]) if tags else ""


def _by_crossing(P, names, crossings, st) -> dict:
    """Each crossing's own verdict: its statistics' min-p among the replicates'."""
    out = {}
    for c in crossings:
        cols = [j for j, k in enumerate(names) if k.endswith("@" + c)]
        if not cols:
            continue
        pmin = P[:, cols].min(axis=1)
        pc = float(np.mean(pmin <= pmin[0]))
        own = {names[j].split("@")[0]: float(P[0, j]) for j in cols}
        reasons = [r for r in REASONS if own.get(r, 1.0) < FALSE_ALARM]
        if "one_sensor" in reasons and "@" + c in st.sensor_names:
            k = st.sensor_names["@" + c][int(np.argmax(st.sensor_ratios["@" + c]))]
            reasons[reasons.index("one_sensor")] = f"one_sensor:{k}"
        out[c] = {
            "verdict": "misfit" if pc < FALSE_ALARM else "fits",
            "p_value": pc,
            "p_values": own,
            "reasons": reasons if pc < FALSE_ALARM else [],
        }
    return out
