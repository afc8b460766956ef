"""The girder PINN's network, physics and training (`uq.girder_pinn` explains the model; the problem it
is fitted to, `GirderProblem` with its FE enrichment, is in `uq.girder_problem`): the Gram pieces of a
network's features at its points (`pieces`), the physics and data normal equations at any parameters (`physics`,
`data_terms`), the reduced objective with the output layer profiled out (`reduced`, `solve_phi`), and the
training of one network (`train_fit`)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import torch

from .. import seeding
from ..pinn.network import PINN
from .girder_problem import GirderProblem, enrichment_column

#: pseudo-sd of the physics rows while training (non-dimensional: w in units of U, the PDE in units of
#: q = P / L): the network's correction is asked to meet the physics to 1 % of the load's scales
TRAIN_PHYSICS_SD = 1e-2
#: relative ridge of the normal equations (times each diagonal entry)
RIDGE = 1e-10


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
    is_draws: int = 800

    @classmethod
    def for_profile(cls, profile: str) -> GirderNetSettings:
        if profile == "smoke":
            return cls(16, 2, 60, 3e-3, 3e-4, 300, 40, 60, 30, 30, 200)
        if profile == "paper":
            return cls(64, 5, 2000, 2e-3, 1e-4, 2500, 400, 1000, 100, 200, 1600)
        return cls()


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
    #: KK (1, 1, D, D) and Kf (1, D) hold the PDE rows combined at one phi (`pieces`' `at`)
    collapsed: bool = False


def features(net: PINN, xi: torch.Tensor, tau: torch.Tensor, kx: int, kt: int):
    j = net.basis_jet(xi.unsqueeze(0), tau.unsqueeze(0), kx, kt)
    return j.map(lambda c: c[0])


def pieces(
    problem: GirderProblem, net: PINN, pts: Points, y: np.ndarray, at: torch.Tensor | None = None
) -> Pieces:
    """Gram pieces of `net`'s features at the data and `pts` (float64; with gradients if the net has).
    `at`: phi at which to combine the PDE rows of the segments before their products (`physics` then reads
    them at that phi only; S + 1 row blocks instead of (S + 1)^2 products, for many segments)."""
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
    if at is not None:
        theta = problem.coefficients(at)[0]
        K = torch.einsum("i,inD->nD", torch.cat([theta, torch.ones(1, dtype=dt)]), K)[None]
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
        collapsed=at is not None,
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
    a = torch.ones(1, dtype=torch.float64)
    if not P.collapsed:
        a = torch.cat([theta, a])
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


class GirderTrainer:
    """One girder network in training, a trainer of the one training loop (`pinn.train.run_steps`): each
    Adam step moves the hidden layers on the sum of squares of the scaled residuals at the output layer
    solved for them; every `theta_every` steps phi is re-solved (module docstring)."""

    def __init__(self, problem: GirderProblem, settings: GirderNetSettings, seed):
        self.problem, self.settings = problem, settings
        self.gen = torch.Generator().manual_seed(seeding.int_seed(seed))
        self.net = PINN(
            settings.width, settings.depth, members=1, generators=[self.gen], dtype=torch.float64
        )
        net = self.net
        hidden = [p for p in net.parameters() if all(p is not q for q in net.head_parameters())]
        hidden = [p for p in hidden if p is not net.log_ei]
        self.opt = torch.optim.Adam(hidden, lr=settings.lr)
        n = max(settings.steps, 1)
        r = settings.lr_final / settings.lr
        self.sched = torch.optim.lr_scheduler.LambdaLR(
            self.opt, lambda i: r + (1 - r) * 0.5 * (1 + math.cos(math.pi * min(i, n) / n))
        )
        self.sc = Scales_(
            problem.sigma0, TRAIN_PHYSICS_SD, TRAIN_PHYSICS_SD, TRAIN_PHYSICS_SD, None
        )
        self.phi = problem.phi0.copy()
        self.pts = Points.draw(settings, self.gen)
        self.loss = float("nan")
        self.step = 0

    def adam_step(self) -> None:
        problem, settings, sc, i = self.problem, self.settings, self.sc, self.step
        if i and i % settings.resample_every == 0:
            self.pts = Points.draw(settings, self.gen)
        phit = torch.as_tensor(self.phi)
        at = phit if problem.collapse else None
        P = pieces(problem, self.net, self.pts, problem.y, at)
        with torch.no_grad():
            E = enrichment_column(problem, phit)
        Ap, gp, kp = physics(problem, P, phit, sc)
        Ad, gd, kd = data_terms(problem, P, E, sc.sigma)
        G, g = Ap + Ad, gp + gd
        c, _ = _solve(G.detach(), g.detach())
        obj = c @ G @ c - 2 * c @ g + kp + kd
        self.opt.zero_grad()
        obj.backward()
        self.opt.step()
        self.sched.step()
        self.loss = float(obj.detach())
        if (i + 1) % settings.theta_every == 0 or i + 1 == settings.steps:
            with torch.no_grad():
                Pd = pieces(problem, self.net, self.pts, problem.y)
            self.phi = solve_phi(problem, _detach(Pd), self.phi, sc)
        self.step += 1

    def postfix(self) -> dict:
        return {"loss": f"{self.loss:.4g}"}


def train_fit(
    problem: GirderProblem,
    settings: GirderNetSettings,
    seed: np.random.SeedSequence,
    progress: bool = False,
) -> GirderFit:
    """Train one network's hidden layers (Adam) with the output layer and phi solved (module docstring), by
    the one training loop (`pinn.train.run_steps`; a progress bar with `progress`)."""
    from ..pinn.train import run_steps

    t0 = time.perf_counter()
    tr = GirderTrainer(problem, settings, seed)
    run_steps(tr, settings.steps, desc="girder PINN", quiet=not progress, log_every=10)
    return GirderFit(tr.net, tr.phi, time.perf_counter() - t0, tr.loss)


def _detach(P: Pieces) -> Pieces:
    return Pieces(
        **{k: (v.detach() if isinstance(v, torch.Tensor) else v) for k, v in P.__dict__.items()}
    )
