"""The girder reference's log posterior (`uq.girder_posterior`): where each parameter sits in theta
(`ParameterLayout`: log EI per segment, log springs, log load factor, atanh of the AR(1) coefficient) and
log p(theta | y) with sigma integrated out (`GirderLogPosterior`), vectorised over walkers.

Kept apart from the MAP search (`uq.girder_map`) and the sampler (`uq.girder_emcee`) because the girder
PINN (`uq.girder_net`) evaluates the same density on its own surrogate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..physics.fe_modal import GirderModalModel
from .ar1 import Z_MAX, AR1Noise
from .priors import EIPrior

#: every parameter is confined to this many prior sd around its prior centre
SUPPORT_SD = 10.0
#: largest batch of parameter sets per surrogate call
BATCH = 512


@dataclass(frozen=True)
class ParameterLayout:
    """Where each parameter sits in theta."""

    n_segments: int
    infer_springs: bool
    infer_load: bool
    infer_ar1: bool = False

    @property
    def dim(self) -> int:
        return self.n_segments + 2 * self.infer_springs + self.infer_load + self.infer_ar1

    @property
    def springs(self) -> slice:
        return slice(self.n_segments, self.n_segments + 2 * self.infer_springs)

    @property
    def load(self) -> int | None:
        return self.n_segments + 2 * self.infer_springs if self.infer_load else None

    @property
    def ar1(self) -> int | None:
        """Where z = atanh(rho) of AR(1) noise sits (last), or None (white noise)."""
        return self.dim - 1 if self.infer_ar1 else None

    def names(self) -> list[str]:
        out = [f"EI_segments[{s}]" for s in range(self.n_segments)]
        if self.infer_springs:
            out += ["rotational_stiffness[0]", "rotational_stiffness[1]"]
        if self.infer_load:
            out.append("load_factor")
        if self.infer_ar1:
            out.append("noise_ar1")
        return out


class GirderLogPosterior:
    """log p(theta | y) up to a constant, sigma integrated out: log prior - (n/2) log RSS (white noise), or
    log prior - (n/2) log Q - ((n - m)/2) log(1 - rho^2) with AR(1) noise (`uq.ar1`).

    Call with theta shaped (W, dim); -inf outside the support (10 prior sd; |rho| <= ar1.RHO_MAX).
    """

    def __init__(
        self,
        model: GirderModalModel,
        y: np.ndarray,
        layout: ParameterLayout,
        ei_prior: EIPrior,
        k_prior: tuple[float, float] | None,
        load_rel_sd: float | None,
        noise: AR1Noise | None = None,
    ):
        if layout.infer_ar1 != (noise is not None):
            raise ValueError("AR(1) noise needs its series, and only then")
        self.model, self.layout, self.noise = model, layout, noise
        self.y = np.asarray(y, float)
        self.n = self.y.size
        S = layout.n_segments
        loc = [ei_prior.loc] * S
        sd = [ei_prior.log_sd] * S
        if layout.infer_springs:
            if k_prior is None:
                raise InputError("prior.k_median", None, "a spring prior when springs are inferred")
            loc += [math.log(k_prior[0])] * 2
            sd += [k_prior[1]] * 2
        if layout.infer_load:
            if not load_rel_sd:
                raise InputError("vehicle.load_rel_sd", load_rel_sd, "> 0 to infer the load factor")
            loc.append(0.0)  # log load factor; its sd to first order
            sd.append(load_rel_sd)
        if layout.infer_ar1:
            loc.append(0.0)  # z = atanh(rho); its prior (uniform rho) has sd about 1 in z
            sd.append(1.0)
        self.load_rel_sd = load_rel_sd
        self.loc, self.sd = np.array(loc), np.array(sd)
        self.lo = self.loc - SUPPORT_SD * self.sd
        self.hi = self.loc + SUPPORT_SD * self.sd
        if layout.infer_load:
            self.lo[layout.load] = math.log(max(1.0 - SUPPORT_SD * load_rel_sd, 1e-3))
            self.hi[layout.load] = math.log(1.0 + SUPPORT_SD * load_rel_sd)
        if layout.infer_ar1:
            self.lo[layout.ar1], self.hi[layout.ar1] = -Z_MAX, Z_MAX

    def unpack(self, theta: np.ndarray):
        """(EI (W, S), springs (W, 2) or None, load factor (W,) or None) of theta (W, dim)."""
        lay = self.layout
        theta = np.atleast_2d(theta)
        EI = np.exp(theta[:, : lay.n_segments])
        ks = np.exp(theta[:, lay.springs]) if lay.infer_springs else None
        lf = np.exp(theta[:, lay.load]) if lay.infer_load else None
        return EI, ks, lf

    def log_prior(self, theta: np.ndarray) -> np.ndarray:
        """Log prior density with respect to theta, up to a constant."""
        lay = self.layout
        theta = np.atleast_2d(theta)
        z = (theta - self.loc) / self.sd
        g = lay.n_segments + 2 * lay.infer_springs  # the Gaussian coordinates
        out = -0.5 * np.sum(z[:, :g] ** 2, axis=1)
        if lay.infer_load:
            ll = theta[:, lay.load]  # log load factor: N(1, sd) in the factor, times its Jacobian
            out = out - 0.5 * ((np.exp(ll) - 1.0) / self.load_rel_sd) ** 2 + ll
        if lay.infer_ar1:
            out = out + AR1Noise.log_prior(theta[:, lay.ar1])
        return out

    def predict(self, theta: np.ndarray) -> np.ndarray:
        """Surrogate predictions (W, P), in batches of BATCH."""
        theta = np.atleast_2d(theta)
        out = np.empty((theta.shape[0], self.n))
        for i in range(0, theta.shape[0], BATCH):
            EI, ks, lf = self.unpack(theta[i : i + BATCH])
            out[i : i + BATCH] = self.model.predict(EI, ks, lf)
        return out

    def rss(self, theta: np.ndarray) -> np.ndarray:
        r = self.y[None, :] - self.predict(theta)
        return np.einsum("wp,wp->w", r, r)

    def log_noise(self, theta: np.ndarray) -> np.ndarray:
        """The sigma-marginalised log likelihood: -(n/2) log RSS, or with AR(1) noise
        -(n/2) log Q(rho) - ((n - m)/2) log(1 - rho^2)."""
        theta = np.atleast_2d(theta)
        if self.noise is None:
            return -0.5 * self.n * np.log(self.rss(theta))
        z = theta[:, self.layout.ar1]
        q = self.noise.quad(self.y[None, :] - self.predict(theta), z)
        return -0.5 * self.n * np.log(q) + self.noise.log_jacobian(z)

    def log_quad(self, theta: np.ndarray, lp: np.ndarray) -> np.ndarray:
        """log of the sum of squares sigma's inverse-gamma law uses (RSS, or Q(rho) with AR(1) noise),
        recovered from stored log densities lp = log prior + log_noise."""
        theta = np.atleast_2d(theta)
        rest = self.log_prior(theta) - lp
        if self.noise is not None:
            rest = rest + self.noise.log_jacobian(theta[:, self.layout.ar1])
        return rest * (2.0 / self.n)

    def inside(self, theta: np.ndarray) -> np.ndarray:
        theta = np.atleast_2d(theta)
        return np.all((theta > self.lo) & (theta < self.hi), axis=1) & np.all(
            np.isfinite(theta), axis=1
        )

    def __call__(self, theta: np.ndarray) -> np.ndarray:
        theta = np.atleast_2d(theta)
        out = np.full(theta.shape[0], -np.inf)
        ok = self.inside(theta)
        if ok.any():
            out[ok] = self.log_prior(theta[ok]) + self.log_noise(theta[ok])
        return out
