"""Reference posterior of a real girder: emcee on the reduced modal surrogate of `physics.fe_modal`.

Parameters theta = (log EI_s for each of S equal segments, log k_left and log k_right when the bearing
springs are inferred, the log of the common axle-load factor when it is inferred); Gaussian white
noise of unknown sd sigma. The load factor is sampled in log so that the quasi-static ridge
EI / load factor = const is a straight line in theta.

* Priors. log EI_s ~ N(log EI_median, EI_log_sd), independent (the `EIPrior` of every segment);
  log k ~ N(log k_median, k_log_sd) at each support; load factor ~ N(1, load_rel_sd) truncated to > 0
  (the law `data.girder_data.draw_load_factor` draws the truth from; its density in log load factor
  carries the Jacobian, the factor itself). Every parameter is confined to 10 prior sd around its
  prior centre (the load factor to [max(1 - 10 load_rel_sd, 1e-3), 1 + 10 load_rel_sd]; prior mass
  cut off below 1e-8), which keeps the surrogate in its range.
* sigma: log-uniform (Jeffreys), integrated out exactly as `modal_mcmc`'s collapsed sampler does:
  p(theta | y) is proportional to p(theta) RSS(theta)^(-n/2); afterwards sigma^2 | theta, y ~
  InvGamma(n/2, RSS/2) is drawn exactly for every draw (RSS recovered from the stored log density).
* Likelihood: `GirderModalModel` (exact FE static part plus n_modes modal corrections). n_modes is the
  smallest of 6, 12, 24, 48 whose predictions at the MAP differ from twice as many modes by at most
  `modal_mcmc.TRUNCATION_FRACTION` of the MAP sigma (as `modal_mcmc.choose_modes`); the surrogate's
  reduced basis is referenced at the MAP.
* MAP: a scan of a common log EI, then L-BFGS-B on theta (central-difference gradients, evaluated as
  one batch); with springs inferred from three spring starts. Laplace covariance from a batched
  central-difference Hessian (eigenvalues floored at the smallest prior precision).
* emcee with its differential-evolution move (`DEMove`; the stretch move is an option). Measured on
  the damaged Exeter girder (5 segments, 100 deflection points, 30 dB; the machine's other core busy):
  tau 34-39 steps with DEMove against 103-110 with the stretch move; long runs of both give segment
  sds within 3 % (DEMove) and 5 % (stretch) of an importance sampler's (multivariate-t proposal,
  2e5 draws, weight ESS 970). emcee 3.1.6's `DESnookerMove` (mixed in at 0.2, as emcee's docs
  suggest) gave segment sds 10-16 % too small: its step along the snooker line is
  gamma |s - z| (u . (z1 - z2)) with u the unit direction, i.e. it grows with the distance from the
  anchor walker z (`u = delta / sqrt(norm)` where the method needs delta / norm), which its
  acceptance factor does not correct; it is not used.
* `n_groups` independent ensembles, each of max(16, 2 dim) walkers rounded up to even, i.e.
  max(32, 4 dim) walkers in all for two groups, started from MAP + Laplace-covariance draws. The run
  grows in chunks until the post-burn-in part (burn-in: `burn_factor` tau) is at least `tau_factor`
  integrated autocorrelation times long and the tau estimate changed by less than `tau_rtol` since the
  previous check, or `max_steps` is reached (a warning). tau: emcee's estimate on the last two thirds
  of each group's chain, the largest over parameters and groups.
* Diagnostics per parameter (every segment EI, each spring, the load factor, sigma and the derived
  span-averaged EI): ArviZ rank-normalised split R-hat and bulk/tail ESS with one chain per
  independent group (its walkers' trajectories one after another, as `sampler.sample` arranges them);
  `converged` when every R-hat <= RHAT_MAX and every ESS >= ESS_MIN.

Derived: the span-averaged EI = L / integral dx / EI = S / sum_s (1 / EI_s) (equal segments), and
`p_damaged` per segment, the posterior probability that EI_s < 0.9 EI_nominal (default: the prior
median). `GirderPosterior.summary()` uses the keys of the contract's "Real girders" section.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .. import seeding
from ..config import Beam, Vehicle, _check_number
from ..data.girder_data import check_load_rel_sd
from ..data.measurements import Measurements
from ..errors import InputError
from ..physics.girder import Girder
from ..threads import one_blas_thread
from .ar1 import AR1Noise
from .girder_emcee import GirderChains, GirderMCMCSettings, run_emcee
from .girder_logpost import BATCH, SUPPORT_SD, GirderLogPosterior, ParameterLayout
from .girder_map import (
    MODE_STEPS,
    choose_girder_modes,
    find_map,
    laplace_covariance,
    surrogate_model,
)
from .posterior import jsonable, mcmc_diagnostics, summarise
from .priors import EIPrior, NoisePrior
from .sampler import ESS_MIN, RHAT_MAX

#: its public names, with those of its parts in their own modules (`girder_logpost`: the log posterior;
#: `girder_map`: MAP, Laplace covariance, mode count; `girder_emcee`: the sampler), importable from here
__all__ = [
    "BATCH",
    "DAMAGE_FRACTION",
    "MODE_STEPS",
    "SUPPORT_SD",
    "GirderChains",
    "GirderLogPosterior",
    "GirderMCMCSettings",
    "GirderPosterior",
    "ParameterLayout",
    "choose_girder_modes",
    "find_map",
    "girder_posterior",
    "laplace_covariance",
    "run_emcee",
]

SUPPORTS = ("pinned", "springs")
LOAD_FACTOR_MODES = ("auto", "off")
NOISE_MODELS = ("iid", "ar1")
#: a segment is damaged when its EI is below this fraction of EI_nominal
DAMAGE_FRACTION = 0.9


# --------------------------------------------------------------------------------------------------
# result


@dataclass
class GirderPosterior:
    """Posterior draws of a girder's parameters, each shaped (chain, draw) with one chain per
    independent walker group.

    Attributes
    ----------
    EI_segments : array (chain, draw, S), segment EI [N m^2], left to right
    rotational_stiffness : array (chain, draw, 2) [N m/rad] (left, right), or None (pinned analysis)
    load_factor : array (chain, draw), or None (not inferred)
    sigma : array (chain, draw), noise sd (units of the data; the marginal sd with AR(1) noise)
    edges : array (S + 1,), segment boundaries [m]
    EI_nominal : design EI [N m^2] that damage is judged against
    diagnostics : worst-case rhat / ess_bulk / ess_tail, `per_parameter`, converged, tau, steps, ...
    info : MAP, Laplace sds, priors
    runtime_s : wall time [s]
    """

    EI_segments: np.ndarray
    rotational_stiffness: np.ndarray | None
    load_factor: np.ndarray | None
    sigma: np.ndarray
    edges: np.ndarray
    EI_nominal: float
    diagnostics: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    runtime_s: float = 0.0
    method: str | None = None  # the summary key of the method that computed it, where one says
    #: (chain, draw) AR(1) coefficient of the noise between consecutive samples, or None (white noise)
    noise_ar1: np.ndarray | None = None

    @property
    def n_segments(self) -> int:
        return int(self.EI_segments.shape[-1])

    @property
    def EI(self) -> np.ndarray:
        """Span-averaged EI L / integral dx / EI = S / sum_s 1 / EI_s, (chain, draw)."""
        return self.n_segments / np.sum(1.0 / self.EI_segments, axis=-1)

    @property
    def p_damaged(self) -> np.ndarray:
        """(S,): posterior probability that EI_s < DAMAGE_FRACTION x EI_nominal."""
        thr = DAMAGE_FRACTION * self.EI_nominal
        return np.mean(self.EI_segments.reshape(-1, self.n_segments) < thr, axis=0)

    def draws(self) -> dict[str, np.ndarray]:
        """Every reported quantity by its diagnostic name, each (chain, draw)."""
        out = {f"EI_segments[{s}]": self.EI_segments[..., s] for s in range(self.n_segments)}
        if self.rotational_stiffness is not None:
            out["rotational_stiffness[0]"] = self.rotational_stiffness[..., 0]
            out["rotational_stiffness[1]"] = self.rotational_stiffness[..., 1]
        if self.load_factor is not None:
            out["load_factor"] = self.load_factor
        out["EI"] = self.EI
        out["sigma"] = self.sigma
        if self.noise_ar1 is not None:
            out["noise_ar1"] = self.noise_ar1
        return out

    def interval(self, name: str = "EI", level: float = 0.9) -> tuple[float, float]:
        """Equal-tailed credible interval of a quantity named as in `draws()`."""
        a = (1.0 - level) / 2.0
        lo, hi = np.quantile(self.draws()[name].ravel(), [a, 1.0 - a])
        return float(lo), float(hi)

    def summary(self, truth: dict | None = None) -> dict:
        """The method's summary entry (contract keys): EI, EI_segments (x0, x1, p_damaged and the
        fields of `summarise`), rotational_stiffness [left, right] when inferred, load_factor when
        inferred, sigma, EI_nominal, diagnostics, runtime_s. `truth` (e.g. `girder_truth`) may hold
        EI, EI_segments, rotational_stiffness and load_factor; matching entries get rel_error_pct."""
        t = _check_truth(truth, self.n_segments)
        out: dict[str, Any] = {"EI": summarise(self.EI, t.get("EI"))}
        seg_truth = t.get("EI_segments") or [None] * self.n_segments
        pd = self.p_damaged
        segs = []
        for s in range(self.n_segments):
            e = {"x0": float(self.edges[s]), "x1": float(self.edges[s + 1])}
            e.update(summarise(self.EI_segments[..., s], seg_truth[s]))
            e["p_damaged"] = float(pd[s])
            segs.append(e)
        out["EI_segments"] = segs
        if self.rotational_stiffness is not None:
            kt = t.get("rotational_stiffness") or [None, None]
            out["rotational_stiffness"] = [
                summarise(self.rotational_stiffness[..., i], kt[i] if _finite(kt[i]) else None)
                for i in range(2)
            ]
        if self.load_factor is not None:
            out["load_factor"] = summarise(self.load_factor, t.get("load_factor"))
        out["sigma"] = summarise(self.sigma)
        if self.noise_ar1 is not None:
            out["noise_ar1"] = summarise(self.noise_ar1)
        out["EI_nominal"] = float(self.EI_nominal)
        out["diagnostics"] = jsonable(self.diagnostics)
        out.update(jsonable(self.info))
        out["runtime_s"] = float(self.runtime_s)
        return out


def _finite(v: Any) -> bool:
    return v is not None and math.isfinite(float(v))


def _check_truth(truth: dict | None, S: int) -> dict:
    if truth is None:
        return {}
    if not isinstance(truth, dict):
        raise InputError("truth", truth, "a dict of true values")
    out = dict(truth)
    if truth.get("EI") is not None:
        out["EI"] = _check_number("truth.EI", truth["EI"], positive=True)
    if truth.get("EI_segments") is not None:
        seg = list(truth["EI_segments"])
        if len(seg) != S:
            raise InputError("truth.EI_segments", seg, f"{S} values (one per analysis segment)")
        out["EI_segments"] = [
            _check_number(f"truth.EI_segments[{i}]", v, positive=True) for i, v in enumerate(seg)
        ]
    if truth.get("rotational_stiffness") is not None:
        ks = list(truth["rotational_stiffness"])
        if len(ks) != 2:
            raise InputError("truth.rotational_stiffness", ks, "two values (left, right)")
        for i, k in enumerate(ks):
            if (
                isinstance(k, bool)
                or not isinstance(k, int | float | np.integer | np.floating)
                or not (float(k) >= 0)
            ):
                raise InputError(
                    f"truth.rotational_stiffness[{i}]", k, "a number >= 0 N m/rad, or inf"
                )
        out["rotational_stiffness"] = [float(k) for k in ks]
    if truth.get("load_factor") is not None:
        out["load_factor"] = _check_number("truth.load_factor", truth["load_factor"], positive=True)
    return out


# --------------------------------------------------------------------------------------------------
# entry point


def _geometry(girder: Girder | Beam) -> tuple[float, float, float, float]:
    if isinstance(girder, Girder | Beam):
        return girder.length, girder.mass_per_length, girder.section_depth, girder.damping_ratio
    raise InputError("girder", girder, "a Girder or a Beam (the span's geometry)")


def _check_segments(S: Any, n_data: int) -> int:
    if isinstance(S, bool) or not isinstance(S, int | np.integer) or S < 1:
        raise InputError("model.EI_segments", S, "an integer >= 1")
    if S > n_data:
        raise InputError("model.EI_segments", S, f"at most the number of data points ({n_data})")
    return int(S)


@one_blas_thread
def girder_posterior(
    data: Measurements,
    girder: Girder | Beam,
    vehicle: Vehicle,
    *,
    ei_prior: EIPrior,
    EI_segments: int = 1,
    supports: str = "pinned",
    load_factor: str = "auto",
    load_rel_sd: float = 0.0,
    k_median: float = 1.0e8,
    k_log_sd: float = 2.0,
    EI_nominal: float | None = None,
    noise: str = "iid",
    seed: int | np.random.SeedSequence = 0,
    settings: GirderMCMCSettings | None = None,
    n_elements: int = 96,
) -> GirderPosterior:
    """Sample the reference posterior of a girder's segment EI (and bearing springs, load factor).

    Parameters
    ----------
    data : measurements of one kind (deflection or strain: one noise sd).
    girder : the span's geometry (length, mass per length, depth, damping); its EI and springs are
        not used (a config `Beam` works too).
    vehicle : the stated axles.
    ei_prior : log-normal prior of each segment's EI.
    EI_segments : n equal segments from the left support ([model] EI_segments).
    supports : "pinned", or "springs" (a rotational spring inferred at each support).
    load_factor : "auto" (infer a common axle-load factor when load_rel_sd > 0) or "off".
    load_rel_sd : relative sd of the axle loads around the stated ones ([vehicle] load_rel_sd).
    k_median, k_log_sd : log-normal spring prior [N m/rad] ([prior] k_median, k_log_sd).
    EI_nominal : design EI that damage is judged against (default: the prior median).
    noise : "iid" (white) or "ar1" (AR(1) along each sensor's series, its coefficient inferred: `uq.ar1`).
    seed : root seed (walker starts and moves: "emcee" stream; sigma draws: "noise").
    settings : run-length rules.
    n_elements : FE elements of the surrogate.

    Runs with one BLAS thread: its small dense algebra is faster so, and its draws are then the same function
    of the seed on every machine (two threads round differently, and the chains drift apart).

    Returns
    -------
    GirderPosterior: draws (chain = independent walker group, draw), diagnostics per parameter,
    MAP and Laplace information; a function of the seed.
    """
    t0 = time.perf_counter()
    if not isinstance(data, Measurements):
        raise InputError("data", data, "a Measurements set")
    L, mu, depth, zeta = _geometry(girder)
    if not isinstance(vehicle, Vehicle):
        raise InputError("vehicle", vehicle, "a Vehicle")
    if not isinstance(ei_prior, EIPrior):
        raise InputError("prior", ei_prior, "an EIPrior")
    S = _check_segments(EI_segments, len(data))
    if supports not in SUPPORTS:
        raise InputError("model.supports", supports, "'pinned' or 'springs'")
    if load_factor not in LOAD_FACTOR_MODES:
        raise InputError("model.load_factor", load_factor, "'auto' or 'off'")
    if noise not in NOISE_MODELS:
        raise InputError("model.noise", noise, "'iid' or 'ar1'")
    load_rel_sd = check_load_rel_sd(load_rel_sd)
    k_median = _check_number("prior.k_median", k_median, positive=True)
    k_log_sd = _check_number("prior.k_log_sd", k_log_sd, positive=True)
    nominal = ei_prior.median if EI_nominal is None else EI_nominal
    nominal = _check_number("model.EI_nominal", nominal, positive=True)
    if len(set(np.asarray(data.kind).tolist())) != 1:
        raise InputError("data.kind", sorted(set(data.kind.tolist())), "one kind (one noise sd)")
    settings = settings or GirderMCMCSettings()
    infer_springs = supports == "springs"
    infer_load = load_factor == "auto" and load_rel_sd > 0
    lay = ParameterLayout(S, infer_springs, infer_load, noise == "ar1")
    ar1 = AR1Noise.of(data) if noise == "ar1" else None
    k_prior = (k_median, k_log_sd) if infer_springs else None
    lf_sd = load_rel_sd if infer_load else None
    y = np.asarray(data.value, float)
    if not np.all(np.isfinite(y)) or not np.any(y != 0):
        raise InputError(
            "data.value", "all zero or non-finite", "finite measurements, not all zero"
        )

    def template(EI: Sequence[float], ks: Sequence[float]) -> Girder:
        return Girder(
            L,
            tuple(float(e) for e in EI),
            mu,
            depth,
            damping_ratio=zeta,
            rotational_stiffness=tuple(float(k) for k in ks) if infer_springs else (0.0, 0.0),
        )

    def build(tmpl: Girder, n_modes: int) -> GirderLogPosterior:
        m = surrogate_model(tmpl, vehicle, data, n_modes, infer_springs, n_elements)
        return GirderLogPosterior(m, y, lay, ei_prior, k_prior, lf_sd, ar1)

    # MAP on a surrogate referenced at the prior centre, then re-referenced at the MAP
    tmpl = template([ei_prior.median] * S, [k_median, k_median])
    post = build(tmpl, MODE_STEPS[0])
    theta = find_map(post)
    EI_m, ks_m, _ = post.unpack(theta)
    tmpl = template(EI_m[0], ks_m[0] if ks_m is not None else (0.0, 0.0))
    post = build(tmpl, MODE_STEPS[0])
    sigma_map = math.sqrt(float(post.rss(theta)[0]) / post.n)
    n_modes, trunc = choose_girder_modes(tmpl, vehicle, data, post, theta, sigma_map, n_elements)
    post = build(tmpl, n_modes)
    theta = find_map(post, starts=[theta])
    cov = laplace_covariance(post, theta)
    sigma_map = math.sqrt(float(post.rss(theta)[0]) / post.n)
    t_map = time.perf_counter() - t0

    ch = run_emcee(post, theta, cov, settings, seed)
    th = ch.theta
    EI_seg = np.exp(th[..., :S])
    ks = np.exp(th[..., lay.springs]) if infer_springs else None
    lf = np.exp(th[..., lay.load]) if infer_load else None
    # RSS (or Q(rho)) from the stored log density
    flat = th.reshape(-1, lay.dim)
    log_rss = post.log_quad(flat, ch.lp.ravel())
    g = np.random.default_rng(seeding.stream(seed, "noise")).gamma(
        post.n / 2.0, 1.0, size=flat.shape[0]
    )
    noise_prior = NoisePrior.build("vague", y)
    sig = np.sqrt(np.exp(log_rss) / (2.0 * g)).reshape(ch.lp.shape)
    sig = np.clip(sig, noise_prior.low, noise_prior.high)

    result = GirderPosterior(
        EI_segments=EI_seg,
        rotational_stiffness=ks,
        load_factor=lf,
        sigma=sig,
        edges=np.linspace(0.0, L, S + 1),
        EI_nominal=nominal,
        noise_ar1=np.tanh(th[..., lay.ar1]) if lay.infer_ar1 else None,
    )
    per = {name: mcmc_diagnostics(d) for name, d in result.draws().items()}
    rhat = max(v["rhat"] for v in per.values())
    ess_b = min(v["ess_bulk"] for v in per.values())
    ess_t = min(v["ess_tail"] for v in per.values())
    converged = bool(
        all(
            v["rhat"] <= RHAT_MAX and v["ess_bulk"] >= ESS_MIN and v["ess_tail"] >= ESS_MIN
            for v in per.values()
        )
    )
    if not converged:
        warnings.warn(
            f"girder MCMC did not meet R-hat <= {RHAT_MAX} and ESS >= {ESS_MIN} for every "
            f"parameter: {per}",
            RuntimeWarning,
            stacklevel=2,
        )
    result.diagnostics = {
        "rhat": rhat,
        "ess_bulk": ess_b,
        "ess_tail": ess_t,
        "converged": converged,
        "per_parameter": per,
        "tau": ch.tau,
        "tau_per_parameter": dict(
            zip([f"log {n}" for n in lay.names()], ch.tau_per_parameter.tolist(), strict=True)
        ),
        "steps": ch.steps,
        "burn": ch.burn,
        "thin": ch.thin,
        "walkers": ch.walkers,
        "groups": settings.n_groups,
        "acceptance": ch.acceptance,
        "n_modes": n_modes,
        "truncation_error": trunc,
        "noise_prior": noise_prior.describe(),
        "scheme": "emcee on theta with sigma marginalised; exact inverse-gamma sigma draws"
        + ("; AR(1) noise, rho as atanh(rho)" if lay.infer_ar1 else ""),
    }
    EI_map, ks_map, lf_map = post.unpack(theta)
    map_info: dict[str, Any] = {"EI_segments": EI_map[0].tolist(), "sigma": sigma_map}
    if infer_springs:
        map_info["rotational_stiffness"] = ks_map[0].tolist()
    if infer_load:
        map_info["load_factor"] = float(lf_map[0])
    if lay.infer_ar1:
        map_info["noise_ar1"] = float(np.tanh(theta[lay.ar1]))
    result.info = {
        "map": map_info,
        "laplace_sd": dict(
            zip([f"log {n}" for n in lay.names()], np.sqrt(np.diag(cov)).tolist(), strict=True)
        ),
        "model": {
            "EI_segments": S,
            "supports": supports,
            "load_factor": "inferred" if infer_load else "fixed at 1",
            "noise": noise,
        },
        "prior": {
            "EI_median": ei_prior.median,
            "EI_log_sd": ei_prior.log_sd,
            **({"k_median": k_median, "k_log_sd": k_log_sd} if infer_springs else {}),
            **({"load_rel_sd": load_rel_sd} if infer_load else {}),
        },
        "map_time_s": t_map,
    }
    result.runtime_s = time.perf_counter() - t0
    return result
