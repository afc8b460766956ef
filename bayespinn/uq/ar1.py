"""AR(1) measurement noise: the likelihood's algebra, with sigma integrated out.

The noise of each sensor's series (in time order) is stationary AR(1): e_1 ~ N(0, sigma^2) and
e_k = rho e_(k-1) + sqrt(1 - rho^2) sigma z_k, so sigma is the noise's marginal sd (the sd that sets the
SNR, as `data.synthetic.ar1_noise` simulates it) and rho the correlation of consecutive samples. Scattered
deflection points without sensor names are one series, in time order (one instrument read in turn).

Whitening u_1 = r_1, u_k = (r_k - rho r_(k-1)) / sqrt(1 - rho^2) makes the residuals i.i.d. N(0, sigma^2)
with Jacobian (1 - rho^2)^(-(n_s - 1)/2) per series, so with m series and n points

    log p(r | sigma, rho) = -(n/2) log(2 pi sigma^2) - ((n - m)/2) log(1 - rho^2) - Q(rho) / (2 sigma^2),

Q(rho) = sum_first r^2 + (B - 2 rho C + rho^2 D) / (1 - rho^2), with B = sum r_k^2, C = sum r_k r_(k-1) and
D = sum r_(k-1)^2 over the non-first samples. Under the log-uniform prior on sigma the marginal is
proportional to Q^(-n/2) (1 - rho^2)^(-(n - m)/2), and sigma^2 | rest ~ InvGamma(n/2, Q/2). rho = 0 gives
the i.i.d. likelihood exactly.

rho is sampled as z = atanh(rho) with a uniform prior on rho in (-1, 1) (density 1 - rho^2 = sech^2 z in z),
confined to |rho| <= RHO_MAX.
"""

from __future__ import annotations

import math

import numpy as np

from ..data.measurements import Measurements

#: the largest |rho| the posterior may reach (its support in z = atanh(rho))
RHO_MAX = 0.999
Z_MAX = math.atanh(RHO_MAX)


def noise_series(data: Measurements) -> list[np.ndarray]:
    """Row indices of each noise series in time order: one per sensor name, the unnamed points together
    (the grouping `data.synthetic.ar1_noise` simulates)."""
    sensor = np.asarray(data.sensor).astype(str)
    t = np.asarray(data.t, float)
    out = []
    for name in dict.fromkeys(sensor.tolist()):
        rows = np.flatnonzero(sensor == name)
        out.append(rows[np.argsort(t[rows], kind="stable")])
    return out


def log_cosh(z: np.ndarray) -> np.ndarray:
    """log cosh z without overflow."""
    a = np.abs(z)
    return a + np.log1p(np.exp(-2.0 * a)) - math.log(2.0)


class AR1Noise:
    """The AR(1) likelihood's pieces for fixed series (`noise_series`): the quadratic form Q(rho) of residual
    vectors, its log-determinant term, the prior of z = atanh(rho), and whitening."""

    def __init__(self, series: list[np.ndarray], n: int):
        order = np.concatenate(series) if series else np.zeros(0, int)
        if order.size != n or np.unique(order).size != n:
            raise ValueError("the noise series must cover every data point exactly once")
        self.series = series
        self.n, self.m = n, len(series)
        self.first = np.array([s[0] for s in series if s.size], dtype=int)
        self.cur = np.concatenate([s[1:] for s in series]) if series else order
        self.prev = np.concatenate([s[:-1] for s in series]) if series else order

    @classmethod
    def of(cls, data: Measurements) -> AR1Noise:
        return cls(noise_series(data), len(data))

    def quad(self, r: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Q(rho) for residuals r (W, n) and z = atanh(rho) (W,): the whitened residuals' sum of squares."""
        rho = np.tanh(z)
        a = np.einsum("wp,wp->w", r[:, self.first], r[:, self.first])
        rc, rp = r[:, self.cur], r[:, self.prev]
        d = rc - rho[:, None] * rp
        return a + np.einsum("wp,wp->w", d, d) * np.cosh(z) ** 2  # 1 / (1 - rho^2) = cosh^2 z

    def log_one_minus_rho2(self, z: np.ndarray) -> np.ndarray:
        """log(1 - rho^2) = -2 log cosh z."""
        return -2.0 * log_cosh(z)

    def log_jacobian(self, z: np.ndarray) -> np.ndarray:
        """-((n - m)/2) log(1 - rho^2): the whitening's Jacobian."""
        return -0.5 * (self.n - self.m) * self.log_one_minus_rho2(z)

    @staticmethod
    def log_prior(z: np.ndarray) -> np.ndarray:
        """Uniform rho on (-1, 1), as a density in z: log sech^2 z (up to a constant)."""
        return -2.0 * log_cosh(z)

    def whiten(self, r: np.ndarray, rho: float) -> np.ndarray:
        """Innovations of residuals r (n,) under coefficient rho: i.i.d. N(0, sigma^2) when the model holds."""
        r = np.asarray(r, float)
        u = r.copy()
        u[self.cur] = (r[self.cur] - rho * r[self.prev]) / math.sqrt(1.0 - rho * rho)
        return u


def lag1(series: list[np.ndarray], r: np.ndarray) -> float:
    """Pooled lag-1 autocorrelation of r (n,) over the series (means removed per series)."""
    num = den = 0.0
    for rows in series:
        d = r[rows] - r[rows].mean()
        num += float(np.sum(d[1:] * d[:-1]))
        den += float(np.sum(d * d))
    return num / den if den > 0 else 0.0
