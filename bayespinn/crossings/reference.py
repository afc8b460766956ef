"""The modal reference for real crossings: EI with what a recording leaves uncertain (the speed, the entry
time on the data's clock, the damping ratio, the axles' dynamic forces and the girder's resonant response
to them), one or several crossings.

`crossings_reference(data, cfg, seed=...)` finds the maximum of the posterior (`peak`: EI profiled on a
grid at the stated values, then least squares with the priors as pseudo-observations) and samples from
there. With constant forces: emcee (`uq.sampler.sample`, the reference's driver) on every inferred
parameter, the noise sd integrated out and drawn afterwards from its exact inverse-gamma conditional, or
with several crossings each one's speed and entry time by Laplace (`laplace`). With fluctuating forces the
forces and the resonant terms (`resonance`) are integrated out exactly; the rest is linearised
(`linearised`: importance sampling, or emcee, on the hyperparameters, the other parameters from their
Gaussian conditional) and,
where that fails its importance check, the exact posterior is importance-sampled (`importance`). With
constant forces, EI, damping and noise are shared by all crossings; speed, entry time and suspension are
each crossing's own. Several crossings with fluctuating forces are analysed one at a time and EI combined
with a crossing-level error (`combine`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
import warnings

import numpy as np
from scipy.optimize import minimize

from .. import seeding
from ..config import Config
from ..data.measurements import Measurements
from ..threads import one_blas_thread
from ..uq.posterior import mcmc_diagnostics
from ..uq.priors import EIPrior, NoisePrior, prior_only
from ..uq.sampler import ESS_MIN, RHAT_MAX, MCMCSettings, sample
from . import peak
from .checks import (  # noqa: F401  (re-exported: the package's names)
    check_crossings,
    needs_crossings,
    refuse_crossings,
    split_crossings,
)
from .likelihood import CrossingsLogPosterior
from .result import CrossingsReference

#: chains the importance sampler's resampled draws are split into (a layout, not independent chains)
IMPORTANCE_CHAINS = 4


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
    combine: bool | None = None,
    method: str,
) -> CrossingsReference:
    """The reference posterior of EI and of what the crossings leave uncertain (module docstring).

    laplace : integrate each crossing's speed and entry time out by Laplace (`crossings.laplace`) and sample
        the shared parameters alone; None: with several crossings and constant forces. False: emcee on
        every parameter (the brute force it is checked against).
    combine : analyse each crossing on its own and combine EI through a crossing-level error
        (`crossings.combine`); None: with several crossings and fluctuating forces. False: one model of
        every crossing, the force law, damping and noise shared.
    method : the summary key the posterior is labelled with (the reference's, `methods.REFERENCE_KEY`)."""
    from .predictor import CrossingsPredictor, crossing_fit_checks

    t_start = time.perf_counter()
    check_crossings(cfg, data)
    if len(data) == 0:
        return prior_only(EIPrior.from_spec(cfg.prior), seed, t_start, method)
    s = settings or MCMCSettings()
    m = cfg.model
    forces = m.axle_forces == "fluctuating"
    if combine is None:
        combine = forces and len(split_crossings(cfg, data)) > 1
    if combine:
        from .combine import combined_reference

        return combined_reference(
            data,
            cfg,
            seed=seed,
            settings=s,
            progress=progress,
            single=functools.partial(crossings_reference, method=method),
        )
    damping = (
        (cfg.prior.damping_median, cfg.prior.damping_log_sd) if m.damping == "inferred" else None
    )
    ei_prior = EIPrior.from_spec(cfg.prior)
    noise = NoisePrior.build("vague", np.asarray(data.value, float))
    # the second mode's damping ratio (its resonant term): its own, with the damping prior
    mode_damping = (cfg.prior.damping_median, cfg.prior.damping_log_sd)

    def post_of(n_modes: int) -> CrossingsLogPosterior:
        return CrossingsLogPosterior(
            peak.terms(cfg, data, n_modes, forces), ei_prior, noise,
            zeta_known=cfg.beam.damping_ratio, damping_prior=damping, forces=forces,
            mode_damping_prior=mode_damping,
        )  # fmt: skip

    post = post_of(8)
    th = peak.start(post, cfg)
    th, sigma = peak.least_squares_fit(post, th)
    n_modes, trunc = peak.choose_modes(cfg, data, post_of, th, sigma)
    if n_modes != 8:
        post = post_of(n_modes)
        th, sigma = peak.least_squares_fit(post, th)
    rss = sum(float(np.sum(r**2)) for r, _ in post.residuals(th[None]))
    sigma = math.sqrt(rss / post.n)
    L = post.layout
    if forces:
        th = peak.fluctuation_start(post, th, sigma)
    h = np.array([peak.step(n, post) for n in L.names])
    if laplace is None:
        kind = "linearised" if forces else ("laplace" if len(post.terms) > 1 else "emcee")
    else:
        kind = ("linearised" if forces else "laplace") if laplace else "emcee"
    extra: dict = {}
    hyper_is = False  # the linearised scheme's hyperparameters by importance sampling
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
        hyper_is = kind == "linearised" and extra["linearisation"]["hyper_sampler"] == "importance"
        draws = flat.reshape(*shape, L.dim)
    else:
        if forces:  # the whole maximum under the exact likelihood
            res = minimize(
                lambda z: -float(post(z[None])[0]), th, method="Nelder-Mead",
                options={"maxiter": 150 * L.dim, "xatol": 1e-6, "fatol": 1e-3},
            )  # fmt: skip
            if np.isfinite(res.fun) and res.fun < -float(post(th[None])[0]):
                th = res.x
        scale = peak.hessian_scale(post, th, h)
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
            ("adaptive importance sampling" if hyper_is else "emcee")
            + " on the force fluctuation's scale, time scale and sigma; the axle-force fluctuations and "
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
        if "logit_r" in L.index:
            nuisance["axle_force_correlation"] = par["r"].reshape(shape)
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
    if kind == "linearised" and hyper_is:  # resampled importance draws: the weights' ESS, not R-hat
        imp = extra["linearisation"]["hyper_importance"]
        diag.update(rhat=None, ess_bulk=imp["ess"], ess_tail=imp["ess"])
    elif kind == "importance":  # weighted draws: the weights' ESS and k-hat, not chain statistics
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
        force_band=[c.model.n_band for c in post.terms] if forces else 0,
        dynamic_modes=[c.model.basis_modes for c in post.terms] if forces else 0,
        parameters=list(L.names), noise_prior=noise.describe(), scheme=scheme,
        diagnostics_over="the worst of every sampled parameter", **extra,
    )  # fmt: skip
    mean_th = flat.mean(axis=0)
    info = {"map": {n: float(v) for n, v in zip(L.names, th, strict=True)}}
    predictor = CrossingsPredictor(cfg, data, post, flat, mean_th)
    out = CrossingsReference(
        method, EI, sig, diagnostics=diag, info=info, predictor=predictor,
        sample_stats=(
            {"lp": lp_is.reshape(shape)}
            if kind == "importance"
            else {k: v for k, v in (("lp", ch.lp), ("acceptance", ch.walker_acceptance)) if v is not None}
        ),
        nuisance=nuisance, crossing_names=tuple(c.name for c in post.terms),
    )  # fmt: skip
    if fit_checks and len(post.terms) > 1:
        out.info["crossing_fit_checks"] = crossing_fit_checks(out, data, cfg, post)
    out.runtime_s = time.perf_counter() - t_start
    return out
