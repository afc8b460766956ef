"""The girder PINN's problem (`uq.girder_net`, `uq.girder_pinn` explains the model): the parameters phi
and their layout, their prior, the data, and the finite-element enrichment E(x, t; phi) at the data with
its derivative in phi (`GirderProblem`, `enrichment_column`). In a module of its own because it is what the
network is fitted to, apart from the network's features, normal equations and training (`uq.girder_net`).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..config import Config
from ..data.measurements import Measurements
from ..errors import InputError
from ..physics.fe_modal import GirderModalModel
from ..physics.girder import Girder
from ..pinn.problem import Problem
from .girder_logpost import GirderLogPosterior, ParameterLayout
from .girder_map import choose_girder_modes, find_map
from .priors import EIPrior

#: width of the logistic steps of the segment indicators, as a fraction of the span (the fast profile's
#: Gaussian load width beta / L: the PDE rows resolve nothing finer)
EDGE_WIDTH_REL = 0.01
#: width of the Gaussian loads in the network's PDE rows, as a fraction of the span (the fast profile's)
LOAD_WIDTH_REL = 0.01
#: log-parameter step of the central differences of the enrichment's data column
FD_STEP = 1e-4


class GirderProblem:
    """Everything a girder PINN fit needs besides the network: the layout of phi, its prior, the FE modal
    model at the data (the enrichment), the scales and the loads. Built once per dataset layout."""

    #: whether training assembles the PDE rows at the current phi only (`girder_net.pieces`' `at`): for
    #: many segments (a smooth field's pieces, `uq.field_pinn`); with a few, the products for any phi
    collapse = False

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
