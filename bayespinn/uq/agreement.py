"""Agreement verdict: does a PINN posterior of EI (ensemble, B-PINN) match the modal reference?

The modal MCMC posterior is exact up to Monte Carlo error for the model both share, so a PINN method
whose posterior mean sits far from it, or whose spread is much narrower or wider, is flagged: a much
narrower posterior is overconfident (its intervals will under-cover), a much wider one wastes the data.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .. import methods as registry

#: a PINN posterior disagrees when |mean - reference mean| exceeds this many reference sds
MEAN_TOL_SD = 1.0
#: ... or when sd / reference sd falls outside this range
SD_RATIO_RANGE = (0.67, 1.5)


@dataclass(frozen=True)
class Verdict:
    """The comparison of one method's EI posterior with the reference.

    mean_diff_sd : (mean - reference mean) / reference sd, None without a reference
    sd_ratio : sd / reference sd, None without a reference
    agrees : True / False, None when there is nothing to compare with
    reasons : why it disagrees (or why no verdict)
    """

    method: str
    mean_diff_sd: float | None
    sd_ratio: float | None
    agrees: bool | None
    reasons: tuple[str, ...] = ()

    @property
    def label(self) -> str:
        if self.agrees is None:
            return "no verdict"
        return "agrees" if self.agrees else "**DISAGREES**"

    def sentence(self) -> str:
        """One line for the report."""
        who = registry.display(self.method)
        if self.agrees is None:
            return f"{who}: no verdict ({'; '.join(self.reasons)})."
        if self.agrees:
            return (
                f"{who} agrees with the modal reference (mean {self.mean_diff_sd:+.2f} reference sd away, "
                f"sd ratio {self.sd_ratio:.2f})."
            )
        return f"**{who} DISAGREES with the modal reference**: {'; '.join(self.reasons)}."


def _finite(v) -> bool:
    return isinstance(v, int | float) and math.isfinite(v)


def compare(
    entry: dict,
    reference: dict,
    method: str,
    *,
    mean_tol_sd: float = MEAN_TOL_SD,
    sd_ratio_range: tuple[float, float] = SD_RATIO_RANGE,
) -> Verdict:
    """Verdict for one summary.json method entry against the reference's entry."""
    e, r = entry.get("EI", {}), reference.get("EI", {})
    if (
        not all(_finite(v) for v in (e.get("mean"), e.get("sd"), r.get("mean"), r.get("sd")))
        or r["sd"] <= 0
    ):
        return Verdict(
            method, None, None, None, ("the reference or this method has no finite mean and sd",)
        )
    d = (e["mean"] - r["mean"]) / r["sd"]
    ratio = e["sd"] / r["sd"]
    reasons = []
    if abs(d) > mean_tol_sd:
        reasons.append(f"mean {d:+.2f} reference sd away (limit {mean_tol_sd:g})")
    lo, hi = sd_ratio_range
    if ratio < lo:
        reasons.append(f"sd {ratio:.2f} x the reference's: overconfident (limit {lo:g})")
    elif ratio > hi:
        reasons.append(f"sd {ratio:.2f} x the reference's: underconfident (limit {hi:g})")
    return Verdict(method, d, ratio, not reasons, tuple(reasons))


#: the summary key of the reference posterior (the methods registry's)
REFERENCE_KEY = registry.REFERENCE_KEY


def agreement(methods: dict, reference: str = REFERENCE_KEY, **limits) -> list[Verdict]:
    """Verdicts for every method other than the reference (the PINNs: ensemble, bpinn, and any registered
    method) in a summary's `methods` dict, in the dict's order."""
    out = []
    for key in methods:
        if key == reference:
            continue
        if reference not in methods:
            out.append(Verdict(key, None, None, None, ("the modal reference did not run",)))
        else:
            out.append(compare(methods[key], methods[reference], key, **limits))
    return out


def caveats(methods: dict, reference: str = REFERENCE_KEY) -> list[str]:
    """Reasons to read the verdict with care (the reference itself unconverged or not identifying EI)."""
    out = []
    ref = methods.get(reference)
    if ref is None:
        return out
    conv = (ref.get("diagnostics") or {}).get("converged")
    if conv is False:
        out.append(
            "The modal reference did not meet its convergence criteria (R-hat, ESS): "
            "its own intervals, and this verdict, are approximate."
        )
    if ref.get("identified") is False:
        out.append(
            "The modal reference finds EI not identified by these data: "
            "agreement then only means both methods return (roughly) the prior."
        )
    return out
