"""The `Posterior` type every UQ method returns: draws of EI and sigma, summaries, ArviZ I/O."""

from __future__ import annotations

import os
import tempfile
import warnings
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .arviz_import import import_arviz

#: posterior predictive draws written beside the posterior (`Posterior.to_inference_data`)
PREDICTIVE_DRAWS = 200


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
    az = import_arviz()

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
    method : the method's summary key (the reference's `methods.REFERENCE_KEY`, "ensemble", "bpinn", or a
        registered method's)
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
    #: per-draw sample statistics (chain, draw) of a sampler, named as ArviZ's `sample_stats` group names
    #: them: emcee `lp`, `acceptance`; NUTS `lp`, `diverging`, `step_size`, `tree_depth`
    sample_stats: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not isinstance(self.method, str) or not self.method:
            raise ValueError(f"method must be a method's summary key, got {self.method!r}")
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

    def predictive_draws(
        self, data, n_draws: int = PREDICTIVE_DRAWS, seed: int = 0
    ) -> np.ndarray | None:
        """Posterior predictive draws at the data points, (n, P) in the data's units: the method's noise-free
        response for n posterior draws (deflection; strain = -y x curvature on strain rows) plus
        N(0, sigma^2) noise, sigma drawn from its posterior. None without a predictor, data or finite sigma.
        A function of `seed`."""
        sig = self.sigma[np.isfinite(self.sigma)]
        if self.predictor is None or len(data) == 0 or sig.size == 0:
            return None
        ss = np.random.SeedSequence(int(seed), spawn_key=(zlib.crc32(b"posterior_predictive"),))
        strain = np.asarray(data.kind) == "strain"
        parts = {}
        for quantity, rows in (("deflection", ~strain), ("curvature", strain)):
            if rows.any():
                # the same generator state for both calls, so both kinds of rows use the same draws
                r = np.asarray(
                    self.predictor(
                        data.x[rows], data.t[rows], quantity, n_draws, np.random.default_rng(ss)
                    ),
                    float,
                )
                parts[quantity] = -data.y[rows][None, :] * r if quantity == "curvature" else r
        n = min(p.shape[0] for p in parts.values())
        resp = np.empty((n, len(data)))
        if "deflection" in parts:
            resp[:, ~strain] = parts["deflection"][:n]
        if "curvature" in parts:
            resp[:, strain] = parts["curvature"][:n]
        rng = np.random.default_rng(ss.spawn(1)[0])
        s = rng.choice(sig, size=n, replace=True)
        return resp + s[:, None] * rng.standard_normal(resp.shape)

    def to_inference_data(self, data=None, seed: int = 0):
        """ArviZ InferenceData: `posterior` (EI, sigma; chain, draw) and `sample_stats` where the method is a
        sampler; with the data also `observed_data` and `constant_data` (y, x, t by observation) and
        `posterior_predictive` (y at the data points, `predictive_draws`, one chain)."""
        az = import_arviz()

        attrs = {"method": self.method, "runtime_s": float(self.runtime_s)}
        for k, v in {**self.diagnostics, **self.info}.items():
            if isinstance(v, int | float | str | bool | np.floating | np.integer):
                attrs[f"bayespinn_{k}"] = v if not isinstance(v, bool) else int(v)
        groups: dict = {"posterior": {"EI": self.EI, "sigma": self.sigma}}
        if self.sample_stats:
            groups["sample_stats"] = {k: np.asarray(v) for k, v in self.sample_stats.items()}
        dims = {}
        if data is not None and len(data):
            groups["observed_data"] = {"y": np.asarray(data.value, float)}
            groups["constant_data"] = {
                "x": np.asarray(data.x, float),
                "t": np.asarray(data.t, float),
            }
            dims = {"y": ["obs"], "x": ["obs"], "t": ["obs"]}
            pp = self.predictive_draws(data, seed=seed)
            if pp is not None:
                groups["posterior_predictive"] = {"y": pp[None, :, :]}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # groups of different draw counts
            idata = az.from_dict(**groups, dims=dims)
        idata.posterior.attrs.update(attrs)
        return idata

    def to_netcdf(self, path: str | Path, data=None, seed: int = 0) -> Path:
        """Write the InferenceData (`to_inference_data`) atomically (temporary file, then rename)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        os.close(fd)
        try:
            self.to_inference_data(data, seed).to_netcdf(tmp, engine="h5netcdf")
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
        az = import_arviz()

        idata = az.from_netcdf(path, engine="h5netcdf")
        post = idata.posterior
        attrs = dict(post.attrs)
        diag = {k[len("bayespinn_") :]: v for k, v in attrs.items() if k.startswith("bayespinn_")}
        stats = {}
        if "sample_stats" in idata.groups():
            stats = {k: v.values for k, v in idata.sample_stats.data_vars.items()}
        return cls(
            method=str(attrs.get("method")),
            EI=post["EI"].values,
            sigma=post["sigma"].values,
            diagnostics=diag,
            runtime_s=float(attrs.get("runtime_s", 0.0)),
            sample_stats=stats,
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
