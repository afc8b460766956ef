"""B-PINN in Pyro: NUTS on (log EI, log sigma) of a last-layer Bayesian PINN.

The variant (after Yang, Meng & Karniadakis's B-PINNs, with the linear output layer integrated out
analytically, see `lastlayer`): a deterministic PINN fit (the one training loop) provides the hidden
features; the output weights get a Gaussian prior and are marginalised exactly; the data likelihood
is Gaussian with unknown sigma; PDE, boundary and initial residuals enter as Gaussian pseudo-observations
with stated scales. Pyro's NUTS samples the two remaining parameters through a `potential_fn` (no
tracing per step), several chains from a dispersed start around the MAP; ArviZ gives R-hat and ESS, and
`nuts` the divergences, tree depths and warnings, all of which decide whether the run counts as converged.

This is the fast default. `bpinn_full` samples every hidden weight too (the same model with the hidden
layers free); it runs only when `--bpinn-variant full` asks for it (`bayespinn.methods.bpinn`), and the
summary's `info.variant` names the one that ran.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np
import torch

from .. import seeding
from ..config import Config
from ..data.measurements import Measurements
from ..threads import torch_threads
from .ar1 import AR1Noise
from .bpinn_core import (
    LastLayerPotential,
    assemble,
    last_layer_map,
    log_shift,
    no_data,
    warm_start_fit,
)
from .lastlayer import LastLayerPredictor
from .nuts import NUTSSettings, Whitened, nuts_health, run_nuts, sample_stats, valid_start
from .posterior import Posterior
from .priors import EIPrior, NoisePrior

log = logging.getLogger(__name__)

VARIANT = "last-layer B-PINN (output weights marginalised analytically; NUTS on log EI, log sigma)"


@dataclass(frozen=True)
class _Chain:
    """One NUTS chain of `nuts`, an executor task: its result is a function of (pot, z_map, L, s, seed, c)."""

    pot: LastLayerPotential
    z_map: np.ndarray
    L: np.ndarray
    s: NUTSSettings
    seed: object
    c: int
    progress: bool = False


def _run_chain(t: _Chain):
    """(z draws (draw, dim), the chain's run) of chain t.c, from a dispersed start (2 Laplace sds around the
    MAP, `valid_start`) on its own seed."""
    wpot = Whitened(t.pot, t.z_map, t.L)
    cs = seeding.child(t.seed, "pyro", t.c)
    u0 = valid_start(
        wpot,
        torch.tensor(np.random.default_rng(cs).standard_normal(len(t.z_map)), dtype=torch.float64),
    )
    run = run_nuts(
        wpot,
        {"u": u0},
        warmup=t.s.warmup,
        samples=t.s.samples,
        seed=cs,
        full_mass=True,
        max_tree_depth=t.s.max_tree_depth,
        progress=t.progress,
    )
    return wpot.z_draws(run.samples["u"]), run


def nuts(
    pot: LastLayerPotential,
    z_map: np.ndarray,
    L: np.ndarray,
    s: NUTSSettings,
    seed,
    progress: bool,
    executor=None,
):
    """Run `s.chains` NUTS chains on the whitened potential, each from a dispersed start on its own seed, as
    tasks of `executor` (default: the local pool, one process per core; each chain runs single-threaded
    wherever it runs, so the draws do not depend on the executor); draws of z (chain, draw, 2, or 3 with
    AR(1) noise) and the chains' runs (sample statistics, warnings)."""
    from ..executor import Executor, task_resources

    tasks = [_Chain(pot, z_map, L, s, seed, c) for c in range(s.chains)]
    res = (executor or Executor()).map(
        _run_chain, tasks, desc="B-PINN chains", progress=progress, resources=task_resources("cpu")
    )
    return np.stack([d for d, _ in res]), [r for _, r in res]


def lastlayer_posterior(
    data: Measurements,
    cfg: Config,
    *,
    seed: int | np.random.SeedSequence,
    profile: str,
    device: str,
    noise: NoisePrior,
    progress: bool = False,
    fit_seed=None,
    executor=None,
) -> Posterior:
    """Fit a PINN, then sample the last-layer B-PINN posterior of (EI, sigma) with NUTS; with `[model] noise =
    "ar1"` the noise is AR(1) along each sensor's series and its coefficient is sampled too. The chains are
    tasks of `executor` (`nuts`)."""
    t0 = time.perf_counter()
    if len(data) == 0:
        return no_data(cfg, seed, t0)
    res, problem, settings, warm = warm_start_fit(
        data, cfg, seed, profile, device, progress, fit_seed
    )
    ei_prior = EIPrior.from_spec(cfg.prior)
    shift = log_shift(res, problem)
    with torch_threads(1):  # tiny linear algebra (see `threads`)
        draws, diag, pred, stats = _sample_last_layer(
            res,
            problem,
            data,
            seed,
            profile,
            progress,
            noise,
            settings,
            ei_prior,
            shift,
            cfg,
            executor,
        )
    share = diag.pop("network_share")
    post = assemble(
        draws,
        diag,
        pred,
        stats,
        res=res,
        shift=shift,
        ei_prior=ei_prior,
        variant="last-layer",
        name=VARIANT,
        t0=t0,
        warm_start=warm,
    )
    post.info["network_share"] = share  # of the fit the posterior is built on
    return post


def _sample_last_layer(
    res,
    problem,
    data,
    seed,
    profile,
    progress,
    noise,
    settings,
    ei_prior,
    shift,
    cfg,
    executor=None,
):
    """NUTS on (log theta, log sigma[, atanh rho]) of the last-layer model: z draws (chain, draw, 2 or 3),
    diagnostics, predictor and the chains' sample statistics."""
    ar1 = AR1Noise.of(data) if cfg.model.noise == "ar1" else None
    _, ll, pot, z_map, L = last_layer_map(
        res, problem, data, seed, noise, settings, ei_prior, shift, ar1=ar1
    )
    log.info("[bpinn] NUTS: %s", VARIANT)
    s = NUTSSettings.for_profile(profile)
    draws, runs = nuts(pot, z_map, L, s, seed, progress, executor)
    diag = {
        "chains": s.chains,
        "warmup": s.warmup,
        "samples": s.samples,
        **nuts_health(runs),
        "pseudo_sd": {"pde": ll.s_f, "bc": ll.s_b, "ic": ll.s_i},
        "network_share": ll.network_share,
        "first_mode": {
            "follows_EI": ll.first_mode_varies,
            "vibration_z2": ll.vibration_z2,
            "threshold": ll.vibration_threshold,
        },
    }
    pred = LastLayerPredictor(
        ll,
        draws[:, :, 0].ravel(),
        draws[:, :, 1].ravel(),
        shift,
        draws[:, :, 2].ravel() if ar1 is not None else None,
    )
    return draws, diag, pred, sample_stats(runs)
