"""Many crossings at the cost of a few: each crossing's speed and entry time integrated out by a Laplace
approximation inside the likelihood of what the crossings share, tabulated so that the sampler never
calls the forward model.

For the shared parameters theta (log EI, and log zeta when the damping is inferred) and the noise sd sigma,
crossing c contributes

    l_c(theta, sigma) = log int N(y_c; mu_c(theta, eta), sigma^2 I) p(eta) d eta
                      ~ -n_c log(sigma sqrt(2 pi)) - RSS_c / (2 sigma^2) + log p(eta_c) + (d/2) log 2 pi
                        - (1/2) log det(J'J / sigma^2 + Pi),

at the conditional mode eta_c(theta) (Gauss-Newton on the residuals with the normal priors on log v and
t0, precision Pi, at the maximum's sigma), J = d mu / d eta there. The speed and entry time are fixed by
thousands of samples to a small fraction of their prior, where the response is linear in them to well
under the noise, so the Laplace approximation is accurate (tests/test_crossings_posterior.py compares it
with brute-force emcee over every parameter). RSS_c, log p(eta_c), J'J and eta_c are smooth in theta:
they are tabulated on Chebyshev nodes over +-`WINDOW` Laplace sds of theta, the interpolant checked
where the posterior lives against the exact conditional (`TABLE_NATS`), and emcee runs on (theta, log sigma)
alone. Each crossing's (log v, t0) is then drawn from its Laplace Gaussian given each draw of theta, sigma.
"""

from __future__ import annotations

import math

import numpy as np

from .curvature import curvature_sds
from .likelihood import CrossingsLogPosterior

#: the table spans the maximum +- WINDOW Laplace sds of each shared parameter
WINDOW = 8.0
#: the tabulated log-likelihood must stay within this many nats of the exact conditional where the
#: posterior lives: ten strain crossings sit at 0.09 nats with 32 or 64 nodes alike (the conditional fits'
#: own floor, not the interpolation's), and the two tables give EI within 0.04 sd, sds within 1 %
TABLE_NATS = 0.1
#: the table is checked at random points within this many Laplace sds of the maximum
PROBE_SD = 4.0
#: Gauss-Newton iterations and the step (in Laplace sds) that ends them
GN_ITER, GN_TOL = 12, 1e-7


def _cheb(u: np.ndarray, K: int) -> np.ndarray:
    return np.cos(np.arccos(np.clip(u, -1.0, 1.0))[:, None] * np.arange(K)[None, :])


class Conditional:
    """Each crossing's Laplace pieces at given shared parameters: eta_c, RSS_c, log p(eta_c), J'J."""

    def __init__(self, post: CrossingsLogPosterior, theta_map: np.ndarray, sigma: float):
        self.post, self.sigma = post, float(sigma)
        L = post.layout
        self.shared = [i for i, n in enumerate(L.names) if "[" not in n]
        self.own = []
        for c in post.terms:
            own = c.own
            idx = [L.index[n] for n, _, _ in own]
            mean = np.array([m for _, m, _ in own], float)
            sd = np.array([d for _, _, d in own], float)
            self.own.append((idx, mean, sd))
        self.theta_map = np.asarray(theta_map, float)

    def at(self, shared: np.ndarray) -> list[dict]:
        """For shared parameters (K, S): per crossing {eta (K, d), rss (K,), logp (K,), JtJ (K, d, d)}."""
        shared = np.atleast_2d(shared)
        K = shared.shape[0]
        base = np.repeat(self.theta_map[None], K, 0)
        base[:, self.shared] = shared
        out = []
        for c, (idx, mean, sd) in zip(self.post.terms, self.own, strict=True):
            eta = base[:, idx].copy()
            d = len(idx)
            Pi = np.diag(1.0 / sd**2) if d else np.zeros((0, 0))
            h = 1e-4 * sd
            step = np.full((K, d), np.inf)
            for it in range(GN_ITER + 1):
                rows = np.repeat(base[:, None], d + 1, 1)  # (K, d + 1, D): eta and its d steps
                rows[:, :, idx] = eta[:, None, :]
                for i in range(d):
                    rows[:, i + 1, idx[i]] += h[i]
                r = self._residual(c, rows.reshape(-1, base.shape[1])).reshape(K, d + 1, -1)
                r0 = r[:, 0]
                J = -(r[:, 1:] - r0[:, None]) / h[None, :, None]  # d mu / d eta, (K, d, n)
                JtJ = np.einsum("kin,kjn->kij", J, J)
                if d == 0 or it == GN_ITER or np.all(np.abs(step) < GN_TOL * sd):
                    break  # r and J are those of the final eta
                A = JtJ / self.sigma**2 + Pi[None]
                g = np.einsum("kin,kn->ki", J, r0) / self.sigma**2 - (eta - mean) / sd**2
                step = np.linalg.solve(A, g[:, :, None])[:, :, 0]
                eta = eta + step
            logp = np.sum(
                -0.5 * ((eta - mean) / sd) ** 2 - np.log(sd * math.sqrt(2 * math.pi)), axis=1
            )
            out.append({"eta": eta, "rss": np.einsum("kn,kn->k", r0, r0), "logp": logp, "JtJ": JtJ})
        return out

    def _residual(self, c, theta: np.ndarray) -> np.ndarray:
        i = self.post.terms.index(c)
        return c.y[None, :] - c.predict(self.post.unpack(theta), i)


def crossing_loglik(parts: list[dict], own, sigma: np.ndarray, n: list[int]) -> np.ndarray:
    """sum_c l_c (module docstring) for sigma (K,) and the pieces of `Conditional.at` (K rows)."""
    s2 = sigma**2
    out = np.zeros(sigma.shape)
    for p, (idx, _, sd), nc in zip(parts, own, n, strict=True):
        d = len(idx)
        out += -nc * np.log(sigma * math.sqrt(2 * math.pi)) - p["rss"] / (2 * s2) + p["logp"]
        if d:
            A = p["JtJ"] / s2[:, None, None] + np.diag(1.0 / sd**2)[None]
            out += 0.5 * d * math.log(2 * math.pi) - 0.5 * np.linalg.slogdet(A)[1]
    return out


class Table:
    """Chebyshev tensor interpolant of the Laplace pieces over the shared parameters' window."""

    def __init__(
        self, cond: Conditional, center: np.ndarray, half: np.ndarray, nodes: tuple[int, ...]
    ):
        self.cond, self.center, self.half, self.nodes = cond, center, half, nodes
        grids = [np.cos(np.pi * (np.arange(K) + 0.5) / K) for K in nodes]
        mesh = np.stack(np.meshgrid(*grids, indexing="ij"), -1).reshape(-1, len(nodes))
        parts = cond.at(center + half * mesh)
        self.coef = []
        for p in parts:
            flat = {k: v.reshape(v.shape[0], -1) for k, v in p.items()}
            self.coef.append({k: self._fit(v, grids) for k, v in flat.items()})
        self.shapes = [{k: v.shape[1:] for k, v in p.items()} for p in parts]

    def _fit(self, values: np.ndarray, grids) -> np.ndarray:
        V = values.reshape(*self.nodes, -1)
        for ax, g in enumerate(grids):
            Tinv = np.linalg.inv(_cheb(g, g.size))
            V = np.moveaxis(np.tensordot(Tinv, np.moveaxis(V, ax, 0), axes=(1, 0)), 0, ax)
        return V

    def inside(self, shared: np.ndarray) -> np.ndarray:
        return np.all(np.abs((np.atleast_2d(shared) - self.center) / self.half) <= 1.0, axis=1)

    def at(self, shared: np.ndarray) -> list[dict]:
        """The interpolated pieces (as `Conditional.at`) at shared (K, S) inside the window."""
        u = (np.atleast_2d(shared) - self.center) / self.half
        T = [_cheb(u[:, a], K) for a, K in enumerate(self.nodes)]
        out = []
        for coef, shapes in zip(self.coef, self.shapes, strict=True):
            e = {}
            for k, C in coef.items():
                if len(self.nodes) == 1:
                    v = T[0] @ C
                else:
                    v = np.einsum("ki,kj,ijm->km", T[0], T[1], C)
                e[k] = v.reshape(u.shape[0], *shapes[k])
            out.append(e)
        return out


def build_table(
    cond: Conditional, center, sd, sigma: float, n_list: list[int]
) -> tuple[Table, float]:
    """The smallest table (8, 16, 32 nodes per shared parameter) whose log-likelihood at sigma is within
    TABLE_NATS of the exact conditional at random points within PROBE_SD Laplace sds of the maximum;
    returns it and that error (the last table's, reported, when even 32 nodes miss it)."""
    center, sd = np.asarray(center, float), np.asarray(sd, float)
    half = WINDOW * sd
    rng = np.random.default_rng(0)
    # probes where the posterior lives (within +-PROBE_SD Laplace sds), which is what the sampler visits
    probe = center + PROBE_SD * sd * rng.uniform(-1.0, 1.0, (12, center.size))
    probe[0] = center
    exact = crossing_loglik(cond.at(probe), cond.own, np.full(len(probe), sigma), n_list)
    err = math.inf
    for K in (8, 16, 32):
        nodes = (K,) if center.size == 1 else (K, max(8, K // 2))
        tab = Table(cond, center, half, nodes)
        approx = crossing_loglik(tab.at(probe), cond.own, np.full(len(probe), sigma), n_list)
        err = float(np.max(np.abs(approx - exact)))
        if err <= TABLE_NATS:
            break
    return tab, err


def marginal_scale(cond: Conditional, post, center, h, sigma: float, n_list) -> np.ndarray:
    """Laplace sds of the shared parameters from the curvature of their Laplace-marginal log posterior at
    sigma (central differences with steps h, a handful of conditional fits)."""

    def neg_logp(pts: np.ndarray) -> np.ndarray:
        full = np.repeat(cond.theta_map[None], len(pts), 0)
        full[:, cond.shared] = pts
        sig = np.full(len(pts), sigma)
        return -(_shared_prior(post, full) + crossing_loglik(cond.at(pts), cond.own, sig, n_list))

    sd = curvature_sds(neg_logp, center, h)
    if sd is not None:
        return sd
    return 10 * np.asarray(h, float)


def laplace_sample(
    post: CrossingsLogPosterior, theta_map, steps, sigma: float, settings, seed, progress
):
    """emcee on (shared parameters, log sigma) under the tabulated Laplace likelihood, then each
    crossing's (log v, t0) from its Laplace Gaussian per draw. steps: finite-difference steps of every
    parameter (the shared ones' curvature). Returns the draws in the joint layout (chain * draw, D), sigma
    (chain, draw), the chains and diagnostics to add."""
    from .. import seeding
    from ..uq.sampler import sample

    cond = Conditional(post, theta_map, sigma)
    S = cond.shared
    n_list = [c.y.size for c in post.terms]
    scale = np.zeros(theta_map.size)
    scale[S] = marginal_scale(cond, post, theta_map[S], np.asarray(steps, float)[S], sigma, n_list)
    table, err = build_table(cond, theta_map[S], scale[S], sigma, n_list)
    if err > TABLE_NATS:
        import warnings

        warnings.warn(
            f"the crossings' Laplace table is {err:.3g} nats off the exact conditional (tolerance "
            f"{TABLE_NATS})", RuntimeWarning, stacklevel=2,
        )  # fmt: skip
    noise = post.noise_prior

    def logp(z: np.ndarray) -> np.ndarray:
        z = np.atleast_2d(z)
        full = np.repeat(theta_map[None], z.shape[0], 0)
        full[:, S] = z[:, :-1]
        lp = _shared_prior(post, full) + noise.logpdf(z[:, -1])
        ok = np.isfinite(lp) & table.inside(z[:, :-1])
        out = np.full(z.shape[0], -np.inf)
        if ok.any():
            sig = np.exp(z[ok, -1])
            out[ok] = lp[ok] + crossing_loglik(table.at(z[ok, :-1]), cond.own, sig, n_list)
        return out

    center = np.append(theta_map[S], math.log(sigma))
    sc = np.append(np.asarray(scale)[S], 1.0 / math.sqrt(2 * post.n))
    ch = sample(logp, center, sc, settings, seed, progress, desc="crossings MCMC")
    z = ch.draws.reshape(-1, len(S) + 1)
    sig = np.exp(z[:, -1])
    flat = np.repeat(theta_map[None], z.shape[0], 0)
    flat[:, S] = z[:, :-1]
    rng = np.random.default_rng(seeding.child(seed, "emcee", 9000))
    for p, (idx, _, sd) in zip(table.at(z[:, :-1]), cond.own, strict=True):
        if not idx:
            continue
        A = p["JtJ"] / sig[:, None, None] ** 2 + np.diag(1.0 / sd**2)[None]
        Lc = np.linalg.cholesky(np.linalg.inv(A))
        flat[:, idx] = p["eta"] + np.einsum("kij,kj->ki", Lc, rng.standard_normal(p["eta"].shape))
    extra = {
        "laplace": {
            "table_nodes": list(table.nodes),
            "window_sd": WINDOW,
            "max_table_error_nats": err,
            "table_within_tolerance": bool(err <= TABLE_NATS),
            "shared": [post.layout.names[i] for i in S],
        }
    }
    return flat, sig.reshape(ch.draws.shape[:2]), ch, extra


def _shared_prior(post: CrossingsLogPosterior, full: np.ndarray) -> np.ndarray:
    """The log prior of the shared parameters (EI, damping) of full parameter rows."""
    lp = post.ei_prior.logpdf(full[:, 0])
    L = post.layout
    if "log_zeta" in L.index:
        med, sd = post.damping_prior
        lz = full[:, L.index["log_zeta"]]
        lp = lp - 0.5 * ((lz - math.log(med)) / sd) ** 2 - math.log(sd * math.sqrt(2 * math.pi))
        lp = np.where(lz < math.log(0.5), lp, -np.inf)
    return lp
