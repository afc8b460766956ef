"""The `Posterior` type every UQ method returns: draws of EI and sigma, summaries, ArviZ I/O."""

from __future__ import annotations

import os
import tempfile
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: method keys of the contract
METHOD_KEYS = ("modal_mcmc", "ensemble", "bpinn")


def summarise(draws: np.ndarray, truth: float | None = None) -> dict:
    """mean, sd, median, equal-tailed ci90/ci95 [lower, upper] (and rel_error_pct when truth is known)."""
    d = np.asarray(draws, float).ravel()
    q = np.quantile(d, [0.025, 0.05, 0.5, 0.95, 0.975])
    out = {
        "mean": float(d.mean()),
        "sd": float(d.std(ddof=1)) if d.size > 1 else 0.0,
        "median": float(q[2]),
        "ci90": [float(q[1]), float(q[3])],
        "ci95": [float(q[0]), float(q[4])],
    }
    if truth is not None:
        out["rel_error_pct"] = float(100.0 * (out["mean"] - truth) / truth)
    return out


def central_interval(draws: np.ndarray, level: float) -> tuple[float, float]:
    """Equal-tailed credible interval at `level` from draws."""
    a = (1.0 - level) / 2.0
    lo, hi = np.quantile(np.asarray(draws, float).ravel(), [a, 1.0 - a])
    return float(lo), float(hi)


def mcmc_diagnostics(x: np.ndarray) -> dict:
    """R-hat and bulk/tail ESS of draws shaped (chain, draw), from ArviZ (rank-normalised split R-hat)."""
    import arviz as az

    x = np.asarray(x, float)
    if x.ndim != 2 or x.shape[0] < 2 or x.shape[1] < 4:
        return {"rhat": float("nan"), "ess_bulk": float("nan"), "ess_tail": float("nan")}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return {
            "rhat": float(az.rhat(x)),
            "ess_bulk": float(az.ess(x, method="bulk")),
            "ess_tail": float(az.ess(x, method="tail")),
        }


@dataclass
class Posterior:
    """Posterior draws of EI [N m^2] and sigma (m or strain), shaped (chain, draw).

    Attributes
    ----------
    method : one of METHOD_KEYS
    EI, sigma : arrays (chain, draw)
    diagnostics : e.g. rhat, ess_bulk, ess_tail, converged, n_modes, truncation error
    info : method-specific summary entries (members, member_EI, variant, ...), copied into summary.json
    runtime_s : wall time of the inference [s]
    """

    method: str
    EI: np.ndarray
    sigma: np.ndarray
    diagnostics: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    runtime_s: float = 0.0
    #: optional predictive: predictor(x, t, quantity, n_draws, rng) -> array (n_draws, P) of
    #: 'deflection' [m], 'moment' [N m] or 'curvature' (u_xx) [1/m] (strain = -y * curvature)
    predictor: Callable | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.method not in METHOD_KEYS:
            raise ValueError(f"method must be one of {METHOD_KEYS}, got {self.method!r}")
        self.EI = np.atleast_2d(np.asarray(self.EI, float))
        self.sigma = np.atleast_2d(np.asarray(self.sigma, float))
        if self.EI.shape != self.sigma.shape:
            raise ValueError(
                f"EI draws {self.EI.shape} and sigma draws {self.sigma.shape} differ in shape"
            )

    def interval(self, level: float = 0.9, var: str = "EI") -> tuple[float, float]:
        """Central credible interval of EI (or sigma) at `level`."""
        return central_interval(getattr(self, var), level)

    def summary(self, truth: dict | None = None) -> dict:
        """The method's entry of summary.json (contract schema)."""
        t = truth or {}
        out = {
            "EI": summarise(self.EI, t.get("EI")),
            "sigma": summarise(self.sigma),
        }
        if self.diagnostics:
            out["diagnostics"] = jsonable(self.diagnostics)
        out.update(jsonable(self.info))
        out["runtime_s"] = float(self.runtime_s)
        return out

    def to_inference_data(self):
        """ArviZ InferenceData with posterior variables EI and sigma (chain, draw)."""
        import arviz as az

        attrs = {"method": self.method, "runtime_s": float(self.runtime_s)}
        for k, v in {**self.diagnostics, **self.info}.items():
            if isinstance(v, int | float | str | bool | np.floating | np.integer):
                attrs[f"bayespinn_{k}"] = v if not isinstance(v, bool) else int(v)
        idata = az.from_dict(posterior={"EI": self.EI, "sigma": self.sigma})
        idata.posterior.attrs.update(attrs)
        return idata

    def to_netcdf(self, path: str | Path) -> Path:
        """Write the InferenceData atomically (temporary file, then rename)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        os.close(fd)
        try:
            self.to_inference_data().to_netcdf(tmp, engine="h5netcdf")
            from ..data.measurements import _FILE_MODE

            os.chmod(tmp, _FILE_MODE)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        return path

    @classmethod
    def from_netcdf(cls, path: str | Path) -> Posterior:
        """Read a posterior written by `to_netcdf`."""
        import arviz as az

        idata = az.from_netcdf(path, engine="h5netcdf")
        post = idata.posterior
        attrs = dict(post.attrs)
        diag = {k[len("bayespinn_") :]: v for k, v in attrs.items() if k.startswith("bayespinn_")}
        return cls(
            method=str(attrs.get("method")),
            EI=post["EI"].values,
            sigma=post["sigma"].values,
            diagnostics=diag,
            runtime_s=float(attrs.get("runtime_s", 0.0)),
        )


def jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.bool_ | bool):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating | float):
        v = float(obj)
        return v if np.isfinite(v) else None
    return obj
