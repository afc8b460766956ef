"""Reference posterior of a smooth EI field (`[model] EI_field = "smooth"`): a local loss of stiffness of
its own depth, place and width.

EI per segment finds a loss that sits on a segment; a loss of its own shape and place (corrosion, a
crack, a heavy repair) lies across segment edges. Here EI(x) is the girder's level times one smooth
local loss,

    EI(x) = EI_level (1 - depth exp(-(x - position)^2 / (2 width^2))),

and the answer is EI(x) with its 90 % band along the span, and the loss's depth, position and width.

Prior. log EI_level ~ N(m, sd^2) with m = log EI_median and sd = EI_log_sd (the user's prior, as for a
uniform girder); depth uniform on (0, 1); position uniform on the span; width log-uniform from one
piece (L / `PIECES`: what the surrogate's mesh resolves) to L / 4 (wider, the loss is the level's).
No constant is fitted to data: the ranges follow from the span and the mesh. The sampler works in
theta = (a, u_depth, u_position, u_width) ~ N(0, I): the level is m + sd a, each bounded quantity its
range's quantile at Phi(u). Noise: white Gaussian, sigma under the Jeffreys prior integrated out,
p(theta | y) proportional to N(theta; 0, I) RSS(theta)^(-n/2); sigma^2 | theta ~ InvGamma(n/2, RSS/2)
drawn afterwards.

Likelihood: `GirderModalModel` on a `PIECES`-segment girder, each piece's EI the compliance average of
EI(x) over the piece (exact FE statics, modal dynamics with the girder reference's mode-count check at
the level-only fit).

Inference. The position makes the posterior multimodal (a loss can explain the data from more than one
place, and gauges see EI only near where they sit), so the MAP search is global: a grid over
(position, width, depth) with the level profiled out, whose local maxima (at most `STARTS`) start
Levenberg-Marquardt runs (from starts along the span alone, the search missed the best mode by hundreds
of nats on gauge data, even on data from the surrogate itself); distinct modes within `MODE_CUTOFF` of
the best Laplace evidence each get a multivariate t proposal (`T_DOF`) from their Laplace fit, and adaptive multiple importance sampling refines them (at least `AMIS_ROUNDS`;
deterministic-mixture weights over every proposal; rounds continue until the effective sample size
reaches `sampler.ESS_MIN`, at most `AMIS_MAX_ROUNDS`; the search and the sampler: `uq.field_search`).
The draws are resampled to `N_DRAWS`.
Diagnostics: the weights' Kish effective sample size (`converged` when at least `sampler.ESS_MIN`), the
modes found. Derived per draw: EI(x) on `GRID` points along the span, the span-averaged flexibility's
equivalent EI = L / integral dx / EI (the summary's `EI`), and p_damaged(x) = P(EI(x) < 0.9 EI_nominal).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.special import ndtr

from .. import seeding
from ..config import Config
from ..data.measurements import Measurements
from ..errors import InputError
from ..physics.fe_modal import GirderModalModel
from ..physics.girder import Girder
from ..physics.hermite import element_of
from ..threads import one_blas_thread
from .field_search import (
    AMIS_MAX_ROUNDS,
    STARTS,
    SUPPORT_SD,
    _distinct,
    _grid_starts,
    _lm_map,
    amis,
)
from .girder_map import MODE_STEPS
from .girder_posterior import DAMAGE_FRACTION
from .modal_mcmc import TRUNCATION_FRACTION
from .priors import EIPrior
from .sampler import ESS_MIN

#: equal pieces of the surrogate (each two of its 96 elements), and points per piece of the compliance
#: average
PIECES = 48
SUB = 8
#: posterior draws kept (resampled)
N_DRAWS = 4000
#: points of the reported EI(x)
GRID = 101


@dataclass(frozen=True)
class LocalLoss:
    """The map from theta = (a, u_depth, u_position, u_width) to the field, for a span `length` and the
    level's prior N(m, sd^2) in log EI."""

    length: float
    m: float
    sd: float

    @property
    def width_range(self) -> tuple[float, float]:
        return self.length / PIECES, self.length / 4.0

    def params(self, theta: np.ndarray) -> dict[str, np.ndarray]:
        """level [N m^2], depth, position [m], width [m] per row of theta (W, 4)."""
        th = np.atleast_2d(theta)
        lo, hi = self.width_range
        return {
            "level": np.exp(self.m + self.sd * th[:, 0]),
            "depth": ndtr(th[:, 1]),
            "position": self.length * ndtr(th[:, 2]),
            "width": lo * np.exp(math.log(hi / lo) * ndtr(th[:, 3])),
        }

    def EI_at(self, theta: np.ndarray, x: np.ndarray) -> np.ndarray:
        """EI(x) (W, len(x))."""
        p = self.params(theta)
        x = np.asarray(x, float)[None, :]
        g = np.exp(-0.5 * ((x - p["position"][:, None]) / p["width"][:, None]) ** 2)
        return p["level"][:, None] * (1.0 - p["depth"][:, None] * g)

    def curvature_factor(
        self, theta: np.ndarray, EI_pieces: np.ndarray, x: np.ndarray, piece: np.ndarray
    ):
        """(W, len(x)): the factor EI_piece / EI(x) that turns the surrogate's curvature at x (where the
        piece `piece` holds EI_pieces) into the field's, M / EI(x). The bending moment is what the
        surrogate gets right (statically determined on pinned supports); the curvature at a gauge is the
        moment over the EI at the gauge itself, not over its piece's average (on the loss's flank the two
        differ by several per cent over one piece)."""
        ux, inv = np.unique(np.asarray(x, float), return_inverse=True)
        return EI_pieces[:, piece] / self.EI_at(theta, ux)[:, inv.ravel()]

    def EI_pieces(self, theta: np.ndarray) -> np.ndarray:
        """Each piece's compliance-averaged EI, (W, PIECES)."""
        x = (np.arange(PIECES * SUB) + 0.5) * self.length / (PIECES * SUB)
        with np.errstate(divide="ignore"):
            inv = 1.0 / self.EI_at(theta, x)
        return 1.0 / inv.reshape(-1, PIECES, SUB).mean(axis=2)


@dataclass
class FieldPosterior:
    """Draws of the smooth field: `theta` (N, 4) through `loss`, `sigma` (N,), and the run's facts."""

    loss: LocalLoss
    theta: np.ndarray
    sigma: np.ndarray
    EI_nominal: float
    diagnostics: dict = field(default_factory=dict)
    runtime_s: float = 0.0

    @property
    def length(self) -> float:
        return self.loss.length

    @property
    def EI(self) -> np.ndarray:
        """Span-averaged flexibility's equivalent L / integral dx / EI, per draw (N,)."""
        return PIECES / np.sum(1.0 / self.loss.EI_pieces(self.theta), axis=1)

    def EI_at(self, x: np.ndarray) -> np.ndarray:
        """EI(x) per draw (N, len(x))."""
        return self.loss.EI_at(self.theta, x)

    def params(self) -> dict[str, np.ndarray]:
        return self.loss.params(self.theta)

    def EI_x(self, truth: np.ndarray | None = None) -> dict:
        """The contract's `EI_x` entry on `field_grid` points (with p_damaged); given the true EI at those
        points, also the share of them the 90 % band holds (`coverage`)."""
        x = field_grid(self.length)
        e = self.EI_at(x)
        q = np.quantile(e, [0.05, 0.95], axis=0)
        out = {
            "x": x.tolist(),
            "mean": e.mean(0).tolist(),
            "ci90": np.stack(q, axis=1).tolist(),
            "p_damaged": np.mean(e < DAMAGE_FRACTION * self.EI_nominal, axis=0).tolist(),
        }
        if truth is not None:
            t = np.asarray(truth, float)
            out["coverage"] = float(np.mean((t >= q[0]) & (t <= q[1])))
        return out


def field_grid(length: float) -> np.ndarray:
    """The GRID points [m] of `EI_x`."""
    return np.linspace(0.0, length, GRID)


def field_posterior(
    data: Measurements,
    cfg: Config,
    *,
    seed: int | np.random.SeedSequence = 0,
    progress: bool = False,
) -> FieldPosterior:
    """The reference posterior of a smooth EI field for `cfg` (pinned girder, white noise, stated loads)."""
    t0 = time.perf_counter()
    check_field(cfg, data)
    return one_blas_thread(_field_posterior)(data, cfg, seed, progress, t0)


@dataclass
class _Problem:
    """The smooth field's posterior on one dataset (picklable: a PINN's problem carries it to worker
    processes). `predict(theta)`: the surrogate's noise-free response (W, n) at the data's points per row
    of theta, strain rows at the field's own EI at the gauge (`LocalLoss.curvature_factor`);
    `residuals(theta)`: the residuals (W, n) and log N(theta; 0, I) - (n/2) log RSS (W,) per row of theta
    (-inf outside the support or where the surrogate fails); `a0` the level-only fit's theta[0];
    `n_modes` the surrogate's mode count; `evals` the surrogate evaluations spent setting it up."""

    loss: LocalLoss
    y: np.ndarray
    model: GirderModalModel
    curv: np.ndarray  # the curvature (strain) rows
    x_c: np.ndarray  # their positions [m]
    piece_c: np.ndarray  # their piece in the surrogate's mesh
    a0: float
    n_modes: int
    evals: int

    @property
    def n(self) -> int:
        return self.y.size

    def predict(self, th: np.ndarray) -> np.ndarray:
        ei = self.loss.EI_pieces(th)
        pred = self.model.predict(ei)
        if self.curv.size:
            pred[:, self.curv] *= self.loss.curvature_factor(th, ei, self.x_c, self.piece_c)
        return pred

    def residuals(self, th: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        th = np.atleast_2d(th)
        y, n = self.y, self.n
        r = np.full((len(th), n), np.nan)
        ok = np.flatnonzero(np.all(np.abs(th) < SUPPORT_SD, axis=1))
        for i in range(0, ok.size, 256):
            rows = ok[i : i + 256]
            with np.errstate(all="ignore"):
                r[rows] = y[None] - self.predict(th[rows])
        rss = np.einsum("wp,wp->w", r, r)
        good = np.isfinite(rss) & (rss > 0)
        with np.errstate(all="ignore"):
            lp = np.where(good, -0.5 * np.sum(th**2, 1) - 0.5 * n * np.log(rss), -np.inf)
        return r, lp

    def log_target(self, th: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """log p (W,) and RSS (W,) per row of theta."""
        r, lp = self.residuals(th)
        return lp, np.where(np.isfinite(lp), np.einsum("wp,wp->w", r, r), np.inf)


def _problem(data: Measurements, cfg: Config) -> _Problem:
    """Set up the smooth field's posterior for `data` (see `_Problem`)."""
    b = cfg.beam
    prior = EIPrior.from_spec(cfg.prior)
    m, sd = prior.loc, prior.log_sd
    y = np.asarray(data.value, float)
    n = y.size
    loss = LocalLoss(b.length, m, sd)
    a_u, a_xx = data.weights

    def girder_at(level):
        return Girder.from_beam(b, (level,) * PIECES)

    def model_for(n_modes, girder):
        return GirderModalModel(girder, cfg.vehicle, data.x, data.t, a_u, a_xx, n_modes=n_modes)

    # level-only fit on a scan, then the mode count at that level (the girder reference's check)
    scan = m + sd * np.linspace(-6.0, 6.0, 241)
    pred = model_for(6, girder_at(math.exp(m))).predict(np.repeat(np.exp(scan)[:, None], PIECES, 1))
    rss_scan = np.sum((y - pred) ** 2, axis=1)
    lp_scan = -0.5 * ((scan - m) / sd) ** 2 - 0.5 * n * np.log(rss_scan)
    level = float(scan[int(np.argmax(lp_scan))])
    sigma_hat = float(np.sqrt(np.min(rss_scan) / n))
    n_modes = _mode_count(model_for, girder_at(math.exp(level)), level, sigma_hat, y)
    model = model_for(n_modes, girder_at(math.exp(level)))
    # curvature rows (strain gauges): their piece in the surrogate's mesh, for `curvature_factor`
    curv = np.flatnonzero((np.asarray(a_u) == 0) & (np.asarray(a_xx) != 0))
    x_c = np.asarray(data.x, float)[curv]
    piece_c = element_of(x_c, model.h, model.n_elements)[0] // (model.n_elements // PIECES)
    return _Problem(loss, y, model, curv, x_c, piece_c, (level - m) / sd, n_modes, len(scan))


def _field_posterior(data, cfg, seed, progress, t0) -> FieldPosterior:
    prob = _problem(data, cfg)
    loss, residuals, log_target, n = prob.loss, prob.residuals, prob.log_target, prob.n
    n_modes, a0, evals = prob.n_modes, prob.a0, prob.evals
    rng = seeding.rng(seed, "importance")
    bar = _progress(progress, 1 + STARTS + AMIS_MAX_ROUNDS, "smooth field")
    starts, k = _grid_starts(residuals, prob.y, a0, loss.sd, PIECES)
    evals += k
    bar.update(1)
    modes = []
    for th0 in starts:
        th, lp_map, H, k = _lm_map(residuals, n, th0)
        evals += k
        _, logdet = np.linalg.slogdet(H)
        modes.append({"theta": th, "H": H, "lap": lp_map - 0.5 * logdet})
        bar.update(1)
    modes = _distinct(modes)
    pts, logw, rss, k = amis(log_target, modes, rng, bar)
    bar.close()
    evals += k
    W = np.exp(logw - logw.max())
    W /= W.sum()
    ess = float(1.0 / np.sum(W**2))
    pick = rng.choice(W.size, size=N_DRAWS, replace=True, p=W)
    sigma = np.sqrt(rss[pick] / (2.0 * rng.gamma(n / 2.0, 1.0, size=N_DRAWS)))
    diagnostics = {
        "sampler": "adaptive importance sampling around the Laplace fits of the posterior's modes",
        "ess": ess,
        "converged": bool(ess >= ESS_MIN),
        "n_modes": int(n_modes),
        "posterior_modes": len(modes),
        "evaluations": int(evals),
    }
    nominal = cfg.model.EI_nominal or cfg.prior.EI_median
    return FieldPosterior(
        loss,
        pts[pick],
        sigma,
        float(nominal),
        diagnostics=diagnostics,
        runtime_s=time.perf_counter() - t0,
    )


def _mode_count(model_for, girder, level, sigma, y) -> int:
    """Smallest n in MODE_STEPS whose predictions at the level differ from 2 n modes' by at most
    TRUNCATION_FRACTION sigma (the girder reference's rule)."""
    tol = max(TRUNCATION_FRACTION * sigma, 1e-9 * float(np.sqrt(np.mean(y**2))))
    EI = np.full((1, PIECES), math.exp(level))
    for n in MODE_STEPS:
        if (
            np.max(np.abs(model_for(n, girder).predict(EI) - model_for(2 * n, girder).predict(EI)))
            <= tol
        ):
            return n
    return MODE_STEPS[-1]


def _progress(on: bool, total: int, desc: str):
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="step", disable=not on, leave=False)


def check_field(cfg: Config, data: Measurements) -> None:
    """Refuse, one line naming the key, what the smooth field's reference does not describe."""
    m = cfg.model
    why = "with a smooth EI field"
    if m.EI_segments != 1:
        raise InputError(
            "model.EI_segments", m.EI_segments, f"1 {why} (the field replaces segments)"
        )
    if m.supports != "pinned":
        raise InputError("model.supports", m.supports, f"'pinned' {why}")
    if m.noise != "iid":
        raise InputError("model.noise", m.noise, f"'iid' {why}")
    if cfg.infers_load_factor:
        raise InputError("vehicle.load_rel_sd", cfg.vehicle.load_rel_sd, f"0 {why}")
    if len(data) < 50:
        raise InputError("data", len(data), f"at least 50 observations {why}")
    if len(set(data.kind)) != 1:
        raise InputError("data.kind", sorted(set(data.kind)), f"one kind of measurement {why}")
