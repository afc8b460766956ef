"""The exact fluctuating-force crossing posterior where its linearisation fails: adaptive multiple
importance sampling (AMIS; Cornuet, Marin, Mira and Robert 2012) started from the linearised draws.

On realistic crossings the linear Gaussian model of `linearised` is a good guide to where the posterior
lies but a poor density: its importance weights against the exact likelihood have an effective sample size
of a few per cent. Its draws are still a fine first proposal. Each round draws `N_PER_ROUND` points from a
multivariate t (`DF` degrees of freedom, heavier tails than the target) whose location and scale are the
importance-weighted mean and covariance of every draw so far, evaluates the exact log posterior there
(prior plus `linearised.exact_loglik`, the forces integrated out with mu and R at each point), and
re-weights every draw of every round against the equal mixture of all proposals used (the deterministic
mixture weights that make AMIS stable). It stops once the weights' effective sample size reaches
`ESS_TARGET` with the Pareto tail index k-hat of the weights at most `KHAT_MAX` (Vehtari, Simpson, Gelman,
Yao and Gabry, "Pareto smoothed importance sampling", 2024: above 0.7 an importance estimate is not to be
trusted), or after `MAX_ROUNDS`; `N_OUT` equal-weight draws are then resampled (systematic resampling).
Whether it converged is reported, never assumed.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats
from scipy.special import logsumexp

#: draws per round, the most rounds, the proposal's degrees of freedom and the first proposal's scale
#: on the linearised draws' covariance (wider than the guide: the exact posterior sits beside it)
N_PER_ROUND, MAX_ROUNDS, DF, FIRST_INFLATION = 500, 24, 5.0, 2.0
#: converged: the weights' effective sample size at least ESS_TARGET and k-hat at most KHAT_MAX
ESS_TARGET, KHAT_MAX = 400.0, 0.7
#: equal-weight draws resampled at the end
N_OUT = 4000


def pareto_khat(log_w: np.ndarray) -> float:
    """The generalized Pareto shape k of the largest importance weights (the tail of M = min(n / 5,
    3 sqrt(n)) of them), by the Zhang and Stephens (2009) estimator with the weak prior of Vehtari et
    al.; inf when fewer than 5 finite weights exist."""
    lw = np.asarray(log_w, float)
    lw = lw[np.isfinite(lw)]
    n = lw.size
    if n < 5:
        return math.inf
    M = int(min(n / 5.0, 3.0 * math.sqrt(n)))
    if M < 5:
        return math.inf
    lw = np.sort(lw - lw.max())
    tail = np.exp(lw[-M:])
    u = np.exp(lw[-M - 1])  # the threshold: the largest weight below the tail
    x = tail - u
    if not np.any(x > 0):
        return 0.0
    return _gpd_k(np.sort(x))


def _gpd_k(x: np.ndarray) -> float:
    """Zhang and Stephens' posterior-mean estimate of the generalized Pareto shape of sorted excesses x,
    shrunk towards 0.5 as in PSIS (a prior worth 10 observations)."""
    n = x.size
    m = 30 + int(math.sqrt(n))
    prior = 3.0
    q1 = x[int(n / 4.0 + 0.5) - 1]
    j = np.arange(1, m + 1)
    theta = 1.0 / x[-1] + (1.0 - np.sqrt(m / (j - 0.5))) / (prior * q1)
    k_th = np.mean(np.log1p(-theta[:, None] * x[None, :]), axis=1)
    l_th = n * (np.log(-theta / k_th) - k_th - 1.0)
    w = np.exp(l_th - logsumexp(l_th))
    theta_hat = float(np.sum(theta * w))
    k = float(np.mean(np.log1p(-theta_hat * x)))
    return (n * k + 10 * 0.5) / (n + 10)  # PSIS sign: k > 0 is a heavy tail


def amis(log_target, guide: np.ndarray, rng: np.random.Generator, progress: bool = False) -> tuple:
    """Adaptive multiple importance sampling of log_target (rows (W, D) -> (W,)) from a cloud of guide
    draws (module docstring). Returns N_OUT resampled draws, their log target, and the diagnostics."""
    from tqdm.auto import tqdm

    mean = guide.mean(axis=0)
    cov = np.atleast_2d(np.cov(guide.T)) * FIRST_INFLATION**2
    cov += 1e-12 * np.eye(mean.size) * max(1.0, float(np.max(np.diag(cov))))
    props: list = []
    Z: list = []
    LT: list = []
    ess, khat, history, w = 0.0, math.inf, [], None
    bar = tqdm(total=MAX_ROUNDS, desc="crossing importance", unit="round", leave=False,
               disable=not progress)  # fmt: skip
    for _ in range(MAX_ROUNDS):
        bar.update()
        q = stats.multivariate_t(loc=mean, shape=cov, df=DF, allow_singular=True)
        z = q.rvs(size=N_PER_ROUND, random_state=rng).reshape(N_PER_ROUND, -1)
        props.append(q)
        Z.append(z)
        LT.append(np.asarray(log_target(z), float))
        z, lt = np.concatenate(Z), np.concatenate(LT)
        lq = logsumexp(np.stack([p.logpdf(z) for p in props]), axis=0) - math.log(len(props))
        lw = np.where(np.isfinite(lt), lt - lq, -np.inf)
        if not np.any(np.isfinite(lw)):
            history.append({"ess": 0.0, "khat": math.inf})
            continue
        w = np.exp(lw - lw.max())
        w /= w.sum()
        ess, khat = float(1.0 / np.sum(w**2)), pareto_khat(lw)
        history.append({"ess": ess, "khat": khat})
        if ess >= ESS_TARGET and khat <= KHAT_MAX:
            break
        mean = w @ z
        d = z - mean
        cov = (w[:, None] * d).T @ d + 1e-12 * np.eye(mean.size) * float(np.max(np.var(z, 0)))
    bar.close()
    if w is None:  # no draw of any round inside the support: nothing to weigh
        raise RuntimeError(
            "importance sampling found no draw inside the posterior's support "
            f"in {MAX_ROUNDS} rounds of {N_PER_ROUND}"
        )
    idx = _systematic(w, N_OUT, rng)
    idx = idx[rng.permutation(idx.size)]
    info = {
        "rounds": len(history),
        "evaluated": int(z.shape[0]),
        "ess": ess,
        "khat": khat,
        "passed": bool(ess >= ESS_TARGET and khat <= KHAT_MAX),
        "criterion": f"ESS >= {ESS_TARGET:g} and Pareto k-hat <= {KHAT_MAX:g}",
        "history": history,
    }
    return z[idx], lt[idx], info


def _systematic(w: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Systematic resampling: n indices with counts within one of n w."""
    c = np.cumsum(w)
    c[-1] = 1.0
    return np.searchsorted(c, (rng.uniform() + np.arange(n)) / n)
