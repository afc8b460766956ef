"""Fluctuating axle forces at the cost of constant ones: the crossing posterior linearised in the few
nonlinear parameters, the force fluctuation and those parameters integrated out exactly, and the
linearisation checked against the exact posterior by importance weights.

The fluctuating-force model (`likelihood`) is linear in the force weights w (y = mu(theta) + R(theta)
D^(1/2)(s, l) w + noise) but not in theta = (log EI, log zeta, each crossing's log v and t0). Those are fixed
by the data to a small fraction of their priors, where mu and R are assumed linear in them to well under
the noise (R is held at theta*: on crossings where the fitted fluctuation is large that assumption fails,
and the importance check below says so; docs/methods.md). At a point theta* the model becomes

    y_c = mu_c(theta*) + J_c (theta - theta*) + R_c(theta*) D_c^(1/2) w_c + e,    e ~ N(0, sigma^2 I),

with Gaussian priors on theta (every prior is normal on the unconstrained scale) and w ~ N(0, I): a linear
Gaussian model in (theta, w) given the hyperparameters h = (log s, log l, log sigma). Its evidence p(y | h)
is exact and costs a few small Cholesky factors: each crossing's own block (speed, entry time, its weights)
is eliminated first and the shared block (EI, damping) last (the precision is arrow-shaped), from Gram
matrices X_c' X_c computed once. h alone (three to six dimensions) is sampled by adaptive importance
sampling from its maximum (emcee where that does not converge); theta is then drawn from its Gaussian
conditional given each h. theta* is the conditional mean given the hyperparameters' maximum,
re-linearised until it moves by under `MOVE_TOL` of its sd (Gauss-Newton on the marginal posterior).

The check: for `N_CHECK` joint draws, log w = log p(y | theta, h) - log p_lin(y | theta, h), both with the
forces integrated out (the exact one by `likelihood.woodbury_loglik` with R and mu at theta). The effective
sample size of those weights and the weighted shift of log EI (in posterior sds) are reported; a
linearisation they reject is warned about, never silently used.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .likelihood import (
    BODY_DAMPING_LOG_SD,
    BODY_FREQUENCY_LOG_SD,
    EVAL_CHUNK,
    CrossingsLogPosterior,
    cho_solve,
    rows_of,
    tri_solve,
    woodbury_loglik,
)

#: re-linearise until theta* moves by less than this fraction of its conditional sd (at most MAX_ROUNDS)
MOVE_TOL, MAX_ROUNDS = 0.05, 6
#: joint draws whose exact likelihood checks the linearisation
N_CHECK = 64
#: the check fails when the weights' effective sample size is under this fraction of N_CHECK, or log EI's
#: importance-weighted mean moves by more than SHIFT_MAX posterior sds
ESS_MIN_FRACTION, SHIFT_MAX = 0.5, 0.2
#: draws per vectorised conditional solve
CHUNK = 256
#: a sprung crossing's suspension (log bounce frequency, log damping) is tabulated on TABLE_NODES^2
#: Chebyshev nodes over +- TABLE_HALF_WIDTH prior sds about the linearisation point
#: (off the nodes it is not exact: the importance check covers it)
TABLE_NODES, TABLE_HALF_WIDTH = 10, 2.5


@dataclass
class Block:
    """One crossing's Gram pieces at theta*: columns [shared (S), own (d), force basis (M)]."""

    own: list[int]
    G: np.ndarray
    g: np.ndarray
    rr: float
    n: int
    own_mean: np.ndarray
    own_sd: np.ndarray
    table: dict | None = None
    term: int = 0

    def data_terms(self, u: np.ndarray | None):
        """X'r (W, K) and r'r (W,) at the suspension's scaled coordinates u (W, 2) (None: at theta*)."""
        if self.table is None or u is None:
            W = 1 if u is None else u.shape[0]
            return np.repeat(self.g[None], W, 0), np.full(W, self.rr)
        T = _cheb2(u, self.table["nodes"])  # (W, K^2)
        t = self.table
        g = self.g[None] - T @ t["XtC"].T
        rr = self.rr - 2 * T @ t["rC"] + np.einsum("wi,ij,wj->w", T, t["CC"], T)
        return g, rr


def _steps(name: str) -> float:
    """Central-difference step of each nonlinear parameter for the Jacobian."""
    for prefix, h in (("t0[", 1e-4), ("log_v[", 1e-5), ("log_fb[", 1e-3), ("log_zb[", 1e-3)):
        if name.startswith(prefix):
            return h
    return {"log_EI": 1e-5, "log_zeta": 1e-3}[name]


def _cheb(u: np.ndarray, K: int) -> np.ndarray:
    return np.cos(np.arccos(np.clip(u, -1.0, 1.0))[:, None] * np.arange(K)[None, :])


def _cheb2(u: np.ndarray, K: int) -> np.ndarray:
    """Tensor Chebyshev basis (W, K^2) at u (W, 2) in [-1, 1]^2."""
    a, b = _cheb(u[:, 0], K), _cheb(u[:, 1], K)
    return (a[:, :, None] * b[:, None, :]).reshape(u.shape[0], K * K)


class Linearisation:
    """The linear Gaussian model at theta* (module docstring), its evidence and conditionals."""

    def __init__(self, post: CrossingsLogPosterior, theta: np.ndarray, tabulate: bool = False):
        """tabulate: sample a sprung crossing's suspension with the hyperparameters, tabulated
        (`TABLE_NODES`, `TABLE_HALF_WIDTH`)."""
        self.post = post
        L = post.layout
        self.theta = np.asarray(theta, float).copy()
        self.tabulate = tabulate
        self.hyper = [L.index[n] for n in L.hyper]
        if (
            tabulate
        ):  # a sprung crossing's suspension is sampled with the hyperparameters, tabulated
            for c in post.terms:
                if c.sprung:
                    self.hyper += [L.index[f"log_fb[{c.name}]"], L.index[f"log_zb[{c.name}]"]]
        self.shared = [L.index[n] for n in ("log_EI", "log_zeta") if n in L.index]
        mean = [post.ei_prior.loc]
        sd = [post.ei_prior.log_sd]
        if "log_zeta" in L.index:
            mean.append(math.log(post.damping_prior[0]))
            sd.append(post.damping_prior[1])
        self.shared_mean, self.shared_sd = np.array(mean), np.array(sd)
        self.blocks = [self._block(i, c) for i, c in enumerate(post.terms)]
        self.n = sum(b.n for b in self.blocks)

    def _block(self, i: int, c) -> Block:
        L, th = self.post.layout, self.theta
        lin_own = [
            o for o in c.own if not (self.tabulate and o[0].startswith(("log_fb[", "log_zb[")))
        ]
        own = [L.index[n] for n, _, _ in lin_own]
        mean = [m for _, m, _ in lin_own]
        sd = [d for _, _, d in lin_own]
        cols = self.shared + own
        h = np.array([_steps(L.names[k]) for k in cols])
        pts = np.repeat(th[None], 1 + 2 * len(cols), 0)
        for j, k in enumerate(cols):
            pts[1 + 2 * j, k] += h[j]
            pts[2 + 2 * j, k] -= h[j]
        p = self.post.unpack(pts)
        first, rest = rows_of(p, slice(0, 1)), rows_of(p, slice(1, None))
        mu = c.predict(rest, i)
        J = (mu[0::2] - mu[1::2]) / (2 * h[:, None])  # (k, n)
        mu0, R = c.responses(first, i)
        X = np.concatenate([J.T, R[0]], axis=1)
        r = c.y - mu0[0]
        table = self._table(i, c, first, X, r) if self.tabulate and c.sprung else None
        return Block(
            own, X.T @ X, X.T @ r, float(r @ r), c.y.size,
            np.array(mean, float), np.array(sd, float), table, i,
        )  # fmt: skip

    def _table(self, i: int, c, first: dict, X: np.ndarray, r: np.ndarray) -> dict:
        """The interaction's change from theta* over the suspension's box, as a tensor Chebyshev
        interpolant, reduced to what the evidence needs (X' C', r' C', C C')."""
        from .interaction import interaction_response

        L = self.post.layout
        idx = [L.index[f"log_fb[{c.name}]"], L.index[f"log_zb[{c.name}]"]]
        center = self.theta[idx]
        half = TABLE_HALF_WIDTH * np.array([BODY_FREQUENCY_LOG_SD, BODY_DAMPING_LOG_SD])
        K = TABLE_NODES
        g = np.cos(np.pi * (np.arange(K) + 0.5) / K)
        mesh = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
        pts = center + half * mesh
        rep = {k: np.repeat(v[0], K * K) for k, v in first.items() if not isinstance(v, list)}
        args = (
            rep["EI"],
            rep["zeta"],
            np.repeat(first["v"][i], K * K),
            np.repeat(first["t0"][i], K * K),
        )
        at_nodes = interaction_response(c.model, *args, np.exp(pts[:, 0]), np.exp(pts[:, 1]))
        at_center = interaction_response(c.model, *(a[:1] for a in args), *np.exp(center))
        V = (at_nodes - at_center).reshape(K, K, -1)
        Tinv = np.linalg.inv(_cheb(g, K))
        V = np.tensordot(Tinv, V, axes=(1, 0))
        V = np.moveaxis(np.tensordot(Tinv, np.moveaxis(V, 1, 0), axes=(1, 0)), 0, 1)
        C = V.reshape(K * K, -1)  # coefficients: Delta I = C' T(u)
        return {
            "nodes": K, "center": center, "half": half, "index": idx,
            "XtC": X.T @ C.T, "rC": C @ r, "CC": C @ C.T,
        }  # fmt: skip

    def inside(self, hyper: np.ndarray) -> np.ndarray:
        """Whether rows of hyper lie inside every suspension table's box."""
        ok = np.ones(hyper.shape[0], bool)
        for b in self.blocks:
            if b.table is not None:
                u = self._u(b, hyper)
                ok &= np.all(np.abs(u) <= 1.0, axis=1)
        return ok

    def _u(self, b: Block, hyper: np.ndarray) -> np.ndarray:
        t = b.table
        cols = [self.hyper.index(k) for k in t["index"]]
        return (hyper[:, cols] - t["center"]) / t["half"]

    # ------------------------------------------------------------------------------- the pieces
    def _scale(self, b: Block, hyper: np.ndarray) -> np.ndarray:
        """Column scales (W, K): 1 on theta's columns, the weights' prior sds on theirs, at theta* with
        the hyperparameters (W, H) in their columns."""
        W = hyper.shape[0]
        full = np.repeat(self.theta[None], W, 0)
        full[:, self.hyper] = hyper
        d = self.post.terms[b.term].column_sds(self.post.unpack(full), b.term)
        return np.concatenate([np.ones((W, len(self.shared) + len(b.own))), d], 1)

    def _local(self, b: Block, sc: np.ndarray, s2: np.ndarray, g0: np.ndarray):
        """The crossing's own block: A_oo, c_o, A_so (W-batched) and its prior terms."""
        S = len(self.shared)
        G = b.G[None] * sc[:, :, None] * sc[:, None, :] / s2[:, None, None]
        g = g0 * sc / s2[:, None]
        M = G.shape[1] - S - len(b.own)
        p_o = np.concatenate([1.0 / b.own_sd**2, np.ones(M)])
        m_o = np.concatenate([b.own_mean - self.theta[b.own], np.zeros(M)])
        A_oo = G[:, S:, S:] + np.diag(p_o)[None]
        c_o = g[:, S:] + (p_o * m_o)[None]
        return A_oo, c_o, G[:, :S, S:], G[:, :S, :S], g[:, :S], p_o, m_o

    def _solve(self, hyper: np.ndarray):
        """Everything the evidence and the conditionals need at hyperparameters (W, 3)."""
        hyper = np.atleast_2d(hyper)
        s2 = np.exp(2 * hyper[:, 2])
        W = s2.size
        p_s = 1.0 / self.shared_sd**2
        m_s = self.shared_mean - self.theta[self.shared]
        A_ss = np.repeat(np.diag(p_s)[None], W, 0)
        c_s = np.repeat((p_s * m_s)[None], W, 0)
        logdet = np.zeros(W)
        quad = np.zeros(W)
        const = -0.5 * self.n * np.log(2 * math.pi * s2) + 0.5 * np.sum(np.log(p_s))
        const -= 0.5 * float(np.sum(p_s * m_s**2))
        local = []
        for b in self.blocks:
            sc = self._scale(b, hyper)
            g0, rr = b.data_terms(self._u(b, hyper) if b.table is not None else None)
            if g0.shape[0] != W:
                g0 = np.repeat(g0[:1], W, 0)
                rr = np.repeat(rr[:1], W, 0)
            A_oo, c_o, A_so, G_ss, g_s, p_o, m_o = self._local(b, sc, s2, g0)
            const += -0.5 * rr / s2 + 0.5 * np.sum(np.log(p_o)) - 0.5 * np.sum(p_o * m_o**2)
            C = np.linalg.cholesky(A_oo)
            logdet += 2 * np.sum(np.log(np.diagonal(C, axis1=1, axis2=2)), axis=1)
            Y = cho_solve(C, np.concatenate([c_o[:, :, None], np.swapaxes(A_so, 1, 2)], 2))
            quad += np.einsum("wk,wk->w", c_o, Y[:, :, 0])
            A_ss = A_ss + G_ss - A_so @ Y[:, :, 1:]
            c_s = c_s + g_s - np.einsum("wsk,wk->ws", A_so, Y[:, :, 0])
            local.append((C, c_o, A_so, Y))
        Cs = np.linalg.cholesky(A_ss)
        logdet += 2 * np.sum(np.log(np.diagonal(Cs, axis1=1, axis2=2)), axis=1)
        mean_s = cho_solve(Cs, c_s[:, :, None])[:, :, 0]
        quad += np.einsum("ws,ws->w", c_s, mean_s)
        return const - 0.5 * logdet + 0.5 * quad, (Cs, mean_s, local)

    def log_evidence(self, hyper: np.ndarray) -> np.ndarray:
        """log p_lin(y | h) for hyperparameters (W, 3) [log s, log l, log sigma]."""
        return self._solve(hyper)[0]

    def conditional(self, hyper: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
        """theta's conditional mean given each row of hyper (rng None), or a draw from its conditional:
        full parameter rows (W, D) with the hyperparameters in their columns."""
        hyper = np.atleast_2d(hyper)
        out = np.repeat(self.theta[None], hyper.shape[0], 0)
        out[:, self.hyper] = hyper
        for lo in range(0, hyper.shape[0], CHUNK):
            sl = slice(lo, lo + CHUNK)
            _, (Cs, mean_s, local) = self._solve(hyper[sl])
            d_s = mean_s
            if rng is not None:  # A_ss = Cs Cs': a draw is mean + Cs'^-1 z
                z = rng.standard_normal(mean_s.shape)
                d_s = mean_s + tri_solve(Cs, z[:, :, None], transposed=True)[:, :, 0]
            out[sl, self.shared] += d_s
            for b, (C, c_o, A_so, _) in zip(self.blocks, local, strict=True):
                if not b.own:
                    continue
                rhs = c_o - np.einsum("wsk,ws->wk", A_so, d_s)
                m = cho_solve(C, rhs[:, :, None])[:, :, 0]
                if rng is not None:
                    z = rng.standard_normal(m.shape)
                    m = m + tri_solve(C, z[:, :, None], transposed=True)[:, :, 0]
                out[sl, b.own] += m[:, : len(b.own)]
        return out

    def loglik(self, theta: np.ndarray) -> np.ndarray:
        """log p_lin(y | theta, h) with the weights integrated out, for full rows (W, D)."""
        th = np.atleast_2d(theta)
        s2 = np.exp(2 * th[:, self.hyper[2]])
        out = -0.5 * self.n * np.log(2 * math.pi * s2)
        for b in self.blocks:
            cols = self.shared + b.own
            k = len(cols)
            delta = th[:, cols] - self.theta[cols]
            G_JJ, G_RJ, G_RR = b.G[:k, :k], b.G[k:, :k], b.G[k:, k:]
            g0, rr0 = b.data_terms(self._u(b, th[:, self.hyper]) if b.table is not None else None)
            if g0.shape[0] != th.shape[0]:
                g0 = np.repeat(g0[:1], th.shape[0], 0)
                rr0 = np.repeat(rr0[:1], th.shape[0], 0)
            rr = rr0 - 2 * np.einsum("wk,wk->w", delta, g0[:, :k])
            rr = rr + np.einsum("wi,ij,wj->w", delta, G_JJ, delta)
            d = self._scale(b, th[:, self.hyper])[:, k:]
            bvec = d * (g0[:, k:] - delta @ G_RJ.T)
            G = G_RR[None] * d[:, :, None] * d[:, None, :]
            A = G / s2[:, None, None] + np.eye(G.shape[1])[None]
            C = np.linalg.cholesky(A)
            logdet = 2 * np.sum(np.log(np.diagonal(C, axis1=1, axis2=2)), axis=1)
            z = tri_solve(C, (bvec / np.sqrt(s2)[:, None])[:, :, None])[:, :, 0]
            out += -0.5 * (logdet + (rr - np.einsum("wm,wm->w", z, z)) / s2)
        return out


def exact_loglik(
    post: CrossingsLogPosterior, theta: np.ndarray, chunk: int = EVAL_CHUNK
) -> np.ndarray:
    """log p(y | theta, h) with the weights integrated out, mu and R at theta (the model itself)."""
    th = np.atleast_2d(theta)
    out = []
    for lo in range(0, th.shape[0], chunk):
        part = th[lo : lo + chunk]
        sig2 = np.exp(2 * part[:, post.layout.index["log_sigma"]])
        ll = -0.5 * post.n * np.log(2 * math.pi * sig2)
        for r, B in post.residuals(part, basis=True):
            ll = ll + woodbury_loglik(r, B, sig2)
        out.append(ll)
    return np.concatenate(out)


def exact_log_posterior(post: CrossingsLogPosterior, theta: np.ndarray) -> np.ndarray:
    """log prior + `exact_loglik` (the model's log posterior, -inf outside the prior's support)."""
    th = np.atleast_2d(theta)
    lp = post.log_prior(th)
    out = np.full(th.shape[0], -np.inf)
    ok = np.isfinite(lp)
    if ok.any():
        out[ok] = lp[ok] + exact_loglik(post, th[ok])
    return out


def check(lin: Linearisation, flat: np.ndarray, rng: np.random.Generator) -> dict:
    """Importance weights of N_CHECK joint draws (module docstring): their effective sample size and
    log EI's weighted shift in posterior sds, and whether the linearisation passes."""
    idx = rng.choice(flat.shape[0], size=min(N_CHECK, flat.shape[0]), replace=False)
    th = flat[idx]
    logw = exact_loglik(lin.post, th) - lin.loglik(th)
    w = np.exp(logw - logw.max())
    w /= w.sum()
    ess = float(1.0 / np.sum(w**2))
    lei = th[:, 0]
    sd = float(np.std(flat[:, 0]))
    shift = float((np.sum(w * lei) - lei.mean()) / sd) if sd > 0 else 0.0
    return {
        "draws": int(idx.size),
        "ess_fraction": ess / idx.size,
        "log_weight_sd": float(np.std(logw)),
        "log_EI_shift_sd": shift,
        "passed": bool(ess >= ESS_MIN_FRACTION * idx.size and abs(shift) <= SHIFT_MAX),
        "criterion": f"ESS >= {ESS_MIN_FRACTION:g} x draws and |shift| <= {SHIFT_MAX:g} sd",
    }


def linearised_sample(post: CrossingsLogPosterior, theta0: np.ndarray, settings, seed, progress):
    """The module's scheme from a starting point theta0 (full layout, the hyperparameters' start in their
    columns). Returns the draws in the joint layout (chain * draw, D), the chains, the linearisation and
    diagnostics to add."""
    from .. import seeding
    from ..uq.sampler import sample
    from .hyper import (
        conditional_sd,
        hyper_importance,
        hyper_maximum,
        hyper_scale,
        log_hyper_posterior,
    )

    theta = np.asarray(theta0, float).copy()
    hyp = [post.layout.index[n] for n in post.layout.hyper]
    h = theta[hyp]
    moves = []
    for _ in range(MAX_ROUNDS):
        lin = Linearisation(post, theta)
        h = hyper_maximum(lin, h)
        theta[hyp] = h
        new = lin.conditional(h[None])[0]
        sd = conditional_sd(lin, h)
        # Gauss-Newton step with backtracking on the exact log posterior at these hyperparameters
        here = float(post(theta[None])[0])
        step = new - theta
        for lam in (1.0, 0.5, 0.25, 0.125):
            cand = theta + lam * step
            if float(post(cand[None])[0]) > here:
                break
        else:
            lam = 0.0
        move = float(np.max(np.abs(lam * step)[sd > 0] / sd[sd > 0]))
        moves.append(move)
        theta = theta + lam * step
        if move < MOVE_TOL:
            break
    lin = Linearisation(post, theta, tabulate=True)
    h = hyper_maximum(lin, theta[lin.hyper])
    scale = hyper_scale(lin, h)
    import dataclasses

    ch, hyper_is = hyper_importance(lin, h, scale, seed, progress)
    if ch is None:  # importance sampling did not converge: emcee, which needs no proposal
        settings = dataclasses.replace(
            settings, n_walkers=max(settings.n_walkers, 2 * len(lin.hyper) + 2)
        )
        ch = sample(
            lambda z: log_hyper_posterior(lin, z), h, scale, settings, seed, progress,
            desc="crossing MCMC",
        )  # fmt: skip
    z = ch.draws.reshape(-1, len(lin.hyper))
    rng = np.random.default_rng(seeding.child(seed, "emcee", 9100))
    flat = lin.conditional(z, rng)
    chk = check(lin, flat, np.random.default_rng(seeding.child(seed, "emcee", 9200)))
    extra = {
        "linearisation": {
            "rounds": len(moves),
            "last_move_sd": moves[-1] if moves else None,
            "hyper_sampler": "importance" if hyper_is["passed"] else "emcee",
            "hyper_importance": hyper_is,
            "importance_check": chk,
            # the linearised posterior's log EI, kept beside whatever replaces it
            "log_EI_mean": float(flat[:, 0].mean()),
            "log_EI_sd": float(flat[:, 0].std()),
        }
    }
    return flat, ch, lin, extra
