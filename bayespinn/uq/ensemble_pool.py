"""The deep ensemble's posterior from its two training phases (`uq.ensemble`): the equal mixture of the
members' last-layer marginals of EI, sigma (and the AR(1) coefficient) drawn from the members' grids, the
info and warnings a reader needs (members with no peak, members that disagree), and the mixture of the
members' predictives. Shared with the batched ensembles of many datasets (`uq.ensemble_batch`).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import numpy as np

from .. import seeding
from ..threads import torch_threads
from .ensemble_marginal import local_sd, member_marginal, pool_log_ei
from .lastlayer import (
    GRID_EDGE,
    IDENTIFIED_FRACTION,
    LastLayerPredictor,
)
from .pinn_ar1 import AR1Posterior
from .posterior import Posterior
from .priors import EIPrior

#: the ensemble's logger: its warnings read as they did when this was part of `uq.ensemble`
log = logging.getLogger("bayespinn.uq.ensemble")

#: posterior draws stored
N_DRAWS = 4000
#: members scattering more than this many times their own local sd are flagged as not converged
#: (with 5 members the sample sd is itself uncertain by ~35 %, so 3x is far outside chance)
MAX_SCATTER_RATIO = 3.0


@dataclass(frozen=True)
class _Phase:
    """One training phase of M members, as either path (batched or one task per member) returns it."""

    EI: np.ndarray  # (M,) [N m^2], beta-corrected
    beta_factor: np.ndarray  # (M,)
    grids: list  # SigmaGrid per member, on the measured data
    last_layers: list | None  # LastLayer per member (phase 2)
    states: list | None  # per-member state dicts (phase 1, the warm start of phase 2; task path)
    state: dict | None  # the batched state (batched path)
    runtime_s: float  # training time, summed over members when they ran as separate tasks
    fit0: object = None  # phase 1, task path: member 0's FitResult (the B-PINN's warm start)
    lap_sd: np.ndarray | None = None  # phase 2, task path: each member's local width (in its task)
    marginals: list | None = (
        None  # phase 2, task path: each member's marginal of log EI (in its task)
    )


def pooled_posterior(
    p1: _Phase,
    p2: _Phase,
    sigma_hat: float,
    base,
    ei_prior: EIPrior,
    seed,
    M: int,
    training: str,
    t0: float,
    runtime_s: float | None = None,
    lap_sd: np.ndarray | None = None,
) -> Posterior:
    """The ensemble's posterior from its two phases: members' local widths (`lap_sd`, computed here from
    phase 2's last layers unless given) pooled with their spread."""
    member_EI = p2.EI
    log_ei_m = np.log(member_EI)
    # per member, on the measured data: the noise level's grid posterior, the local width of log EI and
    # the member's marginal of log EI (its posterior given its features), centred where the data put it
    lls, grids = p2.last_layers, p2.grids
    shifts = [math.log(base.EI_ref) - math.log(f) for f in p2.beta_factor]
    if lap_sd is None:
        lap_sd = p2.lap_sd
    with torch_threads(1):
        if lap_sd is None:
            lap_sd = np.array([local_sd(ll, g, ei_prior) for ll, g in zip(lls, grids, strict=True)])
        marginals = p2.marginals
        if marginals is None:
            marginals = [
                member_marginal(ll, g, ei_prior, sh, float(sd))
                for ll, g, sh, sd in zip(lls, grids, shifts, lap_sd, strict=True)
            ]
    mu, between, lap_var, n_marg, pooled = pool_log_ei(log_ei_m, marginals, ei_prior.log_sd)
    warn = []
    bad = [i for i, m in enumerate(marginals) if m is None]
    if bad:
        warn.append(
            f"member(s) {bad}: the last-layer marginal likelihood has no peak in EI near the member's own "
            "fit, so they give no posterior of their own; the interval rests on the other members"
            + ("" if n_marg else " (none has one: on the spread between the trained members)")
        )
    draw_rng = np.random.default_rng(seeding.child(seed, "ensemble", 0))
    ok = [m for m in marginals if m is not None]
    if ok:  # the equal mixture of the members' marginals
        log_ei = np.concatenate([m.draws(-(-N_DRAWS // len(ok)), draw_rng) for m in ok])[:N_DRAWS]
        log_ei = log_ei[draw_rng.permutation(N_DRAWS)]
    else:
        log_ei = mu + math.sqrt(pooled) * draw_rng.standard_normal(N_DRAWS)
    rho = None
    if grids[0].z is None:
        sigma = np.concatenate([g.draws(-(-N_DRAWS // M), draw_rng) for g in grids])[:N_DRAWS]
        sigma = sigma[draw_rng.permutation(N_DRAWS)]
    else:  # AR(1): sigma and rho jointly, from each member's grid
        sr = [g.draws_ar1(-(-N_DRAWS // M), draw_rng) for g in grids]
        perm = draw_rng.permutation(N_DRAWS)
        sigma = np.concatenate([a for a, _ in sr])[:N_DRAWS][perm]
        rho = np.concatenate([b for _, b in sr])[:N_DRAWS][perm]
    ident = bool(math.sqrt(pooled) < IDENTIFIED_FRACTION * ei_prior.log_sd)
    info = {
        "members": M,
        "member_EI": member_EI.tolist(),
        "member_posterior_EI": [None if m is None else math.exp(m.mean) for m in marginals],
        "member_local_sd_log_EI": [None if m is None else math.sqrt(m.var) for m in marginals],
        "fit_between_sd_log_EI": float(np.std(log_ei_m, ddof=1)) if M > 1 else 0.0,
        "between_sd_log_EI": math.sqrt(between),
        "local_sd_log_EI": math.sqrt(lap_var),
        "pooling": (
            f"equal mixture of {n_marg:g} members' last-layer marginals of EI"
            if n_marg
            else f"the {M} trained EIs: their spread x (1 + 1/{M})"
        ),
        "sigma_hat_rto": sigma_hat,
        "member_sigma_mode": [g.mode for g in grids],
        **(
            {"member_noise_ar1_mode": [math.tanh(g.z_mode) for g in grids]}
            if rho is not None
            else {}
        ),
        "member_first_mode_follows_EI": [ll.first_mode_varies for ll in lls],
        # the share of the fitted response's energy the network carries beyond the enrichment
        "network_share": float(np.median([ll.network_share for ll in lls])),
        "member_network_share": [ll.network_share for ll in lls],
        "identified": ident,
    }
    if M == 1:
        info["note"] = "a single member has no spread: its interval is its own local width only"
    if not ident:
        info["note"] = "EI is not identified by these data"
    # self-check: members whose posteriors' means scatter far more than each one's own width read EI
    # differently from their features; the mixture is then mostly the spread between networks
    disagree = bool(n_marg > 1 and lap_var > 0 and between > MAX_SCATTER_RATIO**2 * lap_var)
    if disagree:
        msg = (
            f"the members disagree: their posteriors' means spread by sd {math.sqrt(between):.3f} in log EI, "
            f"{math.sqrt(between / lap_var):.1f} x each member's own width ({math.sqrt(lap_var):.3f}); "
            "the networks have not converged to one answer, so this interval mostly measures their scatter"
        )
        warn.append(msg)
    for msg in warn:
        log.warning("[ensemble] %s", msg)
    if warn:
        info["warnings"] = warn
    # the verdict: the members agree within their own widths, each has a marginal of its own, and no
    # noise grid cuts off its posterior's mass
    checks = {
        "members_agree": (
            not disagree,
            f"the members' means scatter more than {MAX_SCATTER_RATIO:g} x their own widths",
        ),
        "every_member_has_a_marginal": (
            not bad,
            "some member has no last-layer marginal of its own",
        ),
        "noise_grids_hold_their_mass": (
            not any(g.at_edge(GRID_EDGE) for g in grids),
            "a noise grid cuts off part of its posterior",
        ),
    }
    problems = [why for ok, why in checks.values() if not ok]
    diag = {
        "converged": not problems,
        "convergence_checks": {k: ok for k, (ok, _) in checks.items()},
        **({"problems": problems} if problems else {}),
        "fit_runtime_s": p1.runtime_s + p2.runtime_s,
        "fit_runtime_summed": True,  # over the members, which train in parallel worker processes
        "beta_factor": float(np.median(p2.beta_factor)),
        "training": training,
    }
    predictor = _MixturePredictor(
        [
            LastLayerPredictor(
                ll,
                np.full(64, math.log(ll.theta_fit)) if m is None else m.draws(64, draw_rng) - sh,
                np.full(64, math.log(g.mode)),
                sh,
                None if g.z is None else np.full(64, g.z_mode),
            )
            for ll, g, sh, m in zip(lls, grids, shifts, marginals, strict=True)
        ]
    )
    kw = dict(
        diagnostics=diag,
        info=info,
        runtime_s=time.perf_counter() - t0 if runtime_s is None else runtime_s,
        predictor=predictor,
    )
    if rho is not None:
        return AR1Posterior(
            "ensemble", np.exp(log_ei)[None, :], sigma[None, :], ar1=rho[None, :], **kw
        )
    return Posterior("ensemble", np.exp(log_ei)[None, :], sigma[None, :], **kw)


class _MixturePredictor:
    """Predictive draws split evenly over the members' own last-layer predictives."""

    def __init__(self, parts: list):
        self.parts = parts

    def __call__(
        self, x, t, quantity: str = "deflection", n_draws: int = 200, rng=None
    ) -> np.ndarray:
        rng = rng or np.random.default_rng(0)
        k = max(1, n_draws // len(self.parts))
        return np.concatenate([p(x, t, quantity, k, rng) for p in self.parts])
