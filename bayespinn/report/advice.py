"""What to do about a misfit: the one model extension the residuals point to.

The fit check (`uq.fitcheck`) says *whether* the residuals keep structure the model cannot leave; a user
then needs *which* extension of the model would explain it. Each extension the toolkit can infer changes
the predicted response along a few known directions at the data points: rotational springs at the
supports (left, right), EI per segment, a speed or entry time that is off, an axle force that fluctuates
in time. For each extension the model does not already infer, this module takes those directions
(the finite-element response with the extension at a typical size, minus the model's, at the method's
posterior mean EI: secants rather than derivatives, because an extension's first-order effect often
hides in EI's own direction, as a stiff bearing's does, and shows its shape only at its real size) and asks how
much of the residuals' energy they explain beyond EI's own direction. Under the model the explained
energy over sigma^2 is chi^2 with as many degrees of freedom as directions (a score test of the
extension); the extension with the smallest p-value is the advice. Serial correlation without smooth
structure points to the noise model instead, and one sensor out of line with the others to that sensor
(the fit check's own statistics and reasons decide those two).

Nothing here is per example: the candidates, their directions and the test are the same for every run.
Finite-element solves cost about half a second each, so the diagnosis runs only for a misfit.
"""

from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass, replace

import numpy as np

log = logging.getLogger(__name__)

#: an extension is advised only when its score test is below this (the fit check's own false-alarm rate)
SIGNIFICANT = 0.01
#: sizes of the secants: a rotational spring of 4 EI / L (the end stiffness a clamped far end gives), a
#: segment 20 % softer, the speed 2 % off, the clock shifted by 1 % of the crossing
SPRING_EI_L, SEGMENT_DROP, SPEED_STEP, CLOCK_STEP = 4.0, 0.2, 0.02, 0.01
#: segments of the EI-per-segment candidate, Legendre degrees of the fluctuating-force candidate
SEGMENTS, FORCE_DEGREE = 5, 4


@dataclass(frozen=True)
class Advice:
    """The next step for a misfit: `text` (what to declare, with the TOML key), `cause` (what the
    residuals point to, in words), `share` (fraction of the residuals' energy the extension explains),
    `p_value` of its score test (None when the choice came from the fit check's statistics alone)."""

    text: str
    cause: str
    share: float | None = None
    p_value: float | None = None


#: what to write when the residuals point to no extension the toolkit has
GENERIC = Advice(
    "look at the residual figure for what the model leaves unexplained (a sensor, a support, the loads) "
    "before using EI",
    "structure that no extension of the model the toolkit infers explains",
)


def _p_values(fc: dict) -> dict:
    p = fc.get("p_values")
    return p if isinstance(p, dict) else {}


def sensor_advice(fc: dict) -> Advice | None:
    """One sensor out of line with the others (the fit check's `one_sensor:<name>` reason) and no smooth
    structure: a loose gauge, a wrong position or a wrong fibre distance, not the girder."""
    reasons = fc.get("reasons") if isinstance(fc.get("reasons"), list) else []
    named = [str(r).split(":", 1)[1] for r in reasons if str(r).startswith("one_sensor:")]
    if not named or "smooth_structure" in reasons:
        return None
    ws = fc.get("worst_sensor") if isinstance(fc.get("worst_sensor"), dict) else {}
    ratio = ws.get("variance_ratio") if ws.get("name") == named[0] else None
    times = f" ({float(ratio):.1f} times the others' residual variance)" if ratio else ""
    return Advice(
        f"check sensor {named[0]} (its position, fibre distance and fixing) or leave its rows out of "
        "the file",
        f"one sensor, {named[0]}, out of line with the others{times}",
    )


def noise_advice(fc: dict, cfg) -> Advice | None:
    """Correlated noise when the fit check's serial correlation is significant and its smooth structure is
    not: that pattern is what smoothed or baseline-adjusted records leave, not a wrong girder."""
    p = _p_values(fc)
    serial, smooth = p.get("serial_correlation"), p.get("smooth_structure")
    if serial is None or serial >= SIGNIFICANT or (smooth is not None and smooth < SIGNIFICANT):
        return None
    if getattr(cfg.model, "noise", "iid") != "iid":
        return None
    return Advice(
        'model the noise as correlated in time (`[model] noise = "ar1"`)',
        f"noise correlated in time (lag-1 autocorrelation "
        f"{float(fc.get('residual_autocorr', float('nan'))):+.2f}) without a smooth shape",
        p_value=serial,
    )


#: the finite-element model of the diagnosis: coarser than the reference's (its directions are
#: differences of two solutions of one discretisation, and need not resolve what the fit itself does)
FE_ELEMENTS, FE_STEPS = 48, 3000


@functools.lru_cache(maxsize=16)
def _solve(beam, vehicle, t_end: float):
    from ..physics.girder import Girder, GirderFE

    girder = Girder.from_beam(beam, beam.segments, beam.rotational_stiffness)
    return GirderFE(girder, FE_ELEMENTS).solve(vehicle, t_end, FE_STEPS, 1.0)


def _fe(beam, vehicle, data, t_end: float, shift: float = 0.0) -> np.ndarray:
    """The finite-element response at the data points (deflection rows and strain rows), SI."""
    sol = _solve(beam, vehicle, float(t_end))
    strain = np.asarray(data.kind) == "strain"
    a_xx = np.where(strain, -np.asarray(data.y, float), 0.0)
    a_u = np.where(strain, 0.0, 1.0)
    t = np.clip(np.asarray(data.t, float) + shift, 0.0, t_end)
    out = np.empty(len(data))
    for rows in (strain, ~strain):
        if rows.any():
            out[rows] = sol.sample(data.x[rows], t[rows], a_u[rows][0], a_xx[rows])
    return out


def _candidates(cfg, data, EI: float):
    """(name, advice, cause, directions (n, p)) for every extension the model does not already infer."""
    beam = replace(cfg.beam, EI=float(EI), EI_profile=(), rotational_stiffness=(0.0, 0.0))
    veh = cfg.vehicle
    T = max(cfg.duration, float(np.max(data.t)))
    base = _fe(beam, veh, data, T)
    yield "EI", None, None, base  # the direction already fitted (response proportional to 1 / EI)
    if cfg.model.supports == "pinned":
        k = SPRING_EI_L * EI / cfg.beam.length
        cols = [
            _fe(replace(beam, rotational_stiffness=ks), veh, data, T) - base
            for ks in ((k, 0.0), (0.0, k))
        ]
        yield (
            "supports",
            'infer the support springs (`[model] supports = "springs"`)',
            "bearings that resist rotation (the supports are not pins)",
            np.column_stack(cols),
        )
    if cfg.model.EI_segments == 1 and getattr(cfg.model, "EI_field", "segments") == "segments":
        cols = []
        for i in range(SEGMENTS):
            prof = [EI] * SEGMENTS
            prof[i] = EI * (1.0 - SEGMENT_DROP)
            cols.append(_fe(replace(beam, EI=prof), veh, data, T) - base)
        yield (
            "segments",
            "infer EI per segment (`[model] EI_segments = 5`)",
            "a stiffness that varies along the span (a softer or stiffer part)",
            np.column_stack(cols),
        )
    if getattr(veh, "speed_sd", 0.0) == 0.0 and hasattr(veh, "speed_sd"):
        cols = [_fe(beam, replace(veh, speed=veh.speed * (1.0 + SPEED_STEP)), data, T) - base]
        dt = CLOCK_STEP * T / 2.0
        cols.append(_fe(beam, veh, data, T, shift=dt) - _fe(beam, veh, data, T, shift=-dt))
        entry = (
            " and of the entry time (`[vehicle] entry_time_sd`)"
            if hasattr(veh, "entry_time_sd") and getattr(veh, "entry_time_sd", 0.0) == 0.0
            else ""
        )
        yield (
            "timing",
            f"declare the speed's uncertainty (`[vehicle] speed_sd`){entry}",
            "a speed or clock that is off (the response runs early or late)",
            np.column_stack(cols),
        )
    if getattr(cfg.model, "axle_forces", None) == "constant":
        tau = 2.0 * np.asarray(data.t, float) / T - 1.0
        P = np.polynomial.legendre.legvander(np.clip(tau, -1, 1), FORCE_DEGREE)[:, 1:]
        yield (
            "forces",
            'let the axle forces fluctuate (`[model] axle_forces = "fluctuating"`)',
            "axle forces that vary during the crossing (a vehicle bouncing on the road)",
            base[:, None] * P,  # a quasi-static response scaled by a smooth modulation in time
        )


def _explained(X: np.ndarray, e: np.ndarray) -> float:
    """||P_X e||^2: the energy of e in the column space of X."""
    Q, R = np.linalg.qr(X)
    d = np.abs(np.diag(R))
    Q = Q[:, d > 1e-10 * max(d.max(initial=0.0), 1e-300)]
    return float(np.sum((Q.T @ e) ** 2))


def _log_sf(x: float, k: int) -> float:
    """log P(chi^2_k > x), finite where scipy's underflows (the leading term of its asymptotic series), so
    that p-values far below any float still rank."""
    from scipy.stats import chi2

    v = float(chi2.logsf(x, k))
    if math.isfinite(v):
        return v
    return -x / 2.0 + (k / 2.0 - 1.0) * math.log(x / 2.0) - math.lgamma(k / 2.0)


def diagnose(result, cfg, key: str) -> Advice:
    """The advice for method `key`'s misfit (module docstring): the extension whose directions explain the
    residuals best by a score test, the noise model for serial correlation alone, else `GENERIC`."""
    from ..uq.fitcheck import mean_prediction

    fc = result.summary["methods"][key].get("fit_check") or {}
    first = sensor_advice(fc) or noise_advice(fc, cfg)
    if first is not None:
        return first
    post, data = result.posteriors.get(key), result.data
    if post is None or cfg is None or data is None or len(data) == 0:
        return GENERIC
    try:
        mu = mean_prediction(post, data, seed=int(result.summary.get("seed") or 0))
        if mu is None:
            return GENERIC
        e = np.asarray(data.value, float) - mu
        sigma = float(np.median(np.asarray(post.sigma, float)))
        EI = float(np.mean(np.asarray(post.EI, float)))
        cands = list(_candidates(cfg, data, EI))
    except Exception as exc:  # the advice is an extra: never lose the report for it
        log.debug("misfit diagnosis failed: %s: %s", type(exc).__name__, exc)
        return GENERIC
    ei_dir = cands[0][3][:, None]
    e0 = _explained(ei_dir, e)
    total = float(np.sum(e**2))
    best, best_logp = GENERIC, math.inf
    for _name, text, cause, D in cands[1:]:
        gain = max(_explained(np.column_stack([ei_dir, D]), e) - e0, 0.0)
        if not sigma > 0:
            continue
        logp = _log_sf(gain / sigma**2, D.shape[1])
        log.debug("misfit diagnosis %s: share %.3f, log p %.3g", _name, gain / total, logp)
        if logp < math.log(SIGNIFICANT) and logp < best_logp:
            best, best_logp = (
                Advice(text, cause, gain / total if total > 0 else None, math.exp(logp)),
                logp,
            )
    return best
