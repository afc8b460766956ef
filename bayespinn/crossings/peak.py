"""The crossing reference's model terms and its posterior's peak.

Each crossing's term (its rows, its forward model, its force basis and resonant terms); the start (the
stated values, log EI profiled on a grid); Gauss-Newton on the constant-force parameters with the priors as
pseudo-observations; the modal truncation (modes until the prediction moves by under
`uq.modal_mcmc.TRUNCATION_FRACTION` of the noise sd); the Laplace scale at the peak.
`reference.crossings_reference` starts its samplers there."""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import least_squares

from ..config import Config
from ..data.measurements import Measurements
from ..uq.modal_mcmc import TRUNCATION_FRACTION
from . import resonance, tail
from .checks import split_crossings
from .curvature import curvature_sds
from .forward import CrossingModel
from .likelihood import FORCE_L_MEDIAN, CrossingsLogPosterior, CrossingTerm, n_basis_for
from .resonance import AMPLITUDE_MEDIAN, Resonance
from .resonance import NAMES as RESONANT_NAMES

#: modes in the dynamic correction of the force-basis responses without the band: the law's spectrum lies
#: below 4 / FORCE_L_MIN = 33 rad/s, under the first mode (63 rad/s for the Exeter girder) and far under the
#: second; the first mode alone leaves 0.2 % of those responses (strain gauges, against 24 modes), some
#: 4e-5 of the signal, while no mode at all would leave 15 %. With the band, every mode within its reach
#: (`tail.basis_modes`).
BASIS_MODES = 1


def terms(
    cfg: Config, data: Measurements, n_modes: int, forces: bool, band: bool | None = None
) -> list[CrossingTerm]:
    """Each crossing's `CrossingTerm`. band: with fluctuating forces, the force spectrum beyond the law's
    basis up to the road's reach, every mode within it dynamic (`tail`). None (the reference's law): on
    for a sprung vehicle, whose suspension passes the road's short wavelengths into the axle forces, off
    for moving forces (no body, so no road spectrum to derive the band's prior from); True or False
    forces it (the timing diagnostic, `studies/force_timing_check.py`)."""
    a_u, a_xx = data.weights
    out = []
    for name, rows, veh in split_crossings(cfg, data):
        nb = n_basis_for(cfg.beam.length / veh.speed) if forces else 0
        b = cfg.beam
        with_band = forces and (veh.model == "sprung" if band is None else band)
        extra, dynamic = None, min(n_modes, BASIS_MODES)
        if with_band:
            girder = (b.length, b.mass_per_length, cfg.prior.EI_median, veh.speed)
            extra = tail.band_of(*girder, nb)
            dynamic = tail.basis_modes(*girder, n_modes)
        model = CrossingModel(
            b.length, b.mass_per_length, veh.loads, veh.offsets,
            data.x[rows], data.t[rows], a_u[rows], a_xx[rows], n_modes=n_modes, n_basis=nb,
            basis_modes=dynamic, band=extra,
        )  # fmt: skip
        res = (
            Resonance.build(model, veh.speed, veh.entry_time, cfg.prior.EI_median)
            if forces and resonance.MODES
            else None
        )
        out.append(
            CrossingTerm(
                name,
                rows,
                np.asarray(data.value, float)[rows],
                model,
                veh.speed,
                veh.speed_sd,
                veh.entry_time,
                veh.entry_time_sd,
                sprung=veh.model == "sprung",
                body_frequency=veh.body_frequency,
                body_damping=veh.body_damping,
                resonance=res,
                common=forces and veh.loads.size > 1,
            )  # fmt: skip
        )
    return out


def start(post: CrossingsLogPosterior, cfg: Config) -> np.ndarray:
    """The stated values, with log EI the best of a grid over the prior (the other parameters stated)."""
    L = post.layout
    th = np.zeros(L.dim)
    for c in post.terms:
        if f"log_v[{c.name}]" in L.index:
            th[L.index[f"log_v[{c.name}]"]] = math.log(c.speed)
        if f"t0[{c.name}]" in L.index:
            th[L.index[f"t0[{c.name}]"]] = c.entry_time
    if "log_zeta" in L.index:
        th[L.index["log_zeta"]] = math.log(cfg.prior.damping_median)
    grid = post.ei_prior.loc + post.ei_prior.log_sd * np.linspace(-5, 5, 401)
    cand = np.repeat(th[None], grid.size, 0)
    cand[:, 0] = grid
    prof = np.concatenate(
        [_rss_profile(post, c) for c in np.array_split(cand, max(1, grid.size // 32))]
    ) + post.ei_prior.logpdf(grid)
    th[0] = grid[int(np.argmax(prof))]
    return th


def _rss_profile(post: CrossingsLogPosterior, theta: np.ndarray) -> np.ndarray:
    rss = sum(np.einsum("wp,wp->w", r, r) for r, _ in post.residuals(theta))
    return -0.5 * post.n * np.log(rss)


def least_squares_fit(post: CrossingsLogPosterior, th0: np.ndarray) -> tuple[np.ndarray, float]:
    """The constant-force parameters' maximum (Gauss-Newton on residuals / sigma and the priors as
    pseudo-residuals, sigma from the fit), and sigma there."""
    idx = [i for i, n in enumerate(post.layout.names) if n not in post.layout.hyper]
    base = th0.copy()

    def full(z: np.ndarray) -> np.ndarray:
        th = np.repeat(base[None], z.shape[0], 0)
        th[:, idx] = z
        return th

    sigma = 1.0
    for _ in range(2):  # sigma from the fit, then the fit with that sigma
        rss = sum(float(np.sum(r**2)) for r, _ in post.residuals(full(th0[idx][None])))
        sigma = math.sqrt(rss / post.n)

        def fun(z, sigma=sigma):
            th = full(np.atleast_2d(z))
            r = np.concatenate([r for r, _ in post.residuals(th)], axis=1)[0] / sigma
            return np.concatenate([r, _prior_residuals(post, th[0])])

        def jac(z, sigma=sigma):
            return _jacobian(post, full, idx, z, sigma)

        fit = least_squares(
            fun, th0[idx], jac=jac, method="lm", xtol=1e-12, ftol=1e-12, max_nfev=200
        )
        th0 = th0.copy()
        th0[idx] = fit.x
    return th0, sigma


def _jacobian(post: CrossingsLogPosterior, full, idx: list[int], z: np.ndarray, sigma: float):
    """Central-difference Jacobian of `least_squares_fit`' residuals: each crossing's rows only against the
    shared parameters and its own (the rest of its block is zero), one vectorised call per crossing."""
    names = [post.layout.names[i] for i in idx]
    h = 1e-6 * np.maximum(1.0, np.abs(z))
    Z = np.repeat(np.atleast_2d(z), 2 * z.size, 0)
    for i in range(z.size):
        Z[2 * i, i] += h[i]
        Z[2 * i + 1, i] -= h[i]
    th = full(Z)
    n_obs = sum(c.y.size for c in post.terms)
    P = np.stack([_prior_residuals(post, t) for t in th])
    J = np.zeros((n_obs + P.shape[1], z.size))
    J[n_obs:] = ((P[0::2] - P[1::2]) / (2 * h[:, None])).T
    row = 0
    for ci, c in enumerate(post.terms):
        need = [k for k, n in enumerate(names) if "[" not in n or n.endswith(f"[{c.name}]")]
        sel = np.ravel([[2 * k, 2 * k + 1] for k in need])
        p = post.unpack(th[sel])
        mu = c.predict(p, ci)
        J[row : row + c.y.size, need] = (-(mu[0::2] - mu[1::2]) / (2 * h[need, None] * sigma)).T
        row += c.y.size
    return J


def _prior_residuals(post: CrossingsLogPosterior, th: np.ndarray) -> np.ndarray:
    """sqrt(-2 log prior) terms of the normal priors on the constant-force parameters (pseudo-residuals)."""
    L = post.layout
    out = [(th[0] - post.ei_prior.loc) / post.ei_prior.log_sd]
    if "log_zeta" in L.index:
        med, sd = post.damping_prior
        out.append((th[L.index["log_zeta"]] - math.log(med)) / sd)
    for c in post.terms:
        out += [(th[L.index[name]] - mean) / sd for name, mean, sd in c.own]
    return np.array(out)


def fluctuation_start(post: CrossingsLogPosterior, th: np.ndarray, sigma: float) -> np.ndarray:
    """th with the fluctuating-force law's parameters at their start: the force scale and time scale, the
    axles' correlation and the resonant terms at their priors' medians (half the scale's), sigma from
    the constant-force fit."""
    th = th.copy()
    idx = post.layout.index
    th[idx["log_s"]] = math.log(0.5 * 0.05)
    th[idx["log_l"]] = math.log(FORCE_L_MEDIAN)
    th[idx["log_sigma"]] = math.log(sigma)
    if "logit_r" in idx:
        th[idx["logit_r"]] = 0.0  # the axles' correlation at its prior median, 1/2
    if "log_tail" in idx:
        th[idx["log_tail"]] = 0.0  # the band's level at its prior median
    if post.resonant:
        th[idx["log_q1"]] = th[idx["log_q2"]] = math.log(AMPLITUDE_MEDIAN)
        th[idx["log_z2"]] = math.log(post.mode_damping_prior[0])
    return th


def hessian_scale(post: CrossingsLogPosterior, th: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Laplace sds of the parameters at the maximum (`curvature.curvature_sds` of -log p); the steps h
    where the Hessian is not positive definite."""
    sd = curvature_sds(lambda p: -post(p), th, h)
    return h if sd is None else sd


def choose_modes(cfg, data, post_of, th, sigma, start: int = 8, cap: int = 64):
    """The smallest mode count whose predictions at th differ from twice as many by at most
    TRUNCATION_FRACTION x sigma (a floor of 1e-9 of the data's RMS for clean data)."""
    scale = float(np.sqrt(np.mean(np.asarray(data.value, float) ** 2)))
    tol = max(TRUNCATION_FRACTION * sigma, 1e-9 * scale)
    n = start
    while True:
        p1 = np.concatenate([r for r, _ in post_of(n).residuals(th[None])], axis=1)
        p2 = np.concatenate([r for r, _ in post_of(2 * n).residuals(th[None])], axis=1)
        err = float(np.max(np.abs(p1 - p2)))
        if err <= tol or n >= cap:
            return n, err
        n *= 2


def step(name: str, post: CrossingsLogPosterior) -> float:
    """Finite-difference step of each parameter for the Laplace scale."""
    if name.startswith("t0["):
        return 1e-4
    if name.startswith("log_v["):
        return 1e-5
    if name.startswith(("log_fb[", "log_zb[")):
        return 1e-2
    if name in RESONANT_NAMES or name in ("logit_r", "log_tail"):
        return 1e-2
    return {"log_EI": 1e-4, "log_zeta": 1e-2, "log_s": 1e-2, "log_l": 1e-2, "log_sigma": 1e-3}[name]
