"""The girder PINN's network, physics and training (`uq.girder_pinn` explains the model): the problem
(`GirderProblem`: parameter layout, prior, the FE enrichment at the data), the Gram pieces of a network's
features at its points (`pieces`), the physics and data normal equations at any parameters (`physics`,
`data_terms`), the reduced objective with the output layer profiled out (`reduced`, `solve_phi`), and the
training of one network (`train_fit`)."""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import numpy as np
import torch

from .. import seeding
from ..config import Config
from ..data.measurements import Measurements
from ..errors import InputError
from ..physics.fe_modal import GirderModalModel
from ..physics.girder import Girder
from ..pinn.network import PINN
from ..pinn.problem import Problem
from .girder_logpost import GirderLogPosterior, ParameterLayout
from .girder_map import choose_girder_modes, find_map
from .priors import EIPrior

log = logging.getLogger(__name__)

#: width of the logistic steps of the segment indicators, as a fraction of the span (the fast profile's
#: Gaussian load width beta / L: the PDE rows resolve nothing finer)
EDGE_WIDTH_REL = 0.01
#: width of the Gaussian loads in the network's PDE rows, as a fraction of the span (the fast profile's)
LOAD_WIDTH_REL = 0.01
#: pseudo-sd of the physics rows while training (non-dimensional: w in units of U, the PDE in units of
#: q = P / L): the network's correction is asked to meet the physics to 1 % of the load's scales
TRAIN_PHYSICS_SD = 1e-2
#: relative ridge of the normal equations (times each diagonal entry)
RIDGE = 1e-10
#: log-parameter step of the central differences of the enrichment's data column
FD_STEP = 1e-4


@dataclass(frozen=True)
class GirderNetSettings:
    """How the girder PINN trains: network size, Adam steps and learning rates, collocation points."""

    width: int = 32
    depth: int = 3
    steps: int = 400
    lr: float = 3e-3
    lr_final: float = 2e-4
    n_pde: int = 1000
    n_bc: int = 100
    n_ic: int = 200
    resample_every: int = 100
    theta_every: int = 100
    is_samples: int = 4000
    is_draws: int = 800

    @classmethod
    def for_profile(cls, profile: str) -> GirderNetSettings:
        if profile == "smoke":
            return cls(16, 2, 60, 3e-3, 3e-4, 300, 40, 60, 30, 30, 1000, 200)
        if profile == "paper":
            return cls(64, 5, 2000, 2e-3, 1e-4, 2500, 400, 1000, 100, 200, 8000, 1600)
        return cls()


# --------------------------------------------------------------------------------------------------
# the problem: parameters, prior, enrichment, points


class GirderProblem:
    """Everything a girder PINN fit needs besides the network: the layout of phi, its prior, the FE modal
    model at the data (the enrichment), the scales and the loads. Built once per dataset layout."""

    def __init__(self, data: Measurements, cfg: Config):
        if len(set(np.asarray(data.kind).tolist())) != 1:
            raise InputError(
                "data.kind", sorted(set(data.kind.tolist())), "one kind (one noise sd)"
            )
        self.cfg, self.data = cfg, data
        m = cfg.model
        self.S = m.EI_segments
        self.springs = m.supports == "springs"
        self.infer_load = cfg.infers_load_factor
        self.layout = ParameterLayout(self.S, self.springs, self.infer_load)
        self.ei_prior = EIPrior.from_spec(cfg.prior)
        self.k_prior = (cfg.prior.k_median, cfg.prior.k_log_sd) if self.springs else None
        self.load_rel_sd = cfg.vehicle.load_rel_sd if self.infer_load else None
        self.nominal = m.EI_nominal if m.EI_nominal is not None else self.ei_prior.median
        prob = Problem.from_config(cfg, data)
        self.scales = sc = prob.scales
        self.L, self.T = sc.L, sc.T
        self.y = np.asarray(data.value, float)
        self.a_u, self.a_xx = (np.asarray(w, float) for w in data.weights)
        # the enrichment-only fit: the FE model at the prior centre, then re-referenced at its optimum
        self.post = self._log_posterior(self._template(None), 6)
        phi = find_map(self.post)
        sigma = math.sqrt(float(self.post.rss(phi)[0]) / self.y.size)
        tmpl = self._template(phi)
        n_modes, _ = choose_girder_modes(
            tmpl, cfg.vehicle, data, self._log_posterior(tmpl, 6), phi, sigma
        )
        self.n_modes = n_modes
        self.post = self._log_posterior(tmpl, n_modes)
        self.phi0 = find_map(self.post, starts=[phi])
        self.sigma0 = math.sqrt(float(self.post.rss(self.phi0)[0]) / self.y.size)
        self.dim = self.layout.dim
        # the modal model predicts with the load factor; E is at factor 1 (its coefficient carries lambda)
        self.n_phys = self.S + 2 * self.springs

    def _template(self, phi: np.ndarray | None) -> Girder:
        b = self.cfg.beam
        if phi is None:
            ei = [self.ei_prior.median] * self.S
            ks = [self.cfg.prior.k_median] * 2 if self.springs else [0.0, 0.0]
        else:
            ei = np.exp(phi[: self.S]).tolist()
            ks = np.exp(phi[self.layout.springs]).tolist() if self.springs else [0.0, 0.0]
        return Girder(
            b.length,
            tuple(float(e) for e in ei),
            b.mass_per_length,
            b.section_depth,
            damping_ratio=b.damping_ratio,
            rotational_stiffness=tuple(float(k) for k in ks),
        )

    def _log_posterior(self, tmpl: Girder, n_modes: int) -> GirderLogPosterior:
        model = GirderModalModel(
            tmpl,
            self.cfg.vehicle,
            self.data.x,
            self.data.t,
            self.a_u,
            self.a_xx,
            n_modes=n_modes,
            infer_springs=self.springs,
        )
        return GirderLogPosterior(
            model, self.y, self.layout, self.ei_prior, self.k_prior, self.load_rel_sd
        )

    # ---- the enrichment at the data ------------------------------------------------------------------
    def enrichment(self, phys: np.ndarray) -> np.ndarray:
        """E at the data (W, n) for physical parameters (W, n_phys) (log EI per segment, log springs), load
        factor 1."""
        phys = np.atleast_2d(phys)
        EI = np.exp(phys[:, : self.S])
        ks = np.exp(phys[:, self.S : self.S + 2]) if self.springs else None
        return self.post.model.predict(EI, ks, None)

    # ---- prior in torch --------------------------------------------------------------------------------
    def log_prior(self, phi: torch.Tensor, shift: np.ndarray | None = None) -> torch.Tensor:
        """log p(phi) up to a constant (`GirderLogPosterior.log_prior`), its Gaussian coordinates' centre
        moved by `shift` (the randomise-then-optimise anchor)."""
        loc = torch.as_tensor(self.post.loc, dtype=phi.dtype)
        sd = torch.as_tensor(self.post.sd, dtype=phi.dtype)
        g = self.S + 2 * self.springs
        if shift is not None:
            loc = loc + torch.as_tensor(shift, dtype=phi.dtype) * sd
        out = -0.5 * (((phi[:g] - loc[:g]) / sd[:g]) ** 2).sum()
        if self.infer_load:
            ll = phi[self.layout.load]
            c = 0.0 if shift is None else float(shift[self.layout.load]) * self.load_rel_sd
            out = out - 0.5 * ((torch.exp(ll) - 1.0 - c) / self.load_rel_sd) ** 2 + ll
        return out

    def inside(self, phi: np.ndarray) -> bool:
        return bool(self.post.inside(phi[None])[0])

    # ---- the non-dimensional pieces of phi --------------------------------------------------------------
    def coefficients(self, phi: torch.Tensor):
        """(theta (..., S) = EI_s / EI_ref, (alpha, beta) (..., 2) of the left and right moment rows, lambda
        (...)) of phi (..., dim)."""
        EI_ref = self.scales.EI_ref
        theta = torch.exp(phi[..., : self.S]) / EI_ref
        batch = phi.shape[:-1]
        if self.infer_load:
            lam = torch.exp(phi[..., self.layout.load])
        else:
            lam = torch.ones(batch, dtype=phi.dtype)
        if self.springs:
            kap = torch.exp(phi[..., self.layout.springs]) * (self.L / EI_ref)
            # theta_1 w'' - kappa_L w' = 0 (left), theta_S w'' + kappa_R w' = 0 (right), normalised
            t0, tS = theta[..., 0], theta[..., -1]
            left = torch.stack([t0, -kap[..., 0]], -1) / (t0 + kap[..., 0])[..., None]
            right = torch.stack([tS, kap[..., 1]], -1) / (tS + kap[..., 1])[..., None]
        else:
            pin = torch.tensor([1.0, 0.0], dtype=phi.dtype).expand(*batch, 2)
            left = right = pin
        return theta, left, right, lam

    def chi(self, xi: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Smoothed segment indicators and their first two xi-derivatives, each (S, N); they sum to 1, 0, 0."""
        S, d = self.S, EDGE_WIDTH_REL
        N = xi.shape[-1]
        if S == 1:
            one = torch.ones(1, N, dtype=xi.dtype)
            return one, torch.zeros_like(one), torch.zeros_like(one)
        edges = torch.arange(1, S, dtype=xi.dtype)[:, None] / S
        h = torch.sigmoid((xi[None, :] - edges) / d)  # (S-1, N) steps up at each interior edge
        h1 = h * (1 - h) / d
        h2 = h * (1 - h) * (1 - 2 * h) / d**2
        pad = lambda a, v: torch.cat([torch.full((1, N), v, dtype=xi.dtype), a], 0)  # noqa: E731
        padz = lambda a: torch.cat([a, torch.zeros(1, N, dtype=xi.dtype)], 0)  # noqa: E731
        H, H1, H2 = pad(h, 1.0), pad(h1, 0.0), pad(h2, 0.0)  # (S, N): step before segment s
        return H - padz(h), H1 - padz(h1), H2 - padz(h2)

    def load(self, xi: torch.Tensor, tau: torch.Tensor) -> torch.Tensor:
        """f / q at (xi, tau) (N,): Gaussian loads of width `LOAD_WIDTH_REL` L on the axles' paths, stated
        loads (load factor 1)."""
        v = self.cfg.vehicle
        sc = self.scales
        a = (v.speed * (sc.T * tau[:, None] - torch.as_tensor(v.delays, dtype=tau.dtype))) / sc.L
        live = (a >= 0) & (a <= 1)
        b = LOAD_WIDTH_REL
        g = torch.exp(-(((xi[:, None] - a) / b) ** 2)) / (b * math.sqrt(math.pi))
        P = torch.as_tensor(v.loads / sc.P, dtype=tau.dtype)
        return (g * live * P).sum(-1)


class _EColumn(torch.autograd.Function):
    """The enrichment's data column E(phys) (n,) with its Jacobian by central differences (batched)."""

    @staticmethod
    def forward(ctx, phys: torch.Tensor, problem: GirderProblem, want_grad: bool):
        p = phys.detach().cpu().numpy().astype(float)
        k = p.size
        if not want_grad:
            return torch.from_numpy(problem.enrichment(p)[0])
        pts = np.vstack([p, p + FD_STEP * np.eye(k), p - FD_STEP * np.eye(k)])
        out = problem.enrichment(pts)
        ctx.save_for_backward(torch.from_numpy((out[1 : k + 1] - out[k + 1 :]) / (2 * FD_STEP)))
        return torch.from_numpy(out[0])

    @staticmethod
    def backward(ctx, g):
        (J,) = ctx.saved_tensors
        return J @ g, None, None


def enrichment_column(problem: GirderProblem, phi: torch.Tensor) -> torch.Tensor:
    phys = phi[: problem.n_phys]
    return _EColumn.apply(phys, problem, bool(phi.requires_grad))


# --------------------------------------------------------------------------------------------------
# features at the points, and their Gram pieces


@dataclass
class Points:
    """Non-dimensional collocation points (float64): PDE (xi, tau), the supports' times, initial xi."""

    pde: tuple[torch.Tensor, torch.Tensor]
    bc_tau: torch.Tensor
    ic_xi: torch.Tensor

    @classmethod
    def draw(cls, s: GirderNetSettings, gen: torch.Generator) -> Points:
        r = lambda n: torch.rand(n, generator=gen, dtype=torch.float64)  # noqa: E731
        return cls((r(s.n_pde), r(s.n_pde)), r(s.n_bc), r(s.n_ic))


@dataclass
class Pieces:
    """Gram pieces of the network's features (D = width + 1 columns) for every term, from which
    `assemble` builds the normal equations at any phi. Differentiable in the features when they are."""

    dd: torch.Tensor  # (D, D)  data: Phi_d' Phi_d
    dy: torch.Tensor  # (D,)    Phi_d' y
    yy: torch.Tensor  # ()
    Phi_d: torch.Tensor  # (n, D), for Phi_d' E(phi)
    KK: (
        torch.Tensor
    )  # (S + 1, S + 1, D, D)  PDE: X_i' X_j (X_s = stiffness rows of segment s, X_S inertia)
    Kf: torch.Tensor  # (S + 1, D)  X_i' f
    ff: torch.Tensor  # ()
    vv: torch.Tensor  # (D, D)  support values, both ends
    mm: torch.Tensor  # (2, 2, 2, D, D)  per end: [w_xixi, w_xi]' [w_xixi, w_xi]
    ic: torch.Tensor  # (D, D)  initial value and rate
    counts: dict


def features(net: PINN, xi: torch.Tensor, tau: torch.Tensor, kx: int, kt: int):
    j = net.basis_jet(xi.unsqueeze(0), tau.unsqueeze(0), kx, kt)
    return j.map(lambda c: c[0])


def pieces(problem: GirderProblem, net: PINN, pts: Points, y: np.ndarray) -> Pieces:
    """Gram pieces of `net`'s features at the data and `pts` (float64; with gradients if the net has)."""
    sc = problem.scales
    dt = torch.float64
    d = problem.data
    xi_d = torch.as_tensor(d.x / sc.L, dtype=dt)
    tau_d = torch.as_tensor(d.t / sc.T, dtype=dt)
    strain = bool(np.any(problem.a_xx != 0))
    jd = features(net, xi_d, tau_d, 2 if strain else 0, 0)
    a_u = torch.as_tensor(problem.a_u, dtype=dt)[:, None]
    a_xx = torch.as_tensor(problem.a_xx, dtype=dt)[:, None]
    Phi_d = sc.U * (a_u * jd.value + (a_xx / sc.L**2) * jd.dx(2) if strain else a_u * jd.value)
    yt = torch.as_tensor(y, dtype=dt)
    # PDE rows
    xi, tau = pts.pde
    jp = features(net, xi, tau, 4, 2)
    chi, chi1, chi2 = problem.chi(xi)
    S_c = sc.stiffness
    X = [
        S_c
        * (
            chi[s][:, None] * jp.dx(4)
            + 2 * chi1[s][:, None] * jp.dx(3)
            + chi2[s][:, None] * jp.dx(2)
        )
        for s in range(problem.S)
    ]
    X.append(sc.inertia * jp.dt(2))
    K = torch.stack(X)  # (S + 1, n_f, D)
    f = problem.load(xi, tau)
    # supports and initial state
    nb = pts.bc_tau.numel()
    vv, mm = 0.0, []
    for end in (0.0, 1.0):
        jb = features(net, torch.full((nb,), end, dtype=dt), pts.bc_tau, 2, 0)
        vv = vv + jb.value.T @ jb.value
        Mb = torch.stack([jb.dx(2), jb.dx(1)])  # (2, nb, D)
        mm.append(torch.einsum("anD,bnE->abDE", Mb, Mb))
    ji = features(net, pts.ic_xi, torch.zeros_like(pts.ic_xi), 0, 1)
    ic = ji.value.T @ ji.value + ji.dt(1).T @ ji.dt(1)
    return Pieces(
        dd=Phi_d.T @ Phi_d,
        dy=Phi_d.T @ yt,
        yy=yt @ yt,
        Phi_d=Phi_d,
        KK=torch.einsum("inD,jnE->ijDE", K, K),
        Kf=torch.einsum("inD,n->iD", K, f),
        ff=f @ f,
        vv=vv,
        mm=torch.stack(mm),
        ic=ic,
        counts={"data": len(y), "pde": xi.numel(), "bc": 2 * nb, "ic": pts.ic_xi.numel()},
    )


@dataclass(frozen=True)
class Scales_:
    """The terms' sds: data sigma (SI), PDE, support and initial rows (non-dimensional), weight prior."""

    sigma: float | torch.Tensor
    s_f: float
    s_b: float
    s_i: float
    s_w: float | None  # None: no weight prior (training)


def physics(problem: GirderProblem, P: Pieces, phi: torch.Tensor, sc: Scales_):
    """The physics rows' normal equations over (c, c_E) at phi: (A_p, g_p, k_p), their sum of squares being
    c'A_p c - 2 c'g_p + k_p (the weight prior included when `sc.s_w` is set)."""
    theta, left, right, lam = problem.coefficients(phi)
    D = P.dd.shape[0]
    # PDE: sum_i a_i X_i c + f (c_E - lambda), a = (theta, 1)
    a = torch.cat([theta, torch.ones(1, dtype=torch.float64)])
    Gnn = torch.einsum("i,j,ijDE->DE", a, a, P.KK)
    Gne = torch.einsum("i,iD->D", a, P.Kf)
    sf2 = sc.s_f**2
    A = (
        torch.cat([torch.cat([Gnn, Gne[:, None]], 1), torch.cat([Gne, P.ff[None]])[None, :]], 0)
        / sf2
    )
    g = lam * torch.cat([Gne, P.ff[None]]) / sf2
    k = lam**2 * P.ff / sf2
    # supports and initial state (the network's part only: the enrichment meets them exactly)
    Gb = P.vv + torch.einsum("a,b,abDE->DE", left, left, P.mm[0])
    Gb = Gb + torch.einsum("a,b,abDE->DE", right, right, P.mm[1])
    pad = torch.zeros(D + 1, D + 1, dtype=torch.float64)
    pad[:D, :D] = Gb / sc.s_b**2 + P.ic / sc.s_i**2
    A = A + pad
    if sc.s_w is not None:
        A = A + torch.eye(D + 1, dtype=torch.float64) / sc.s_w**2
    return A, g, k


def data_terms(problem: GirderProblem, P: Pieces, E: torch.Tensor, sigma, y=None, dy=None, yy=None):
    """The data rows' normal equations over (c, c_E): (A_d, g_d, k_d) for rows [U Phi_d, E] / sigma; `y`, `dy`
    = Phi_d' y, `yy` = y'y replace the measured data (a perturbed copy)."""
    y = torch.as_tensor(problem.y, dtype=torch.float64) if y is None else y
    dy = P.dy if dy is None else dy
    yy = P.yy if yy is None else yy
    s2 = sigma**2
    dE = P.Phi_d.T @ E
    A = torch.cat([torch.cat([P.dd, dE[:, None]], 1), torch.cat([dE, (E @ E)[None]])[None, :]], 0)
    return A / s2, torch.cat([dy, (E @ y)[None]]) / s2, yy / s2


def _solve(G: torch.Tensor, g: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(c, Cholesky factor) of G c = g, with a tiny ridge relative to each diagonal entry (the columns' scales
    differ by many orders: the enrichment's against the network's high derivatives)."""
    d = G.diagonal().detach().clamp_min(1e-300)
    for k in range(6):
        L, info = torch.linalg.cholesky_ex(G + torch.diag(RIDGE * 100.0**k * d))
        if int(info) == 0:
            break
    else:
        raise torch.linalg.LinAlgError("girder PINN: normal equations not positive definite")
    c = torch.cholesky_solve(g[:, None], L)[:, 0]
    return c, L


def reduced(problem, P, phi, sc, y=None, dy=None, yy=None, xi=None) -> torch.Tensor:
    """min over (c, c_E) of the data's scaled sum of squares plus the physics' excess over its own minimum at
    phi, (c - mu_p)' A_p (c - mu_p), mu_p = A_p^-1 g_p (differentiable in phi). The physics' own minimum (how
    well the network can meet the equations at phi) is left out: it says how well the features fit the
    equations, not what the data say about phi (`GirderLastLayer.log_marginal`). `xi` (D + 1,) moves mu_p by
    A_p^-1/2 xi: the output layer's prior draw of randomise-then-optimise."""
    E = enrichment_column(problem, phi)
    Ap, gp, _ = physics(problem, P, phi, sc)
    Ad, gd, kd = data_terms(problem, P, E, sc.sigma, y, dy, yy)
    mu, Lp = _solve(Ap, gp)
    if xi is not None:
        xi = torch.as_tensor(xi, dtype=torch.float64)
        mu = mu + torch.linalg.solve_triangular(Lp.T, xi[:, None], upper=True)[:, 0]
        gp = gp + Lp @ xi
    c, _ = _solve(Ap + Ad, gp + gd)
    return kd + mu @ gp - (gp + gd) @ c


def solve_phi(
    problem, P, phi0, sc, shift=None, y=None, dy=None, yy=None, xi=None, iters: int = 50
) -> np.ndarray:
    """phi minimising the reduced objective minus twice the log prior (anchored at `shift`), by L-BFGS."""
    phi = torch.tensor(phi0, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.LBFGS([phi], lr=1.0, max_iter=iters, line_search_fn="strong_wolfe")
    best = [None, math.inf]

    def closure():
        opt.zero_grad()
        if not problem.inside(phi.detach().numpy()):
            v = torch.as_tensor(math.inf, dtype=torch.float64)
            return v
        v = reduced(problem, P, phi, sc, y, dy, yy, xi) - 2.0 * problem.log_prior(phi, shift)
        v.backward()
        if float(v.detach()) < best[1]:
            best[:] = [phi.detach().clone().numpy(), float(v.detach())]
        return v

    opt.step(closure)
    return best[0] if best[0] is not None else np.asarray(phi0, float)


# --------------------------------------------------------------------------------------------------
# training one network


@dataclass
class GirderFit:
    """One trained network: its weights (float64 state), phi at the end, the points it ended on."""

    net: PINN
    phi: np.ndarray
    seconds: float
    loss: float


def train_fit(
    problem: GirderProblem,
    settings: GirderNetSettings,
    seed: np.random.SeedSequence,
    progress: bool = False,
) -> GirderFit:
    """Train one network's hidden layers (Adam) with the output layer and phi solved (module docstring)."""
    t0 = time.perf_counter()
    gen = torch.Generator().manual_seed(seeding.int_seed(seed))
    net = PINN(settings.width, settings.depth, members=1, generators=[gen], dtype=torch.float64)
    hidden = [p for p in net.parameters() if all(p is not q for q in net.head_parameters())]
    hidden = [p for p in hidden if p is not net.log_ei]
    opt = torch.optim.Adam(hidden, lr=settings.lr)
    n = max(settings.steps, 1)
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt,
        lambda i: (
            (settings.lr_final / settings.lr)
            + (1 - settings.lr_final / settings.lr) * 0.5 * (1 + math.cos(math.pi * min(i, n) / n))
        ),
    )
    sc = Scales_(problem.sigma0, TRAIN_PHYSICS_SD, TRAIN_PHYSICS_SD, TRAIN_PHYSICS_SD, None)
    phi = problem.phi0.copy()
    pts = Points.draw(settings, gen)
    loss = float("nan")
    for i in range(settings.steps):
        if i and i % settings.resample_every == 0:
            pts = Points.draw(settings, gen)
        P = pieces(problem, net, pts, problem.y)
        phit = torch.as_tensor(phi)
        with torch.no_grad():
            E = enrichment_column(problem, phit)
        Ap, gp, kp = physics(problem, P, phit, sc)
        Ad, gd, kd = data_terms(problem, P, E, sc.sigma)
        G, g = Ap + Ad, gp + gd
        c, _ = _solve(G.detach(), g.detach())
        obj = c @ G @ c - 2 * c @ g + kp + kd
        opt.zero_grad()
        obj.backward()
        opt.step()
        sched.step()
        loss = float(obj.detach())
        if (i + 1) % settings.theta_every == 0 or i + 1 == settings.steps:
            with torch.no_grad():
                Pd = pieces(problem, net, pts, problem.y)
            phi = solve_phi(problem, _detach(Pd), phi, sc)
        if progress and (i + 1) % max(1, settings.steps // 10) == 0:
            log.debug("[girder-pinn] step %d/%d  loss %.4g", i + 1, settings.steps, loss)
    return GirderFit(net, phi, time.perf_counter() - t0, loss)


def _detach(P: Pieces) -> Pieces:
    return Pieces(
        **{k: (v.detach() if isinstance(v, torch.Tensor) else v) for k, v in P.__dict__.items()}
    )
