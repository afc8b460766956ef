"""The girder reference's MAP, Laplace covariance and mode count (`uq.girder_posterior`): a scan of a
common log EI, then L-BFGS-B with central-difference gradients (from spring starts and, with an uncertain
load, from the best peaks along the load factor's ridge); the Laplace covariance from a batched
central-difference Hessian; and the smallest mode count whose truncation error is below a fraction of
sigma. The girder PINN (`uq.girder_net`) uses the same search on its own surrogate.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.optimize import minimize

from ..config import Vehicle
from ..data.measurements import Measurements
from ..physics.fe_modal import GirderModalModel
from ..physics.girder import Girder
from .ar1 import lag1
from .girder_logpost import GirderLogPosterior
from .modal_mcmc import TRUNCATION_FRACTION

#: mode counts tried in turn by the truncation check
MODE_STEPS = (6, 12, 24, 48)


def _neg_with_grad(post: GirderLogPosterior, h: float = 1e-6):
    def fg(th: np.ndarray) -> tuple[float, np.ndarray]:
        D = th.size
        pts = np.vstack([th, th + h * np.eye(D), th - h * np.eye(D)])
        v = -post(pts)
        if not np.all(np.isfinite(v)):
            return float(v[0]) if np.isfinite(v[0]) else 1e300, np.zeros(D)
        return float(v[0]), (v[1 : D + 1] - v[D + 1 :]) / (2 * h)

    return fg


def find_map(post: GirderLogPosterior, starts: Sequence[np.ndarray] | None = None) -> np.ndarray:
    """theta at the posterior maximum: a scan of a common log EI (other parameters at their prior
    centres), then L-BFGS-B from there (and from each of `starts`; with springs inferred also from
    springs 2 prior sd below and above their median); the best end point."""
    lay = post.layout
    S = lay.n_segments
    base = post.loc.copy()
    grid = post.loc[0] + post.sd[0] * np.linspace(-6.0, 6.0, 241)
    pts = np.repeat(base[None], grid.size, axis=0)
    pts[:, :S] = grid[:, None]
    base[:S] = grid[int(np.argmax(post(pts)))]
    if lay.infer_ar1:  # start rho at the residuals' lag-1 autocorrelation there
        r = post.y - post.predict(base)[0]
        base[lay.ar1] = math.atanh(min(max(lag1(post.noise.series, r), -0.95), 0.95))
    cands = [base]
    if lay.infer_springs:
        for dz in (-2.0, 2.0):
            c = base.copy()
            c[lay.springs] += dz * post.sd[lay.springs]
            cands.append(c)
    if lay.infer_load:
        cands += _ridge_starts(post, base)
    cands += [np.asarray(s, float) for s in (starts or [])]
    pad = 1e-3 * post.sd
    bounds = list(zip(post.lo + pad, post.hi - pad, strict=True))
    fg = _neg_with_grad(post)
    best, best_f = None, np.inf
    for c in cands:
        c = np.clip(c, post.lo + pad, post.hi - pad)
        res = minimize(
            fg,
            c,
            jac=True,
            method="L-BFGS-B",
            bounds=bounds,
            options={"maxiter": 500, "ftol": 1e-14, "gtol": 1e-8},
        )
        if res.fun < best_f:
            best, best_f = np.asarray(res.x, float), float(res.fun)
    return best


#: the load factor's ridge is scanned over this many prior sds each side, at this many points, and the
#: best local maxima along it start L-BFGS-B
RIDGE_SD, RIDGE_POINTS, RIDGE_STARTS = 4.0, 161, 3


def _ridge_starts(post: GirderLogPosterior, base: np.ndarray) -> list[np.ndarray]:
    """Starts along the load factor's ridge. The quasi-static response fixes EI / load, so the posterior
    has a ridge where both move together; along it the first mode's frequency (sqrt EI) changes, and the
    vibration's phase over a crossing makes the likelihood oscillate: a local search from the load's prior
    centre ends on whichever peak is nearest (measured: 15 of 100 replicates at 40 dB, each some 15-40
    posterior sds off). The ridge is scanned (log EI of every segment and log load shifted together) and
    its best local maxima are returned."""
    lay = post.layout
    S, li = lay.n_segments, lay.load
    shift = np.linspace(-RIDGE_SD, RIDGE_SD, RIDGE_POINTS) * post.sd[li]
    pts = np.repeat(base[None], shift.size, axis=0)
    pts[:, li] = post.loc[li] + shift
    pts[:, :S] = base[None, :S] + shift[:, None]
    lp = np.asarray(post(pts), float)
    peaks = [
        i
        for i in range(1, lp.size - 1)
        if np.isfinite(lp[i]) and lp[i] >= lp[i - 1] and lp[i] >= lp[i + 1]
    ]
    peaks.sort(key=lambda i: -lp[i])
    return [pts[i].copy() for i in peaks[:RIDGE_STARTS]]


def laplace_covariance(post: GirderLogPosterior, theta: np.ndarray, h: float = 1e-3) -> np.ndarray:
    """Inverse Hessian of -log p at theta (central differences, one batch); eigenvalues of the
    Hessian floored at the smallest prior precision."""
    D = theta.size
    E = h * np.eye(D)
    pts = [theta]
    for i in range(D):
        pts += [theta + E[i], theta - E[i]]
    for i in range(D):
        for j in range(i + 1, D):
            pts += [
                theta + E[i] + E[j],
                theta + E[i] - E[j],
                theta - E[i] + E[j],
                theta - E[i] - E[j],
            ]
    f = -post(np.array(pts))
    f0 = f[0]
    H = np.zeros((D, D))
    k = 1
    for i in range(D):
        H[i, i] = (f[k] - 2 * f0 + f[k + 1]) / h**2
        k += 2
    for i in range(D):
        for j in range(i + 1, D):
            H[i, j] = H[j, i] = (f[k] - f[k + 1] - f[k + 2] + f[k + 3]) / (4 * h**2)
            k += 4
    if not np.all(np.isfinite(H)):
        return np.diag(post.sd**2)
    lam, V = np.linalg.eigh(0.5 * (H + H.T))
    lam = np.maximum(lam, 1.0 / float(np.max(post.sd)) ** 2)
    return (V / lam) @ V.T


def surrogate_model(
    template: Girder,
    vehicle: Vehicle,
    data: Measurements,
    n_modes: int,
    springs: bool,
    n_elements: int,
) -> GirderModalModel:
    """The reduced modal surrogate of `template` at the data's points (`physics.fe_modal`)."""
    a_u, a_xx = data.weights
    return GirderModalModel(
        template,
        vehicle,
        data.x,
        data.t,
        a_u,
        a_xx,
        n_modes=n_modes,
        infer_springs=springs,
        n_elements=n_elements,
    )


def choose_girder_modes(
    template: Girder,
    vehicle: Vehicle,
    data: Measurements,
    post: GirderLogPosterior,
    theta: np.ndarray,
    sigma: float,
    n_elements: int = 96,
) -> tuple[int, float]:
    """Smallest n in MODE_STEPS whose predictions at theta differ from 2 n modes by at most
    TRUNCATION_FRACTION x sigma (or 1e-9 of the data RMS); returns (n, that largest difference)."""
    scale = float(np.sqrt(np.mean(np.asarray(data.value, float) ** 2)))
    tol = max(TRUNCATION_FRACTION * sigma, 1e-9 * scale)
    EI, ks, lf = post.unpack(theta)
    springs = post.layout.infer_springs
    err = float("nan")
    for n in MODE_STEPS:
        p1 = surrogate_model(template, vehicle, data, n, springs, n_elements).predict(EI, ks, lf)
        p2 = surrogate_model(template, vehicle, data, 2 * n, springs, n_elements).predict(
            EI, ks, lf
        )
        err = float(np.max(np.abs(p1 - p2)))
        if err <= tol:
            return n, err
    return MODE_STEPS[-1], err
