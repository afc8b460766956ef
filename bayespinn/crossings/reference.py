"""The modal reference for real crossings: EI with what a recording leaves uncertain (the speed, the entry
time on the data's clock, the damping ratio, the axles' dynamic forces), one or several crossings.

`crossings_reference(data, cfg, seed=...)` finds the maximum of the posterior (EI profiled on a grid at the
stated values, then least squares with the priors as pseudo-observations), takes a Laplace scale from a
finite-difference Hessian, and runs emcee (`uq.sampler.sample`, the reference's driver) on every inferred
parameter at once. With constant forces the noise sd is integrated out and drawn afterwards from its exact
inverse-gamma conditional; with fluctuating forces it is sampled with the force fluctuation's scale and time
scale. EI, damping, noise and the fluctuation's law are shared by all crossings; speed and entry time are
each crossing's own.
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares, minimize

from .. import seeding
from ..config import Config
from ..data.measurements import Measurements
from ..methods.reference import REFERENCE_KEY
from ..threads import one_blas_thread
from ..uq.posterior import Posterior, mcmc_diagnostics, summarise
from ..uq.priors import EIPrior, NoisePrior, prior_only
from ..uq.sampler import ESS_MIN, RHAT_MAX, MCMCSettings, sample
from .checks import (  # noqa: F401  (re-exported: the package's names)
    check_crossings,
    check_ei_field,
    needs_crossings,
    refuse_crossings,
    split_crossings,
)
from .curvature import curvature_sds
from .forward import CrossingModel
from .likelihood import FORCE_L_MEDIAN, CrossingsLogPosterior, CrossingTerm, n_basis_for
from .resonance import AMPLITUDE_MEDIAN, Resonance
from .resonance import NAMES as RESONANT_NAMES

#: modal truncation below this fraction of the noise sd (as `uq.modal_mcmc`)
TRUNCATION_FRACTION = 0.01
#: modes in the dynamic correction of the force-basis responses: the fluctuation's spectrum lies below
#: 4 / FORCE_L_MIN = 33 rad/s, under the first mode (63 rad/s for the Exeter girder) and far under the
#: second; the first mode alone leaves 0.2 % of those responses (strain gauges, against 24 modes), some
#: 4e-5 of the signal, while no mode at all would leave 15 %
BASIS_MODES = 1
#: chains the importance sampler's resampled draws are split into (a layout, not independent chains)
IMPORTANCE_CHAINS = 4
#: modes carried by the predictor (reports, fit check)
PREDICT_MODES = 24


def _terms(cfg: Config, data: Measurements, n_modes: int, forces: bool) -> list[CrossingTerm]:
    a_u, a_xx = data.weights
    out = []
    for name, rows, veh in split_crossings(cfg, data):
        nb = n_basis_for(cfg.beam.length / veh.speed) if forces else 0
        model = CrossingModel(
            cfg.beam.length, cfg.beam.mass_per_length, veh.loads, veh.offsets,
            data.x[rows], data.t[rows], a_u[rows], a_xx[rows], n_modes=n_modes, n_basis=nb,
            basis_modes=min(n_modes, BASIS_MODES),
        )  # fmt: skip
        res = (
            Resonance.build(model, veh.speed, veh.entry_time, cfg.prior.EI_median)
            if forces
            else None
        )
        out.append(
            CrossingTerm(
                name,
                rows,
                np.asarray(data.value, float)[rows],
                model,
                veh.speed,
                veh.speed_sd,
                veh.entry_time,
                veh.entry_time_sd,
                sprung=veh.model == "sprung",
                body_frequency=veh.body_frequency,
                body_damping=veh.body_damping,
                resonance=res,
            )  # fmt: skip
        )
    return out


def _start(post: CrossingsLogPosterior, cfg: Config) -> np.ndarray:
    """The stated values, with log EI the best of a grid over the prior (the other parameters stated)."""
    L = post.layout
    th = np.zeros(L.dim)
    for c in post.terms:
        if f"log_v[{c.name}]" in L.index:
            th[L.index[f"log_v[{c.name}]"]] = math.log(c.speed)
        if f"t0[{c.name}]" in L.index:
            th[L.index[f"t0[{c.name}]"]] = c.entry_time
    if "log_zeta" in L.index:
        th[L.index["log_zeta"]] = math.log(cfg.prior.damping_median)
    grid = post.ei_prior.loc + post.ei_prior.log_sd * np.linspace(-5, 5, 401)
    cand = np.repeat(th[None], grid.size, 0)
    cand[:, 0] = grid
    prof = np.concatenate(
        [_rss_profile(post, c) for c in np.array_split(cand, max(1, grid.size // 32))]
    ) + post.ei_prior.logpdf(grid)
    th[0] = grid[int(np.argmax(prof))]
    return th


def _rss_profile(post: CrossingsLogPosterior, theta: np.ndarray) -> np.ndarray:
    rss = sum(np.einsum("wp,wp->w", r, r) for r, _ in post.residuals(theta))
    return -0.5 * post.n * np.log(rss)


def _least_squares(post: CrossingsLogPosterior, th0: np.ndarray) -> tuple[np.ndarray, float]:
    """The constant-force parameters' maximum (Gauss-Newton on residuals / sigma and the priors as
    pseudo-residuals, sigma from the fit), and sigma there."""
    hyper = ("log_s", "log_l", "log_sigma", *RESONANT_NAMES)
    idx = [i for i, n in enumerate(post.layout.names) if n not in hyper]
    base = th0.copy()

    def full(z: np.ndarray) -> np.ndarray:
        th = np.repeat(base[None], z.shape[0], 0)
        th[:, idx] = z
        return th

    sigma = 1.0
    for _ in range(2):  # sigma from the fit, then the fit with that sigma
        rss = sum(float(np.sum(r**2)) for r, _ in post.residuals(full(th0[idx][None])))
        sigma = math.sqrt(rss / post.n)

        def fun(z, sigma=sigma):
            th = full(np.atleast_2d(z))
            r = np.concatenate([r for r, _ in post.residuals(th)], axis=1)[0] / sigma
            return np.concatenate([r, _prior_residuals(post, th[0])])

        def jac(z, sigma=sigma):
            return _jacobian(post, full, idx, z, sigma)

        fit = least_squares(
            fun, th0[idx], jac=jac, method="lm", xtol=1e-12, ftol=1e-12, max_nfev=200
        )
        th0 = th0.copy()
        th0[idx] = fit.x
    return th0, sigma


def _jacobian(post: CrossingsLogPosterior, full, idx: list[int], z: np.ndarray, sigma: float):
    """Central-difference Jacobian of `_least_squares`' residuals: each crossing's rows only against the
    shared parameters and its own (the rest of its block is zero), one vectorised call per crossing."""
    names = [post.layout.names[i] for i in idx]
    h = 1e-6 * np.maximum(1.0, np.abs(z))
    Z = np.repeat(np.atleast_2d(z), 2 * z.size, 0)
    for i in range(z.size):
        Z[2 * i, i] += h[i]
        Z[2 * i + 1, i] -= h[i]
    th = full(Z)
    n_obs = sum(c.y.size for c in post.terms)
    P = np.stack([_prior_residuals(post, t) for t in th])
    J = np.zeros((n_obs + P.shape[1], z.size))
    J[n_obs:] = ((P[0::2] - P[1::2]) / (2 * h[:, None])).T
    row = 0
    for ci, c in enumerate(post.terms):
        need = [k for k, n in enumerate(names) if "[" not in n or n.endswith(f"[{c.name}]")]
        sel = np.ravel([[2 * k, 2 * k + 1] for k in need])
        p = post.unpack(th[sel])
        mu = c.predict(p, ci)
        J[row : row + c.y.size, need] = (-(mu[0::2] - mu[1::2]) / (2 * h[need, None] * sigma)).T
        row += c.y.size
    return J


def _prior_residuals(post: CrossingsLogPosterior, th: np.ndarray) -> np.ndarray:
    """sqrt(-2 log prior) terms of the normal priors on the constant-force parameters (pseudo-residuals)."""
    L = post.layout
    out = [(th[0] - post.ei_prior.loc) / post.ei_prior.log_sd]
    if "log_zeta" in L.index:
        med, sd = post.damping_prior
        out.append((th[L.index["log_zeta"]] - math.log(med)) / sd)
    for c in post.terms:
        out += [(th[L.index[name]] - mean) / sd for name, mean, sd in c.own]
    return np.array(out)


def _hessian_scale(post: CrossingsLogPosterior, th: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Laplace sds of the parameters at the maximum (`curvature.curvature_sds` of -log p); the steps h
    where the Hessian is not positive definite."""
    sd = curvature_sds(lambda p: -post(p), th, h)
    return h if sd is None else sd


@dataclass
class CrossingsReference(Posterior):
    """The crossing reference's `Posterior`: EI and sigma draws, and the nuisances' draws (`nuisance`:
    damping_ratio, axle_force_sd, axle_force_time_scale (chain, draw); per crossing speed and entry_time)."""

    nuisance: dict = field(default_factory=dict, repr=False, compare=False)
    crossing_names: tuple = ()

    def summary(self, truth: dict | None = None) -> dict:
        out = super().summary(truth)
        t = truth or {}
        nz = self.nuisance
        for key in ("damping_ratio", "axle_force_sd", "axle_force_time_scale"):
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


def _choose_modes(cfg, data, post_of, th, sigma, start: int = 8, cap: int = 64):
    """The smallest mode count whose predictions at th differ from twice as many by at most
    TRUNCATION_FRACTION x sigma (a floor of 1e-9 of the data's RMS for clean data)."""
    scale = float(np.sqrt(np.mean(np.asarray(data.value, float) ** 2)))
    tol = max(TRUNCATION_FRACTION * sigma, 1e-9 * scale)
    n = start
    while True:
        p1 = np.concatenate([r for r, _ in post_of(n).residuals(th[None])], axis=1)
        p2 = np.concatenate([r for r, _ in post_of(2 * n).residuals(th[None])], axis=1)
        err = float(np.max(np.abs(p1 - p2)))
        if err <= tol or n >= cap:
            return n, err
        n *= 2


@one_blas_thread
def crossings_reference(
    data: Measurements,
    cfg: Config,
    *,
    seed: int | np.random.SeedSequence = 0,
    settings: MCMCSettings | None = None,
    progress: bool = False,
    fit_checks: bool = True,
    laplace: bool | None = None,
) -> CrossingsReference:
    """The reference posterior of EI and of what the crossings leave uncertain (module docstring).

    laplace : integrate each crossing's speed and entry time out by Laplace (`crossings.laplace`) and sample
        the shared parameters alone; None: with several crossings and constant forces. False: emcee on
        every parameter (the brute force it is checked against)."""
    from .predictor import CrossingsPredictor, crossing_fit_checks

    t_start = time.perf_counter()
    check_crossings(cfg, data)
    if len(data) == 0:
        return prior_only(EIPrior.from_spec(cfg.prior), seed, t_start)
    s = settings or MCMCSettings()
    m = cfg.model
    forces = m.axle_forces == "fluctuating"
    damping = (
        (cfg.prior.damping_median, cfg.prior.damping_log_sd) if m.damping == "inferred" else None
    )
    ei_prior = EIPrior.from_spec(cfg.prior)
    noise = NoisePrior.build("vague", np.asarray(data.value, float))
    # the second mode's damping ratio (its resonant term): the damping prior's law about the damping
    # the analysis is told or infers
    mode_damping = (damping[0] if damping else cfg.beam.damping_ratio, cfg.prior.damping_log_sd)

    def post_of(n_modes: int) -> CrossingsLogPosterior:
        return CrossingsLogPosterior(
            _terms(cfg, data, n_modes, forces), ei_prior, noise,
            zeta_known=cfg.beam.damping_ratio, damping_prior=damping, forces=forces,
            mode_damping_prior=mode_damping,
        )  # fmt: skip

    post = post_of(8)
    th = _start(post, cfg)
    th, sigma = _least_squares(post, th)
    n_modes, trunc = _choose_modes(cfg, data, post_of, th, sigma)
    if n_modes != 8:
        post = post_of(n_modes)
        th, sigma = _least_squares(post, th)
    rss = sum(float(np.sum(r**2)) for r, _ in post.residuals(th[None]))
    sigma = math.sqrt(rss / post.n)
    L = post.layout
    if forces:  # the fluctuation's parameters start from the priors' medians
        th[L.index["log_s"]] = math.log(0.5 * 0.05)
        th[L.index["log_l"]] = math.log(FORCE_L_MEDIAN)
        th[L.index["log_sigma"]] = math.log(sigma)
        if post.resonant:
            th[L.index["log_q1"]] = th[L.index["log_q2"]] = math.log(AMPLITUDE_MEDIAN)
            th[L.index["log_z2"]] = math.log(mode_damping[0])
    h = np.array([_step(n, post) for n in L.names])
    if laplace is None:
        kind = "linearised" if forces else ("laplace" if len(post.terms) > 1 else "emcee")
    else:
        kind = ("linearised" if forces else "laplace") if laplace else "emcee"
    extra: dict = {}
    if (
        kind == "laplace"
    ):  # each crossing's speed and entry time by Laplace inside the shared likelihood
        from .laplace import laplace_sample

        flat, sig, ch, extra = laplace_sample(post, th, h, sigma, s, seed, progress)
        shape = sig.shape
        draws = flat.reshape(*shape, L.dim)
    elif (
        kind == "linearised"
    ):  # the nonlinear parameters linearised, forces and theta integrated out
        from .linearised import exact_log_posterior, linearised_sample

        flat, ch, lin, extra = linearised_sample(post, th, s, seed, progress)
        shape = ch.draws.shape[:2]
        th = lin.theta.copy()
        if not extra["linearisation"]["importance_check"]["passed"]:
            # the linearisation is only a guide here: the exact posterior by adaptive importance sampling
            from .importance import amis

            rng = np.random.default_rng(seeding.child(seed, "emcee", 9300))
            flat, lp_is, extra["importance"] = amis(
                lambda z: exact_log_posterior(post, z), flat, rng, progress
            )
            kind = "importance"
            shape = (IMPORTANCE_CHAINS, flat.shape[0] // IMPORTANCE_CHAINS)
            if not extra["importance"]["passed"]:
                imp = extra["importance"]
                warnings.warn(
                    "the crossing posterior's importance sampling did not converge "
                    f"({imp['criterion']}: ESS {imp['ess']:.0f}, k-hat {imp['khat']:.2f})",
                    RuntimeWarning, stacklevel=2,
                )  # fmt: skip
        draws = flat.reshape(*shape, L.dim)
    else:
        if forces:  # the whole maximum under the exact likelihood
            res = minimize(
                lambda z: -float(post(z[None])[0]), th, method="Nelder-Mead",
                options={"maxiter": 150 * L.dim, "xatol": 1e-6, "fatol": 1e-3},
            )  # fmt: skip
            if np.isfinite(res.fun) and res.fun < -float(post(th[None])[0]):
                th = res.x
        scale = _hessian_scale(post, th, h)
        s = dataclasses.replace(s, n_walkers=max(s.n_walkers, 2 * L.dim + 2))
        ch = sample(post, th, scale, s, seed, progress, desc="crossing MCMC")
        draws = ch.draws  # (chain, draw, D)
        flat = draws.reshape(-1, L.dim)
        shape = draws.shape[:2]
    par = post.unpack(flat)
    EI = par["EI"].reshape(shape)
    if kind == "laplace":
        scheme = (
            "emcee on the shared parameters and sigma; each crossing's speed and entry time integrated "
            "out by Laplace (tabulated in the shared parameters), then drawn from its Laplace Gaussian"
        )
    elif kind == "importance":
        sig = par["sigma"].reshape(shape)
        scheme = (
            "adaptive multiple importance sampling of the exact posterior (axle-force fluctuations "
            "integrated out at every point), started from the linearised posterior, which failed its "
            "importance check; equal-weight draws resampled from the weighted ones"
        )
    elif kind == "linearised":
        sig = par["sigma"].reshape(shape)
        scheme = (
            "emcee on the force fluctuation's scale, time scale and sigma; the axle-force fluctuations and "
            "the other parameters, linearised about their conditional mean, integrated out exactly and "
            "drawn from their Gaussian conditional; the linearisation checked by importance weights"
        )
    elif forces:
        sig = par["sigma"].reshape(shape)
        scheme = (
            "emcee on every inferred parameter; axle-force fluctuations integrated out (Woodbury)"
        )
    else:  # lp = log prior - (n/2) log RSS: RSS back from it, then sigma^2 | rest ~ InvGamma(n/2, RSS/2)
        rss_d = np.exp((post.log_prior(flat) - ch.lp.ravel()) * (2.0 / post.n))
        g = np.random.default_rng(seeding.stream(seed, "noise")).gamma(
            post.n / 2.0, 1.0, rss_d.size
        )
        sig = np.clip(np.sqrt(rss_d / (2.0 * g)), noise.low, noise.high).reshape(shape)
        scheme = (
            "emcee on every inferred parameter, sigma marginalised; exact inverse-gamma sigma draws"
        )
    nuisance: dict = {"crossings": {}}
    if damping is not None:
        nuisance["damping_ratio"] = par["zeta"].reshape(shape)
    if forces:
        nuisance["axle_force_sd"] = par["s"].reshape(shape)
        nuisance["axle_force_time_scale"] = par["l"].reshape(shape)
    for i, c in enumerate(post.terms):
        e = {}
        if c.speed_sd > 0:
            e["speed"] = par["v"][i].reshape(shape)
        if c.entry_time_sd > 0:
            e["entry_time"] = par["t0"][i].reshape(shape)
        if c.sprung:
            e["body_frequency"] = par["fb"][i].reshape(shape)
            e["body_damping"] = par["zb"][i].reshape(shape)
        nuisance["crossings"][c.name] = e
    diag: dict = {}
    problems = []
    if kind == "importance":  # weighted draws: the weights' ESS and k-hat, not chain statistics
        imp = extra["importance"]
        diag.update(rhat=None, ess_bulk=imp["ess"], ess_tail=imp["ess"])
        if not imp["passed"]:
            problems.append(
                f"importance sampling of the exact posterior did not converge in {imp['rounds']} "
                f"rounds (ESS {imp['ess']:.0f}, Pareto k-hat {imp['khat']:.2f}; {imp['criterion']})"
            )
    else:
        for n in L.names:
            d = mcmc_diagnostics(draws[:, :, L.index[n]])
            if not diag or d["rhat"] > diag["rhat"]:
                diag.update(rhat=d["rhat"])
            for k in ("ess_bulk", "ess_tail"):
                diag[k] = min(diag.get(k, math.inf), d[k])
        if not (
            diag["rhat"] <= RHAT_MAX and diag["ess_bulk"] >= ESS_MIN and diag["ess_tail"] >= ESS_MIN
        ):
            problems.append(
                f"R-hat {diag['rhat']:.3f} (at most {RHAT_MAX}), ESS "
                f"{min(diag['ess_bulk'], diag['ess_tail']):.0f} (at least {ESS_MIN:.0f})"
            )
            warnings.warn(
                f"crossing MCMC did not meet R-hat <= {RHAT_MAX} and ESS >= {ESS_MIN}: {diag}",
                RuntimeWarning,
                stacklevel=2,
            )
    converged = not problems
    diag.update(
        converged=converged, problems=problems, tau=ch.tau, steps=ch.steps, walkers=s.n_walkers * s.n_groups,
        acceptance=ch.acceptance, n_modes=n_modes, truncation_error=trunc,
        force_basis=[c.model.n_basis for c in post.terms] if forces else 0,
        parameters=list(L.names), noise_prior=noise.describe(), scheme=scheme,
        diagnostics_over="the worst of every sampled parameter", **extra,
    )  # fmt: skip
    mean_th = flat.mean(axis=0)
    info = {"map": {n: float(v) for n, v in zip(L.names, th, strict=True)}}
    predictor = CrossingsPredictor(cfg, data, post, flat, mean_th)
    out = CrossingsReference(
        REFERENCE_KEY, EI, sig, diagnostics=diag, info=info, predictor=predictor,
        sample_stats=(
            {"lp": lp_is.reshape(shape)}
            if kind == "importance"
            else {"lp": ch.lp, "acceptance": ch.walker_acceptance}
        ),
        nuisance=nuisance, crossing_names=tuple(c.name for c in post.terms),
    )  # fmt: skip
    if fit_checks and len(post.terms) > 1:
        out.info["crossing_fit_checks"] = crossing_fit_checks(out, data, cfg, post)
    out.runtime_s = time.perf_counter() - t_start
    return out


def _summarise(draws, truth) -> dict:
    """`uq.posterior.summarise`, with the absolute error `error` beside rel_error_pct (which a truth of 0,
    such as an entry time, has not)."""
    if truth is None:
        return summarise(draws)
    out = summarise(draws, truth if truth != 0 else None)
    out["error"] = out["mean"] - float(truth)
    return out


def _step(name: str, post: CrossingsLogPosterior) -> float:
    """Finite-difference step of each parameter for the Laplace scale."""
    if name.startswith("t0["):
        return 1e-4
    if name.startswith("log_v["):
        return 1e-5
    if name.startswith(("log_fb[", "log_zb[")):
        return 1e-2
    if name in RESONANT_NAMES:
        return 1e-2
    return {"log_EI": 1e-4, "log_zeta": 1e-2, "log_s": 1e-2, "log_l": 1e-2, "log_sigma": 1e-3}[name]
