"""What the fit check says to a user (`uq.fitcheck`): the p-values as a reader should take them, the one
sentence naming what the residuals contradict and what to do, and what was computed. Words only: every
number comes from the check's entry."""

from __future__ import annotations

from . import fitcheck_stats as fs

#: what each band of smooth structure points to, and what to do (the detail's words)
SMOOTH_CAUSES = {
    "timing": "it has the shape of the response shifted or stretched in time, as a stated speed or entry "
    "time that is off leaves (declare their uncertainty: [vehicle] speed_sd, entry_time_sd)",
    "mid": "it varies at a vehicle's bounce frequencies, as dynamic axle forces leave (declare them: "
    '[model] axle_forces = "fluctuating")',
    "low": "it varies at the crossing's own time scale, as a support, a stiffness or a load the model "
    "lacks leaves (change the model: springs at the supports, EI per segment)",
}


def p_text(p: float, replicates: int, floor: float | None = None) -> str:
    """A p-value as a reader should take it: at the Monte Carlo floor of one statistic, 'p < 1/(n + 1)';
    at the floor of a combination of several (k of the n + 1 values share it), 'p <= k/(n + 1)'."""
    one = 1.0 / (replicates + 1)
    if p <= one * (1 + 1e-9):
        return f"p < 1/{replicates + 1}"
    if floor is not None and p <= floor * (1 + 1e-9):
        return f"p <= {round(p * (replicates + 1))}/{replicates + 1}, its floor"
    return f"p = {p:.2g}"


def statistic_text(
    names: list[str],
    ar1: bool,
    n_crossings: int,
    n_basis: int,
    n_timing: int,
    replicates: int,
    false_alarm: float,
) -> str:
    """What the check computed, in one sentence (the entry's `statistic`); `names` the statistics' keys."""
    parts = [
        f"energy in {n_basis} smooth functions of time (and position, for scattered points) and in "
        f"{n_timing} directions of the response shifted or stretched in time, by band",
        "the lag-1 autocorrelation"
        if not ar1
        else f"the autocorrelations at lags 1 to {fs.LAGS} of the whitened residuals",
    ]
    if any(k.startswith("one_sensor") for k in names):
        parts.append("the largest ratio of one sensor's residual variance to the others'")
    noise = "AR(1) noise at its fitted coefficient" if ar1 else "white noise"
    per = f", for all the data and the worst of {n_crossings} crossings" if n_crossings > 1 else ""
    return (
        "residuals at the posterior mean prediction against a parametric bootstrap of the fitted model "
        f"({replicates} replicates of {noise}, less what the fit absorbs): "
        + "; ".join(parts)
        + per
        + f"; combined by min-p, misfit below {false_alarm:g}"
    )


def detail(fc: dict) -> str:
    """One sentence (or two) saying what the residuals contradict and what to do about it."""
    B, false_alarm = fc["replicates"], fc["false_alarm"]
    pv = fc["p_values"]
    noise = (
        f"AR(1) noise with coefficient {fc['noise_ar1']:.2f}"
        if fc["null"] == "ar1"
        else "white noise"
    )
    if fc["verdict"] == "fits":
        text = (
            f"The residuals are what {noise} leaves after the fit: no smooth structure, serial "
            f"correlation or single sensor beyond {B} simulated replicates of the fitted model "
            f"(combined {p_text(fc['p_value'], B, fc['p_value_floor'])})."
        )
    else:
        parts = []
        for r in fc["reasons"]:
            if r == "smooth_structure":
                bands = fc.get("smooth_bands") or {}
                hits = [b for b in ("timing", "mid", "low") if bands.get(b, 1.0) < false_alarm]
                causes = [SMOOTH_CAUSES[b] for b in hits] or [SMOOTH_CAUSES["low"]]
                parts.append(
                    "the residuals keep smooth structure "
                    f"({p_text(pv.get(r, fc['p_value']), B)}) that {noise} cannot leave: "
                    + "; or ".join(causes)
                )
            elif r == "serial_correlation":
                also = "smooth_structure" in fc["reasons"]
                what = (
                    "consecutive residuals are correlated (lag-1 autocorrelation "
                    f"{fc['residual_autocorr']:+.2f}, {p_text(pv.get(r, fc['p_value']), B)})"
                    if fc["null"] == "white"
                    else "the whitened residuals stay correlated over several samples "
                    f"({p_text(pv.get(r, fc['p_value']), B)})"
                )
                fix = (
                    'analyse with [model] noise = "ar1" if the records are filtered or smoothed'
                    if fc["null"] == "white"
                    else "the noise is correlated beyond what AR(1) describes (records filtered "
                    "over several samples)"
                )
                parts.append(
                    f"{what}, as the smooth structure leaves; if it stays once that is explained, {fix}"
                    if also
                    else f"{what}: {fix}"
                )
            elif r.startswith("one_sensor:"):
                ws = fc.get("worst_sensor") or {}
                ratio = (
                    f" ({ws['variance_ratio']:.1f} times the others' residual variance)"
                    if ws.get("name") == r.split(":", 1)[1]
                    else ""
                )
                parts.append(
                    f"sensor {r.split(':', 1)[1]} is much worse than the rest{ratio}: check its "
                    "calibration, position and fixing, or leave it out"
                )
            elif r.startswith("crossing:"):
                c = r.split(":", 1)[1]
                pc = fc["by_crossing"][c]["p_value"]
                parts.append(f"crossing {c} fits worst ({p_text(pc, B)})")
        text = (
            f"The data contradict the model (combined {p_text(fc['p_value'], B, fc['p_value_floor'])}): "
            + "; ".join(parts)
            + "."
        )
    if "worst_crossing" in fc and not any(r.startswith("crossing:") for r in fc["reasons"]):
        c = fc["worst_crossing"]
        text += (
            f" Of {len(fc['by_crossing'])} crossings, {c} fits worst "
            f"({p_text(fc['by_crossing'][c]['p_value'], B)})."
        )
    return text
