"""The smooth EI field's posterior search and sampler (`uq.girder_field` explains the model): a global
grid whose local maxima start Levenberg-Marquardt runs (`_grid_starts`, `_lm_map`), the distinct modes
(`_distinct`), and adaptive multiple importance sampling around them (`amis`, also the girder PINN's
sampler of each member's last-layer posterior, `uq.girder_sampling`). Each takes the field's
`residuals` or `log_target` (`girder_field._Problem`), so it knows nothing of the girder."""

from __future__ import annotations

import math

import numpy as np
from scipy.special import gammaln, ndtri

from .sampler import ESS_MIN

#: the MAP search's global grid, points equally spaced in prior probability: positions along the span
#: (`_grid_starts`' `positions`: one per piece of the surrogate), widths and depths; at most STARTS of the
#: grid's local maxima start the search
GRID_WIDTHS = 8
GRID_DEPTHS = 8
STARTS = 16
#: every coordinate of theta (standard normal a priori) is confined to this many sd
SUPPORT_SD = 8.0
#: modes whose Laplace evidence is below this fraction of the best are not sampled
MODE_CUTOFF = 1e-4
#: draws per proposal and round; rounds at least and at most (between them, until the effective sample
#: size reaches `sampler.ESS_MIN`); the least effective share of draws a refit uses
DRAWS_PER_ROUND = 500
AMIS_ROUNDS = 3
AMIS_MAX_ROUNDS = 10
AMIS_TEMPER_ESS = 0.1
#: a refitted proposal's covariance is the draws' weighted one times this: an importance proposal needs
#: tails wider than its target's (with 1, the depth-width ridge of a narrow loss left the effective
#: sample size at 67 of 5000 draws on one dataset; with 2 it reached the target on the same one)
AMIS_INFLATE = 2.0
#: degrees of freedom of the proposals
T_DOF = 5
#: the MAP search stops when an accepted step raises log p by less than this
TOL_LOGP = 1e-4
#: step of the central-difference Jacobian in theta
FD_STEP = 1e-5


def _grid_starts(
    residuals, y: np.ndarray, a0: float, sd: float, positions: int
) -> tuple[list[np.ndarray], int]:
    """Starting points of the MAP search from a global grid: `positions` x `GRID_WIDTHS` x
    `GRID_DEPTHS` points in (position, width, depth), each equally spaced in prior probability, the level
    profiled out around the level-only fit a0 (sd: the level's prior sd in log EI); each (position, width) cell keeps its best depth, and the cells that beat their
    eight neighbours, best first, are the starts (at most `STARTS`). Returns them and the number of
    surrogate evaluations."""
    u = [ndtri((np.arange(k) + 0.5) / k) for k in (GRID_DEPTHS, positions, GRID_WIDTHS)]
    ud, up, uw = np.meshgrid(*u, indexing="ij")  # (depth, position, width)
    th = np.stack([np.full(ud.size, a0), ud.ravel(), up.ravel(), uw.ravel()], axis=1)
    r, _ = residuals(th)
    # the level profiled out as a scale of the response (exact for the static part, where the response
    # is proportional to 1 / level): prediction p = y - r scaled by c = p.y / p.p, level shifted by
    # -log(c) / sd
    p = y[None] - r
    with np.errstate(all="ignore"):
        c = np.clip((p @ y) / np.einsum("wp,wp->w", p, p), 1e-3, 1e3)
        a = a0 - np.log(c) / sd
        rss = np.einsum("wp,wp->w", y[None] - c[:, None] * p, y[None] - c[:, None] * p)
        lp = -0.5 * (a**2 + np.sum(th[:, 1:] ** 2, 1)) - 0.5 * y.size * np.log(rss)
    lp = np.where(np.isfinite(lp) & (np.abs(a) < SUPPORT_SD), lp, -np.inf).reshape(ud.shape)
    a = a.reshape(ud.shape)
    best_d = np.argmax(lp, axis=0)  # (position, width)
    cell = np.max(lp, axis=0)
    padded = np.pad(cell, 1, constant_values=-np.inf)
    P, W = cell.shape
    neighbours = np.stack(
        [
            padded[1 + i : 1 + i + P, 1 + j : 1 + j + W]
            for i in (-1, 0, 1)
            for j in (-1, 0, 1)
            if (i, j) != (0, 0)
        ]
    )
    peak = np.isfinite(cell) & np.all(cell >= neighbours, axis=0)
    order = [int(q) for q in np.argsort(-np.where(peak, cell, -np.inf), axis=None) if peak.flat[q]]
    starts = []
    for q in order[:STARTS]:
        ip, iw = np.unravel_index(q, cell.shape)
        id_ = best_d[ip, iw]
        starts.append(np.array([a[id_, ip, iw], u[0][id_], u[1][ip], u[2][iw]]))
    return starts, th.shape[0]


def _lm_map(residuals, n: int, theta0: np.ndarray, max_iter: int = 60):
    """MAP of N(theta; 0, I) RSS^(-n/2) by Levenberg-Marquardt from theta0 (`residuals` as in
    `_field_posterior`); returns theta, its log density, the Gauss-Newton Hessian of -log p and the
    number of surrogate evaluations. The Jacobian by central differences in theta."""
    D = theta0.size
    th = theta0.copy()
    r, lp = residuals(th[None])
    r, lp = r[0], lp[0]
    evals, mu = 1, 1e-3
    H = np.eye(D)
    for _ in range(max_iter):
        E = np.eye(D) * FD_STEP
        R, _ = residuals(np.vstack([th + E, th - E]))
        evals += 2 * D
        J = -(R[:D] - R[D:]).T / (2 * FD_STEP)  # d prediction / d theta, (n_obs, D)
        c = n / float(r @ r)
        g = th - c * (J.T @ r)
        H = np.eye(D) + c * (J.T @ J)
        improved, dlp = False, 0.0
        for _ in range(10):
            step = np.linalg.solve(H + mu * np.diag(np.diag(H)), -g)
            rn, lpn = residuals((th + step)[None])
            evals += 1
            if lpn[0] > lp:
                th, dlp, r, lp = th + step, lpn[0] - lp, rn[0], lpn[0]
                mu = max(mu / 10.0, 1e-9)
                improved = True
                break
            mu *= 10.0
        if not improved or dlp < TOL_LOGP:
            break
    return th, lp, H, evals


def _distinct(modes: list[dict]) -> list[dict]:
    """The modes in order of Laplace evidence, one per basin (a mode within 1 of a better one in the
    better one's Mahalanobis distance is the same), those below MODE_CUTOFF of the best dropped."""
    modes = sorted(modes, key=lambda f: -f["lap"])
    kept: list[dict] = []
    for f in modes:
        if f["lap"] - modes[0]["lap"] < math.log(MODE_CUTOFF):
            break
        if all((f["theta"] - k["theta"]) @ k["H"] @ (f["theta"] - k["theta"]) > 1.0 for k in kept):
            kept.append(f)
    return kept


def _log_t(dz: np.ndarray, Lc: np.ndarray) -> np.ndarray:
    """Log density of the multivariate t (`T_DOF`) with scale Lc Lc^T at the offsets dz (W, D)."""
    D = dz.shape[1]
    maha = np.sum(np.linalg.solve(Lc, dz.T) ** 2, 0)
    return (
        gammaln((T_DOF + D) / 2)
        - gammaln(T_DOF / 2)
        - 0.5 * D * math.log(T_DOF * math.pi)
        - np.sum(np.log(np.diag(Lc)))
        - 0.5 * (T_DOF + D) * np.log1p(maha / T_DOF)
    )


def amis(log_target, modes, rng, bar=None, max_rounds: int = AMIS_MAX_ROUNDS):
    """Adaptive multiple importance sampling: each round (at least AMIS_ROUNDS, then until the pooled
    effective sample size reaches ESS_MIN, at most `max_rounds`) draws DRAWS_PER_ROUND from a
    multivariate t per mode, the first round's around the mode's Laplace fit, each later one at the weighted mean and
    covariance of the draws of that mode's proposals so far (weights tempered until their effective sample
    size is at least AMIS_TEMPER_ESS of the draws, so one heavy draw cannot collapse a proposal). Every
    draw is weighted against the equal mixture of all proposals (deterministic-mixture weights).
    `log_target` maps draws (W, d) to (log target, RSS) (W,) each; `bar` (optional) is advanced once a
    round. Returns the draws, their log weights, their RSS and the number of evaluations."""
    props = [(f["theta"], np.linalg.cholesky(np.linalg.inv(f["H"]))) for f in modes]
    all_props, pts, lps, rss, owner = [], [], [], [], []
    for k in range(max_rounds):
        for j, (mean, Lc) in enumerate(props):
            all_props.append((mean, Lc))
            z = rng.standard_normal((DRAWS_PER_ROUND, mean.size))
            u = rng.chisquare(T_DOF, DRAWS_PER_ROUND) / T_DOF
            new = mean + (z @ Lc.T) / np.sqrt(u)[:, None]
            lp, r = log_target(new)
            pts.append(new)
            lps.append(lp)
            rss.append(r)
            owner.append(np.full(len(new), j))
        P = np.concatenate(pts)
        log_q = np.logaddexp.reduce([_log_t(P - m_, L_) for m_, L_ in all_props], axis=0)
        logw = np.concatenate(lps) - (log_q - math.log(len(all_props)))
        if bar is not None:
            bar.update(1)
        w = np.exp(logw - np.max(logw))
        if k + 1 >= AMIS_ROUNDS and w.sum() ** 2 / np.sum(w**2) >= ESS_MIN:
            break
        own = np.concatenate(owner)
        props = [
            _tempered_moments(P[own == j], logw[own == j], props[j]) for j in range(len(props))
        ]
    return P, logw, np.concatenate(rss), len(P)


def _tempered_moments(P: np.ndarray, lw: np.ndarray, old) -> tuple[np.ndarray, np.ndarray]:
    """Mean and Cholesky factor of the covariance (times AMIS_INFLATE) of the draws P under weights
    exp(beta lw), beta the largest in (0, 1] whose effective sample size is at least AMIS_TEMPER_ESS of
    the draws (bisection); the old proposal where too few draws have a finite weight."""
    fin = np.isfinite(lw)
    if fin.sum() < 2 * P.shape[1]:
        return old

    def weights(beta):
        w = np.where(fin, np.exp(beta * (np.where(fin, lw, 0.0) - lw[fin].max())), 0.0)
        return w / w.sum()

    def ess(w):
        return 1.0 / np.sum(w**2)

    target = AMIS_TEMPER_ESS * fin.sum()
    beta = 1.0
    if ess(weights(1.0)) < target:
        lo, hi = 0.0, 1.0
        for _ in range(30):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if ess(weights(mid)) >= target else (lo, mid)
        beta = lo
    w = weights(beta)
    mean = w @ P
    d = P - mean
    cov = AMIS_INFLATE * (d * w[:, None]).T @ d / (1.0 - np.sum(w**2))
    try:
        return mean, np.linalg.cholesky(cov + 1e-10 * np.eye(P.shape[1]))
    except np.linalg.LinAlgError:
        return old
