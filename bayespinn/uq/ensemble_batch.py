"""Many ensembles trained as one network: the GPU's path for studies.

A coverage study, a sweep or a family study fits R datasets with one girder model. A 5-member network of
5 x 64 neurons is far too small to fill a GPU (launches, not arithmetic, bound its step), so on a GPU the
R x M members of the R ensembles train together as one batched network (weights (R M, in, out)).

Member m of dataset r is the member m that `ensemble.ensemble_posterior` trains for that dataset alone:
it draws its initial weights and collocation points from (seed r, m), sees its own dataset (its own
sample points; in phase 2 its own perturbed copy, noise sd and anchor), and its objective is independent
of every other member's (the gradient of the summed loss is per member; Adam and the variable-projection
solve of the output layer and EI act per member). The beta correction is per dataset, at its own members'
median. So each dataset's posterior is the one the single-dataset batched path gives, up to float
rounding (batched matrix products of another batch size round differently), and a study's records do not
depend on how its replicates were grouped beyond that.

The members' last-layer models (float64 CPU work: the noise level's grid and each member's local width)
are built by the executor's processes, one member per task.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from .. import seeding
from ..config import Config
from ..data.measurements import Measurements
from ..threads import torch_threads
from .ensemble import _last_layer, ensemble_posterior, phase2_settings, rto_inputs
from .ensemble_marginal import local_sd, sigma_grid
from .ensemble_pool import _Phase, pooled_posterior
from .posterior import Posterior
from .priors import EIPrior, NoisePrior

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class _LastLayerTask:
    """One member's last-layer model and sigma grid on its measured data (picklable)."""

    model: object  # the member alone (a one-member PINN)
    m: int  # its index in its own ensemble (its pseudo-observation stream)
    cfg: Config
    data: Measurements
    seed: object
    settings: object
    noise: NoisePrior
    keep: bool  # return the last-layer model too (phase 2)


def _member_last_layer(t: _LastLayerTask):
    """(sigma grid, and with `keep` the last-layer model and the member's local sd of log EI)."""
    from ..pinn import Problem

    with torch_threads(1):
        base = Problem.from_config(t.cfg, t.data)
        ll = _last_layer(t.model, t.m, base, t.data, t.seed, t.settings)
        g = sigma_grid(ll, t.noise)
        if not t.keep:
            return g, None
        return g, (ll, local_sd(ll, g, EIPrior.from_spec(t.cfg.prior)))


def _last_layers(fit_result, datas, cfg, seeds, noises, M, settings, executor, keep, progress):
    """(sigma grids, (last-layer model, local sd) or Nones) of every member of a fit of R x M members."""
    from ..executor import Executor, task_resources

    model = fit_result.model("cpu")
    tasks = [
        _LastLayerTask(model.member(r * M + m), m, cfg, d, seeds[r], settings, noises[r], keep)
        for r, d in enumerate(datas)
        for m in range(M)
    ]
    res = (executor or Executor()).map(
        _member_last_layer,
        tasks,
        desc="ensemble last layers",
        progress=progress,
        resources=task_resources("cpu"),
    )
    return [g for g, _ in res], [ll for _, ll in res]


def _layout(cfg: Config, d: Measurements) -> tuple:
    """What datasets trained as one network must share: rows (count, kind, y) and duration."""
    from ..pinn import Problem

    dur = Problem.from_config(cfg, d).duration
    a_u, a_xx = d.weights  # each row's observation operator (from its kind and y)
    return (len(d), np.asarray(a_u, float).tobytes(), np.asarray(a_xx, float).tobytes(), dur)


def ensemble_posteriors(
    datas: list[Measurements],
    cfg: Config,
    *,
    seeds: list,
    noises: list[NoisePrior],
    members: int = 5,
    profile: str = "fast",
    device: str = "cuda",
    executor=None,
    progress: bool = False,
) -> list[Posterior]:
    """The deep-ensemble posterior of each dataset (`ensemble.ensemble_posterior`), with the members of all
    of them trained as one network on `device`.

    Parameters
    ----------
    datas : R measurement sets of the girder `cfg`; those that share their rows (count, kind, y) and
        duration train together, a dataset without rows gets the prior
    seeds : R ensemble seeds (int or SeedSequence), one per dataset
    noises : R noise priors, one per dataset
    members, profile, device : as `ensemble_posterior`
    executor : builds the members' last-layer models (default: the local process pool)

    Returns the R posteriors in order; each one's `runtime_s` is its share of the whole.
    """
    from ..pinn import TrainSettings

    if not (len(datas) == len(seeds) == len(noises)):
        raise ValueError(
            f"need one seed and one noise prior per dataset: {len(datas)} datasets, "
            f"{len(seeds)} seeds, {len(noises)} noise priors"
        )
    seeds = [
        s if isinstance(s, np.random.SeedSequence) else np.random.SeedSequence(int(s))
        for s in seeds
    ]
    settings = TrainSettings.for_profile(profile)
    out: list[Posterior | None] = [None] * len(datas)
    groups: dict[tuple, list[int]] = {}
    for r, d in enumerate(datas):
        if len(d) == 0:
            out[r] = ensemble_posterior(
                d, cfg, seed=seeds[r], members=members, profile=profile, noise=noises[r]
            )
        else:
            groups.setdefault(_layout(cfg, d), []).append(r)
    for idx in groups.values():
        posts = _together(
            [datas[r] for r in idx],
            cfg,
            [seeds[r] for r in idx],
            [noises[r] for r in idx],
            int(members),
            settings,
            device,
            executor,
            progress,
        )
        for r, p in zip(idx, posts, strict=True):
            out[r] = p
    return out


def _together(
    datas, cfg, seeds, noises, M, settings, device, executor, progress
) -> list[Posterior]:
    from ..pinn import Problem, fit

    t0 = time.perf_counter()
    R = len(datas)
    quiet = not progress
    ei_prior = EIPrior.from_spec(cfg.prior)
    bases = [Problem.from_config(cfg, d) for d in datas]
    log.info("[ensemble] %d datasets x %d members as one network on %s", R, M, device)
    # phase 1: every member on its dataset
    prob1 = Problem.from_config(cfg, tuple(d for d in datas for _ in range(M)))
    r1 = fit(
        prob1,
        settings,
        seed=[seeding.stream(s, "init") for s in seeds],
        members=R * M,
        device=device,
        quiet=quiet,
    )
    grids1, _ = _last_layers(r1, datas, cfg, seeds, noises, M, settings, executor, False, progress)
    # phase 2: randomise-then-optimise, each dataset's from its own phase 1
    rto = [
        rto_inputs(d, grids1[r * M : (r + 1) * M], seeds[r], ei_prior, M)
        for r, d in enumerate(datas)
    ]
    prob2 = Problem.from_config(
        cfg,
        tuple(p for _, _, pdata in rto for p in pdata),
        noise_sd=[sh for sh, _, _ in rto for _ in range(M)],
        anchor=(np.concatenate([a for _, a, _ in rto]), ei_prior.log_sd),
    )
    r2 = fit(
        prob2,
        phase2_settings(settings),
        seed=[seeding.stream(s, "collocation") for s in seeds],
        members=R * M,
        device=device,
        quiet=quiet,
        init_state=r1.state,
    )
    grids2, kept = _last_layers(
        r2, datas, cfg, seeds, noises, M, settings, executor, True, progress
    )
    lls2 = [ll for ll, _ in kept]
    sds2 = np.array([sd for _, sd in kept])
    share = (time.perf_counter() - t0) / R
    bf1, bf2 = (np.broadcast_to(np.asarray(r.beta_factor, float), (R,)) for r in (r1, r2))
    EI1, EI2 = np.asarray(r1.EI, float), np.asarray(r2.EI, float)
    training = f"batched (one network of {R} datasets x {M} members)"
    posts = []
    for r in range(R):
        sl = slice(r * M, (r + 1) * M)
        p1 = _Phase(EI1[sl], np.full(M, bf1[r]), grids1[sl], None, None, None, r1.runtime_s / R)
        p2 = _Phase(EI2[sl], np.full(M, bf2[r]), grids2[sl], lls2[sl], None, None, r2.runtime_s / R)
        sigma_hat = rto[r][0]
        posts.append(
            pooled_posterior(
                p1,
                p2,
                sigma_hat,
                bases[r],
                ei_prior,
                seeds[r],
                M,
                training,
                t0,
                runtime_s=share,
                lap_sd=sds2[sl],
            )
        )
    return posts


__all__ = ["ensemble_posteriors"]
