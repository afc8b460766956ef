"""The crossing reference's posterior: EI and sigma draws with the nuisances' draws, and their summary
(per crossing with several crossings)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..uq.posterior import Posterior, summarise


@dataclass
class CrossingsReference(Posterior):
    """The crossing reference's `Posterior`: EI and sigma draws, and the nuisances' draws (`nuisance`:
    damping_ratio, axle_force_sd, axle_force_time_scale, axle_force_correlation (chain, draw); per crossing
    speed and entry_time)."""

    nuisance: dict = field(default_factory=dict, repr=False, compare=False)
    crossing_names: tuple = ()

    def summary(self, truth: dict | None = None) -> dict:
        out = super().summary(truth)
        t = truth or {}
        nz = self.nuisance
        for key in (
            "damping_ratio",
            "axle_force_sd",
            "axle_force_time_scale",
            "axle_force_correlation",
            "crossing_error",
        ):
            if key in nz:
                out[key] = _summarise(nz[key], t.get(key))
        per = nz.get("crossings", {})
        if len(self.crossing_names) == 1:
            for key, d in per.get(self.crossing_names[0], {}).items():
                out[key] = _summarise(d, t.get(key))
        elif self.crossing_names:
            tc = t.get("crossings") or {}
            cross = {}
            for name in self.crossing_names:
                e = {
                    k: summarise(d, (tc.get(name) or {}).get(k))
                    for k, d in per.get(name, {}).items()
                }
                fc = (self.info.get("crossing_fit_checks") or {}).get(name)
                if fc is not None:
                    e["fit_check"] = fc
                cross[name] = e
            out["crossings"] = cross
        out.pop("crossing_fit_checks", None)
        return out

    def to_inference_data(self, data=None, seed: int = 0):
        """The base InferenceData with the nuisances' draws in `posterior` beside EI and sigma:
        damping_ratio, axle_force_sd, axle_force_time_scale, and speed / entry_time (one crossing) or
        speed_<name> / entry_time_<name> (several)."""
        import xarray as xr

        idata = super().to_inference_data(data, seed)
        post = idata.posterior
        extra = {k: v for k, v in self.nuisance.items() if k != "crossings"}
        one = len(self.crossing_names) == 1
        for name, d in self.nuisance.get("crossings", {}).items():
            for k, v in d.items():
                extra[k if one else f"{k}_{name}"] = v
        for k, v in extra.items():
            post[k] = xr.DataArray(np.asarray(v), dims=("chain", "draw"))
        return idata


def _summarise(draws, truth) -> dict:
    """`uq.posterior.summarise`, with the absolute error `error` beside rel_error_pct (which a truth of 0,
    such as an entry time, has not)."""
    if truth is None:
        return summarise(draws)
    out = summarise(draws, truth if truth != 0 else None)
    out["error"] = out["mean"] - float(truth)
    return out
