"""Laplace scales from a finite-difference Hessian: the crossing reference's start for emcee, shared by the
brute-force scheme, the Laplace-marginal one and the linearised one."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def curvature_sds(
    neg_logp: Callable[[np.ndarray], np.ndarray], x: np.ndarray, h: np.ndarray
) -> np.ndarray | None:
    """sqrt of the diagonal of the inverse central-difference Hessian of neg_logp (rows (K, D) -> (K,), all
    points in one vectorised call) at x with steps h; None where the Hessian is not positive definite."""
    x, h = np.asarray(x, float), np.asarray(h, float)
    D = x.size
    pts = [x]
    for i in range(D):
        for j in range(i, D):
            for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                p = x.copy()
                p[i] += si * h[i]
                p[j] += sj * h[j]
                pts.append(p)
    f = neg_logp(np.array(pts))
    H = np.zeros((D, D))
    k = 1
    # a point outside the support (inf - inf) or a negative diagonal: not positive definite, None below
    with np.errstate(invalid="ignore"):
        for i in range(D):
            for j in range(i, D):
                fpp, fpm, fmp, fmm = f[k : k + 4]
                k += 4
                H[i, j] = H[j, i] = (fpp - fpm - fmp + fmm) / (4 * h[i] * h[j])
        if not np.all(np.isfinite(H)):
            return None
        try:
            sd = np.sqrt(np.diag(np.linalg.inv(H)))
            if np.all(np.isfinite(sd)) and np.all(np.linalg.eigvalsh(H) > 0):
                return sd
        except np.linalg.LinAlgError:
            pass
    return None
