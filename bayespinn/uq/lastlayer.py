"""Last-layer Bayesian PINN: the trained network's hidden features fixed, its linear output weights
integrated out analytically.

With the hidden layers of a trained PINN frozen, the non-dimensional deflection is linear in the
output weights beta: w = Phi beta, Phi the output layer's basis (`PINN.basis_jet`: the last hidden
features and a constant, plus the static enrichment and the free vibrations (or the modulated
features) where the profile has them; the free vibrations at each theta tried, see `LastLayer`). Every
term of the PINN is then linear in beta given theta = EI / EI_ref. The model is stated for the
stiffness-scaled weights gamma = theta beta (the output layer of theta w, which the load fixes whatever
EI is, as EI u_xxxx balances the load), so the weight prior and the boundary and initial conditions do
not depend on the unknown stiffness:

* data (SI): y ~ N(D gamma / theta, sigma^2 I), D = U (a_u Phi + a_xx / L^2 Phi_xixi);
* PDE pseudo-observations: 0 ~ N(S Phi_xixixixi gamma + I_c Phi_tautau gamma / theta - f/q, s_f^2) (the
  fit's residual theta S Phi_xixixixi beta + I_c Phi_tautau beta - f/q, unchanged);
* boundary and initial pseudo-observations: 0 ~ N(B gamma, s_b^2), 0 ~ N(C gamma, s_i^2);
* prior gamma ~ N(0, s_w^2 I).

Why gamma and not beta: the trained features cannot meet the boundary conditions exactly, so B beta is a
systematic error proportional to the deflection's amplitude, and a stiffer beam deflects less. Stated
for beta (0 ~ N(B beta, s_b^2), 1600 boundary rows) that term rewards every shrinking of the amplitude,
i.e. a stiffer EI: on a 10 dB Exeter fit (EI 1.012e9) it fell as 1/theta^2 and put the marginal's peak at
+14 % (the B-PINN's runaway at 10 dB, 3 of 20 intervals holding the truth). For gamma it is the same at
every EI; there the peak lies at +1.5 % (the modal posterior's mean: +2.7 %, sd 2.8 %) and the noise level
stays right (5.00e-4 against the modal 5.25e-4). Weakening the boundary rows instead (s_b times 10) also
removes the drift but frees 12-18 output directions to fit the noise (sigma 4.1e-4, 2.9 modal sds low).
The first mode's free vibrations follow theta (their frequency carries information about EI) only where
the data resolve them. The vibration's amplitude is not a free parameter of the model: the initial-
condition rows hold it at the fit's, and where the noise hides the vibration that amplitude is mostly
fitted noise (two 10 and 20 dB fits of the same girder and truck: 5.1 % and 3.6 % of the deflection, with
opposite signs). Its frequency then sharpens the posterior spuriously (10 dB: NUTS sd 0.54x the modal one).
So the fitted first-mode vibration at the data points, v, is tested against the noise: z^2 = |v|^2 /
sigma^2 (sigma the marginal's noise mode at the fitted EI) against the chi^2 quantile of its number of
coefficients at `VIBRATION_FALSE_ALARM`; below it the mode stays at the fitted EI like the others.
Measured (grid posteriors of the B-PINN fits of the must-show runs): Exeter 10 dB, z^2 3.5 < 9.2, held:
sd 1.03x the modal one (0.59x if it varied); Exeter 20 dB, z^2 18.7 > 9.2, varies: 1.01x (1.54x if held,
the modal posterior using the frequency there); 20 m girder at 30 dB, z^2 68 > 16.8: 1.26x.
That test, a hard switch, is for free amplitudes only (`enrich.FreeVibration`). The fast profile ties the
amplitudes to the loads (`enrich.TiedVibration`: one column per mode, its amplitudes those that keep the
girder's state continuous when an axle enters or leaves), so they are no longer fitted noise, the
frequency's information is the physics', and the first mode always follows theta (`vibration_z2` is still
reported).

So p(y | theta, sigma) = integral over gamma is Gaussian and exact: with R = S Phi_xixixixi + I_c
Phi_tautau / theta, A = D'D/(theta sigma)^2 + R'R/s_f^2 + B'B/s_b^2 + C'C/s_i^2 + I/s_w^2 and
b = D'y/(theta sigma^2) + R'f/s_f^2,

    log p = -1/2 (y'y/sigma^2 + f'f/s_f^2) + 1/2 b'A^-1 b - 1/2 log|A| - P log sigma - (H+1) log s_w + c.

The pseudo-observation scales s_f, s_b, s_i are stated, not tuned: the RMS residual of each term at the
deterministic fit (what the network can actually achieve; for gamma_fit = theta_fit beta_fit), floored at
`MIN_PSEUDO_SD` (`PDE_SD_FACTOR`, 1, multiplies the PDE's). The PDE rows are where theta enters: with the
load known, they tie the stiffness-scaled weights to the load, and the data then read theta from the
amplitude. Loosened, they let each member's features trade amplitude for theta, and the members wander
apart. Measured by `studies/pde_sd_sweep.py` on family seed 1 (6 strain and 6 deflection bridges at 30
dB, the ensemble's members rebuilt with the PDE rows' sd at 1, 3, 10, 30 and 100 times the residual): at
1 the members' mixture sits within 0.47 reference sd of the reference with 0.95-1.12x its width on all
12; at 10 (the earlier default) two strain bridges were 1.54x and 1.80x as wide and one 0.95 sd off, and
wider still above (`reports/paper/diagnostics/README.md`). An older version of this model, on a 20 m test
bridge, put the mode 2.6 sd off at 1; with the tied vibrations and today's features the deflection
bridges stay within 0.18 sd there. Scored on the held-out family at 30 dB (`studies/family.py`), both
PINN methods keep every band with strain and deflections; one fast crossing (alpha 0.18) puts the B-PINN
2.8 sd off, which its own check (`bpinn_core.MAX_MOVE_SD`) marks not converged. The girder PINN
(`uq.girder_lastlayer`) keeps its own factor. All Gram matrices are precomputed, so one evaluation costs
one (H+1) x (H+1) Cholesky factorisation (float64, torch, differentiable for NUTS).

AR(1) noise (`noise`, `uq.ar1`): the data term becomes y ~ N(D gamma / theta, sigma^2 R(rho)), R the AR(1)
correlation within each sensor's series. Whitening the rows along each series (x_k -> (x_k - rho x_(k-1)) /
sqrt(1 - rho^2)) turns it into the white model of the whitened rows, with the Jacobian -((n - m)/2)
log(1 - rho^2) for m series, so the marginal stays exact. Every data Gram product X'R^-1 Y splits into four
fixed pieces (first, current and previous rows, `_pieces`) combined at each rho, so the fixed columns cost
nothing more per evaluation; the varying first mode's rows are whitened at each (theta, rho). rho enters
as z = atanh rho (the `z` argument of every method; `self.z`, 0 until set, where it is held).
"""

from __future__ import annotations

import copy
import logging
import math

import numpy as np
import torch

from ..data.measurements import Measurements
from ..pinn.enrich import TiedVibration
from ..pinn.losses import moving_load
from ..pinn.network import PINN
from ..pinn.problem import Problem
from ..pinn.taylor import Jet
from .ar1 import AR1Noise, lag1
from .lastlayer_algebra import (
    _cholesky,
    _log_cosh,
    _pieces,
    combine_pieces,
    feature_jet,
    log_prior_z,
    whiten_rows,
)
from .lastlayer_posterior import (
    GRID_DOUBLINGS,
    GRID_EDGE,
    GRID_HALF_WIDTH,
    GRID_POINTS,
    IDENTIFIED_FRACTION,
    LastLayerPosterior,
    LastLayerPredictor,
    identified,
)

log = logging.getLogger(__name__)

#: its public names, with those of its parts in their own modules (`lastlayer_algebra`: the basis jet and
#: the tensor algebra; `lastlayer_posterior`: what the built marginal says), importable from here
__all__ = [
    "GRID_DOUBLINGS",
    "GRID_EDGE",
    "GRID_HALF_WIDTH",
    "GRID_POINTS",
    "IDENTIFIED_FRACTION",
    "MIN_PSEUDO_SD",
    "PDE_SD_FACTOR",
    "VIBRATION_FALSE_ALARM",
    "WEIGHT_PRIOR_FACTOR",
    "LastLayer",
    "LastLayerPredictor",
    "feature_jet",
    "identified",
    "log_prior_z",
]

#: floor of the pseudo-observation sds (non-dimensional), so a perfect fit cannot make them singular
MIN_PSEUDO_SD = 1e-6
#: the PDE pseudo-observations' sd is the fit's RMS residual times this: 1, the residual the network
#: achieves (module docstring; chosen among 1, 3, 10, 30 and 100 on family seed 1, not the held-out family)
PDE_SD_FACTOR = 1.0
#: false-alarm rate of the test "the data resolve the first mode's vibration" (module docstring)
VIBRATION_FALSE_ALARM = 0.01
#: prior sd of the stiffness-scaled output weights gamma, as a multiple of the largest fitted one
WEIGHT_PRIOR_FACTOR = 10.0


class LastLayer(LastLayerPosterior):
    """Exact marginal likelihood of (theta, sigma) for one trained member; see the module docstring.

    The first mode's free-vibration columns (`enrich.FreeVibration.lowest`, the trailing `nv` columns of
    the basis) are functions of theta: they are re-evaluated at every theta (differentiably), so their
    frequency carries its information about EI. They vanish at the supports, and with zero damping they
    solve the homogeneous PDE exactly, so only their data and initial-condition rows are recomputed. The
    higher modes stay at the fitted theta (re-evaluated, their fast phases would make the likelihood
    jagged under noise) and, being exact homogeneous solutions, get no PDE rows.

    Parameters
    ----------
    model : trained PINN; member : which of its members
    problem : the Problem it was trained on (scales, load); data : the measurements to explain (SI)
    n_pde, n_bc, n_ic : pseudo-observation points (uniform grid-free random, from `rng`)
    beta_rel, images : the Gaussian load as the PINN was trained on it (`TrainSettings.beta_rel`, `.images`)
    vary_first_mode : None (default) lets the vibration test decide whether the first mode follows theta
        (`first_mode_varies`, with `vibration_z2` and `vibration_threshold`); True or False forces it
    noise : None (white noise) or the data's AR(1) series (`uq.ar1.AR1Noise`): the data rows are then
        whitened with the coefficient rho = tanh(z) that every method takes as its ``z`` (default `self.z`,
        0 until set), and the log marginal carries the whitening's Jacobian (`ar1` module docstring)
    """

    def __init__(
        self,
        model: PINN,
        member: int,
        problem: Problem,
        data: Measurements,
        rng: np.random.Generator,
        n_pde: int = 2500,
        n_bc: int = 400,
        n_ic: int = 400,
        beta_rel: float | None = None,
        images: bool = False,
        vary_first_mode: bool | None = None,
        noise: AR1Noise | None = None,
    ):
        model = model.member(member).double()  # one member, float64, for every basis evaluation
        member = 0
        self.model, self.member, self.problem = model, member, problem
        sc = problem.scales
        self.sc = sc
        kw = {} if beta_rel is None else {"beta_rel": beta_rel}
        pt = problem.tensors(1, dtype=torch.float64, **kw)
        self.pt = pt
        T = lambda a: torch.as_tensor(np.asarray(a, float), dtype=torch.float64)  # noqa: E731
        fv_all = model.free_vibration
        self.fv, quiet_pde = None, None
        if (
            fv_all is not None
        ):  # the first mode follows theta, the higher modes stay (`FreeVibration.split`)
            self.fv, _, quiet_pde = fv_all.split(model.head.shape[1])
        self.nv = self.fv.n_features if self.fv is not None else 0
        # data design (SI)
        a_u, a_xx = data.weights
        self.a_u, self.a_xx = T(a_u), T(a_xx)
        self.xi_d, self.tau_d = T(data.x / sc.L), T(data.t / sc.T)
        self.kx_d = 2 if np.any(a_xx != 0) else 0
        y = T(data.value)
        self.ar1, self.z = noise, 0.0
        if noise is not None:
            if noise.n != len(data):
                raise ValueError(f"the AR(1) series cover {noise.n} points, the data {len(data)}")
            L_ = lambda a: torch.as_tensor(np.asarray(a, np.int64))  # noqa: E731
            self._first, self._cur, self._prev = L_(noise.first), L_(noise.cur), L_(noise.prev)
        # pseudo-observation points: PDE (non-dimensional residual, as in training but unscaled by beta),
        # boundary (u = u_xx = 0 at both ends) and initial (u = u_t = 0); drawn in this order from rng
        self.xi_f, self.tau_f = T(rng.uniform(0, 1, n_pde)), T(rng.uniform(0, 1, n_pde))
        self.tb = T(rng.uniform(0, 1, n_bc))
        self.xi_i = T(rng.uniform(0, 1, n_ic))
        self.f = f = moving_load(self.xi_f.unsqueeze(0), self.tau_f.unsqueeze(0), pt, images)[0]
        # columns without PDE rows (exact homogeneous solutions): the quiet higher modes
        self.pde_mask = torch.ones(model.head.shape[1], dtype=torch.float64)
        if quiet_pde is not None:
            self.pde_mask[quiet_pde] = 0.0
        D, P4, P2, Bm, Cm = self.rows(
            lambda xi, tau, kx, kt: feature_jet(model, member, xi, tau, kx, kt)
        )
        # the fitted output weights, and the residual scales they achieve (every column at the fitted EI);
        # the boundary, initial and prior scales are those of the stiffness-scaled weights gamma = theta beta
        beta_fit = model.head[0].detach().double()
        self.theta_fit = float(torch.exp(model.log_ei[member].detach().double()))
        gamma_fit = self.theta_fit * beta_fit
        r_f = self.theta_fit * P4 @ beta_fit + P2 @ beta_fit - f
        self.s_f = max(float(r_f.pow(2).mean().sqrt()), MIN_PSEUDO_SD) * PDE_SD_FACTOR
        self.s_b = max(float((Bm @ gamma_fit).pow(2).mean().sqrt()), MIN_PSEUDO_SD)
        self.s_i = max(float((Cm @ gamma_fit).pow(2).mean().sqrt()), MIN_PSEUDO_SD)
        self.s_w = WEIGHT_PRIOR_FACTOR * float(gamma_fit.abs().max())
        self.beta_fit = beta_fit
        # the fitted response's energy at the data points that the network's own columns carry, beyond
        # the fixed extras (the enrichment and the vibrations, the reference's modal model)
        n_net = model.head.shape[1] - model.extra_head.shape[1]
        w_fit, w_net = D @ beta_fit, D[:, :n_net] @ beta_fit[:n_net]
        self.network_share = float(w_net.pow(2).sum() / w_fit.pow(2).sum().clamp_min(1e-300))
        self.n = y.numel()
        self.k = D.shape[1]
        self.fit_resid = (y - D @ beta_fit).numpy()
        self.fit_rss = float((self.fit_resid**2).sum())
        self.y, self.yy = y, float(y @ y)
        self._gram(D, P4, P2, Bm, Cm)
        # does the first mode's frequency carry information here? (module docstring)
        self.vibration_z2, self.vibration_threshold, self.first_mode_varies = (
            None,
            None,
            self.fv is not None,
        )
        if self.fv is not None:
            from scipy.stats import chi2

            sigma = self.noise_mode(math.log(self.theta_fit))
            v = D[:, self.kf :] @ beta_fit[self.kf :]
            self.vibration_z2 = float(v @ v) / sigma**2
            self.vibration_threshold = float(chi2.ppf(1.0 - VIBRATION_FALSE_ALARM, self.nv))
            if vary_first_mode is None:
                # tied amplitudes are the loads', not fitted noise: their frequency always speaks
                vary_first_mode = isinstance(fv_all, TiedVibration) or (
                    self.vibration_z2 >= self.vibration_threshold
                )
            if not vary_first_mode:
                self.first_mode_varies = False
                if (
                    fv_all.pde_exact
                ):  # now an exact homogeneous solution at the fitted EI, like the others
                    self.pde_mask[self.kf :] = 0.0
                    P4, P2 = P4 * self.pde_mask, P2 * self.pde_mask
                self.fv, self.nv = None, 0
                self._gram(D, P4, P2, Bm, Cm)

    def rows(self, jet) -> tuple[torch.Tensor, ...]:
        """The design rows (D, P4, P2, B, C) of the basis given by ``jet(xi, tau, kx, kt) -> Jet (N, k)`` at this
        model's data and pseudo-observation points (differentiable in whatever ``jet`` depends on)."""
        pt = self.pt
        j = jet(self.xi_d, self.tau_d, 2, 0)
        D = self._design(j.value, j.dx(2))
        jf = jet(self.xi_f, self.tau_f, 4, 2)
        P4 = pt.stiffness * jf.dx(4) * self.pde_mask
        P2 = pt.inertia * jf.dt(2) * self.pde_mask
        rows_b = []
        for end in (0.0, 1.0):
            jb = jet(torch.full_like(self.tb, end), self.tb, 2, 0)
            rows_b += [jb.value, jb.dx(2)]
        ji = jet(self.xi_i, torch.zeros_like(self.xi_i), 0, 1)
        return D, P4, P2, torch.cat(rows_b), torch.cat([ji.value, ji.dt(1)])

    def with_rows(self, D, P4, P2, Bm, Cm) -> LastLayer:
        """The same model (points, scales, priors, first-mode choice) for other design rows, e.g. those of the
        network at other hidden weights (`bpinn_full`). Only for a model whose first mode is held."""
        if self.fv is not None:
            raise ValueError(
                "with_rows needs a last-layer model whose first mode is held (vary_first_mode=False)"
            )
        view = copy.copy(self)
        view._gram(D, P4, P2, Bm, Cm)
        return view

    def _gram(self, D, P4, P2, Bm, Cm):
        """Gram matrices of the columns that stay fixed (all but the varying first mode's), from the design rows."""
        f, y = self.f, self.y
        # rows changed: `_vary_block`'s kept block is not theirs
        self.__dict__.pop("_vary_cache", None)
        self.kf = kf = self.k - self.nv
        Df, P4f, P2f, Cf = D[:, :kf], P4[:, :kf], P2[:, :kf], Cm[:, :kf]
        self.Df, self.Cf = Df, Cf
        self.G_dd, self.g_dy = Df.T @ Df, Df.T @ y
        if self.ar1 is not None:  # the pieces of D'P(rho)D, D'P(rho)y, y'P(rho)y (`_data_gram`)
            f_, c_, p_ = self._first, self._cur, self._prev
            self._ar_G = _pieces(Df[f_], Df[c_], Df[p_], Df[f_], Df[c_], Df[p_])
            self._ar_g = _pieces(Df[f_], Df[c_], Df[p_], y[f_], y[c_], y[p_])
            self._ar_yy = _pieces(y[f_], y[c_], y[p_], y[f_], y[c_], y[p_])
        self.G44 = P4f.T @ P4f / self.s_f**2
        self.G42 = (P4f.T @ P2f + P2f.T @ P4f) / self.s_f**2
        self.G22 = P2f.T @ P2f / self.s_f**2
        self.g4f, self.g2f = P4f.T @ f / self.s_f**2, P2f.T @ f / self.s_f**2
        self.ff = float(f @ f) / self.s_f**2
        Bf = Bm[:, :kf]  # the free vibrations vanish at the supports (u and u_xx)
        self.G_c = Bf.T @ Bf / self.s_b**2 + Cf.T @ Cf / self.s_i**2
        self.eye = torch.eye(self.k, dtype=torch.float64, device=D.device) / self.s_w**2
        self.pde_v = None
        if self.fv is not None and not self.fv.pde_exact:
            self.pde_v = (self.xi_f, self.tau_f, P4f, P2f, f)

    def z_start(self) -> float:
        """A start for z = atanh rho: the fit residuals' lag-1 autocorrelation along the noise series (held
        inside |rho| <= 0.95)."""
        return math.atanh(min(max(lag1(self.ar1.series, self.fit_resid), -0.95), 0.95))

    def noise_mode(self, log_theta: float) -> float:
        """The noise level sigma that maximises the marginal likelihood at theta = exp(log_theta)."""
        from scipy.optimize import minimize_scalar

        c = 0.5 * math.log(max(self.fit_rss, 1e-300) / max(self.n, 1))
        lt = torch.tensor(log_theta, dtype=torch.float64)

        def neg(ls):
            with torch.no_grad():
                return -float(self.log_marginal(lt, torch.tensor(ls, dtype=torch.float64)))

        r = minimize_scalar(
            neg, bounds=(c - 1.5, c + 1.5), method="bounded", options={"xatol": 1e-4}
        )
        return math.exp(float(r.x))

    def _design(self, value: torch.Tensor, curv: torch.Tensor | None) -> torch.Tensor:
        """Rows of the data design (SI) from the basis' values and xi-curvatures at the data points."""
        sc = self.sc
        out = sc.U * self.a_u[:, None] * value
        if curv is not None:
            out = out + sc.U * (self.a_xx / sc.L**2)[:, None] * curv
        return out

    def _fv_jet(
        self, xi: torch.Tensor, tau: torch.Tensor, kx: int, kt: int, log_theta: torch.Tensor
    ) -> Jet:
        # the same (1, N) point tensors at every theta, so the free vibrations' jet cache can hold the
        # parts that do not depend on theta
        key = (id(xi), id(tau))
        pts = self.__dict__.setdefault("_batched_points", {})
        if key not in pts:
            pts[key] = (xi, tau, xi.unsqueeze(0), tau.unsqueeze(0))
        _, _, xb, tb = pts[key]
        j = self.fv.jet(xb, tb, kx, kt, log_theta.reshape(1), detach=False)
        return j.map(lambda c: c[0])

    def _varying(self, log_theta: torch.Tensor):
        """The free vibrations' data design Dv (n, nv) and initial-condition rows Cv at theta."""
        jd = self._fv_jet(self.xi_d, self.tau_d, self.kx_d, 0, log_theta)
        Dv = self._design(jd.value, jd.dx(2) if self.kx_d else None)
        if not hasattr(self, "tau_i"):
            self.tau_i = torch.zeros_like(self.xi_i)
        ji = self._fv_jet(self.xi_i, self.tau_i, 0, 1, log_theta)
        Cv = torch.cat([ji.value, ji.dt(1)])
        return Dv, Cv

    def _z(self, z) -> torch.Tensor | None:
        """The AR(1) coefficient's z = atanh(rho) to use (a float64 tensor), or None for white noise."""
        if self.ar1 is None:
            return None
        z = self.z if z is None else z
        return z if torch.is_tensor(z) else torch.tensor(float(z), dtype=torch.float64)

    def _whiten(self, X: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """Rows of X (n, ...) whitened along the noise series: x_k -> (x_k - rho x_(k-1)) / sqrt(1 - rho^2)
        for every non-first sample (differentiable in z)."""
        return whiten_rows(X, self._cur, self._prev, z)

    def _data_gram(self, z: torch.Tensor | None):
        """(D'PD, D'Py, y'Py) of the fixed columns, P the noise's precision times sigma^2 (I for white noise)."""
        if z is None:
            return self.G_dd, self.g_dy, self.yy
        return tuple(combine_pieces(p, z) for p in (self._ar_G, self._ar_g, self._ar_yy))

    def _vary_block(self, log_theta: torch.Tensor, z: torch.Tensor | None):
        """(Df'P Dv, Dv'P Dv, Dv'P y, Cv) of the varying first mode at theta (P: the noise's precision times
        sigma^2). Where no gradient is asked for, the last one is kept and reused at the same (theta, z): a
        grid over sigma at one theta and rho computes it once."""
        grad = torch.is_grad_enabled() and (
            log_theta.requires_grad or (z is not None and z.requires_grad)
        )
        key = None if grad else (float(log_theta), None if z is None else float(z))
        hit = self.__dict__.get("_vary_cache")
        if key is not None and hit is not None and hit[0] == key:
            return hit[1]
        Dv, Cv = self._varying(log_theta)
        Df, y = self.Df, self.y
        if z is not None:
            Df, Dv, y = self._whiten(Df, z), self._whiten(Dv, z), self._whiten(y, z)
        out = (Df.T @ Dv, Dv.T @ Dv, Dv.T @ y, Cv)
        if key is not None:
            self._vary_cache = (key, out)
        return out

    def _system(self, log_theta: torch.Tensor, log_sigma: torch.Tensor, z=None):
        """Precision A and vector b of the stiffness-scaled weights gamma = theta beta given (theta, sigma, rho),
        with 1 / sigma^2 and the data's whitened sum of squares y'Py."""
        z = self._z(z)
        G_dd, g_dy, yy = self._data_gram(z)
        it = torch.exp(-log_theta)
        inv_s2 = torch.exp(-2 * log_sigma)
        d2 = inv_s2 * it**2  # the data rows are D / theta
        A = G_dd * d2 + self.G44 + it * self.G42 + it**2 * self.G22 + self.G_c
        b = g_dy * (inv_s2 * it) + self.g4f + it * self.g2f
        if self.fv is not None:
            DfDv, DvDv, Dvy, Cv = self._vary_block(log_theta, z)
            s_i2 = self.s_i**2
            A_fv = DfDv * d2 + self.Cf.T @ Cv / s_i2
            A_vv = DvDv * d2 + Cv.T @ Cv / s_i2
            b_v = Dvy * (inv_s2 * it)
            if self.pde_v is not None:  # damped free vibrations leave a PDE residual
                xi_f, tau_f, P4f, P2f, f = self.pde_v
                jf = self._fv_jet(xi_f, tau_f, 4, 2, log_theta)
                Rv = self.pt.stiffness * jf.dx(4) + it * self.pt.inertia * jf.dt(2)
                s_f2 = self.s_f**2
                A_fv = A_fv + (P4f + it * P2f).T @ Rv / s_f2
                A_vv = A_vv + Rv.T @ Rv / s_f2
                b_v = b_v + Rv.T @ f / s_f2
            A = torch.cat([torch.cat([A, A_fv], 1), torch.cat([A_fv.T, A_vv], 1)], 0)
            b = torch.cat([b, b_v])
        return A + self.eye, b, inv_s2, yy, z

    def log_marginal(
        self, log_theta: torch.Tensor, log_sigma: torch.Tensor, z=None
    ) -> torch.Tensor:
        """log p(y, pseudo-observations | theta, sigma[, rho = tanh z]) up to a constant (differentiable
        scalar); ``z`` defaults to `self.z` and is ignored for white noise."""
        A, b, inv_s2, yy, z = self._system(log_theta, log_sigma, z)
        Lc = _cholesky(A)
        w = torch.cholesky_solve(b.unsqueeze(-1), Lc).squeeze(-1)
        logdet = 2 * torch.log(torch.diagonal(Lc)).sum()
        out = -0.5 * (yy * inv_s2 + self.ff) + 0.5 * (b @ w) - 0.5 * logdet - self.n * log_sigma
        if z is not None:  # the whitening's Jacobian, -((n - m)/2) log(1 - rho^2)
            out = out + (self.ar1.n - self.ar1.m) * _log_cosh(z)
        return out
