"""The girder PINN on a smooth EI field (`[model] EI_field = "smooth"`): the same network, physics rows,
training and last layer as on a girder with EI per segment (`uq.girder_pinn`), with phi the field's four
coordinates instead of log EI per segment.

phi = theta = (a, u_depth, u_position, u_width), standard normal a priori, mapped to the field as the
modal reference maps it (`girder_field.LocalLoss`): EI(x) = EI_level (1 - depth exp(-(x - position)^2 /
(2 width^2))). What the girder PINN reads per segment it reads here per piece of the reference's surrogate
(`girder_field.PIECES` pieces, each the compliance average of EI(x) over it):

* the enrichment E(phi) is the reference's surrogate at phi, strain gauges read at the field's own EI at
  the gauge (`girder_field`), so E is the reference's model exactly, as on every other girder;
* the network's PDE rows carry (EI(x) N_xx)_xx through the pieces' smoothed indicators, as segments do;
* the prior is N(0, I) on phi, the start the reference's global MAP search (`field_search._grid_starts`).

Each Adam step assembles the PDE rows' Gram matrix at the current phi only (`FieldGirderProblem.
collapse`): with 48 pieces the products of every pair of pieces' rows (the segment girder's form, for any
phi at once) cost 48^2 / 5^2 times a five-segment girder's per step. The last layer builds them once.

The answer is a `FieldPosterior` of the draws of phi, summarised as the reference's is (`EI_x`,
`local_loss`, `EI` the span-averaged flexibility's equivalent).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ..config import Config
from ..data.measurements import Measurements
from ..pinn.problem import Problem
from .girder_field import (
    PIECES,
    SUB,
    SUPPORT_SD,
    FieldPosterior,
    _distinct,
    _grid_starts,
    _lm_map,
    _problem,
    check_field,
)
from .girder_logpost import ParameterLayout
from .girder_problem import GirderProblem
from .priors import EIPrior

#: names of phi's coordinates (the summary's parameter names for their diagnostics)
NAMES = ("EI_level", "depth", "position", "width")


@dataclass(frozen=True)
class _Support:
    """The prior of phi as the last layer reads it: its sds, its density, and its support (every coordinate within
    `SUPPORT_SD` prior sds, the reference's)."""

    sd: np.ndarray

    def inside(self, phi: np.ndarray) -> np.ndarray:
        """(W,) bool for phi (W, 4)."""
        return np.all(np.abs(np.atleast_2d(phi)) < SUPPORT_SD, axis=1)

    def log_prior(self, phi: np.ndarray) -> np.ndarray:
        """log N(phi; 0, I) (W,) up to a constant."""
        return -0.5 * np.sum(np.atleast_2d(phi) ** 2, axis=1)


class FieldGirderProblem(GirderProblem):
    """`GirderProblem` whose phi is a smooth field's theta (module docstring). Built once per dataset."""

    #: assemble the PDE rows' Gram matrix at one phi in training (`girder_net.pieces`)
    collapse = True

    def __init__(self, data: Measurements, cfg: Config):  # noqa: D107 - the parent's fields, set here
        check_field(cfg, data)
        self.cfg, self.data = cfg, data
        self.field = _problem(data, cfg)
        self.loss = self.field.loss
        self.S = PIECES
        self.springs = False
        self.infer_load = False
        self.layout = ParameterLayout(len(NAMES), False, False)
        self.ei_prior = EIPrior.from_spec(cfg.prior)
        self.k_prior = None
        self.load_rel_sd = None
        m = cfg.model
        self.nominal = m.EI_nominal if m.EI_nominal is not None else self.ei_prior.median
        prob = Problem.from_config(cfg, data)
        self.scales = prob.scales
        self.L, self.T = self.scales.L, self.scales.T
        self.y = np.asarray(data.value, float)
        self.a_u, self.a_xx = (np.asarray(w, float) for w in data.weights)
        f = self.field
        starts, _ = _grid_starts(f.residuals, f.y, f.a0, self.loss.sd, PIECES)
        fits = [_lm_map(f.residuals, f.n, s) for s in starts]
        self.phi0 = np.asarray(max(fits, key=lambda r: r[1])[0], float)
        # the posterior's distinct modes as the reference finds them (theta, Hessian, Laplace evidence):
        # each member's sampler starts a proposal at every one (`girder_sampling.importance_sample`)
        self.modes = _distinct(
            [
                {"theta": th, "H": H, "lap": lp - 0.5 * np.linalg.slogdet(H)[1]}
                for th, lp, H, _ in fits
            ]
        )
        r, _ = f.residuals(self.phi0[None])
        self.sigma0 = math.sqrt(float(r[0] @ r[0]) / self.y.size)
        self.n_modes = f.n_modes
        self.dim = len(NAMES)
        self.n_phys = len(NAMES)
        # what the last layer reads of the prior: its sds (the covariance's floor) and its support
        self.post = _Support(np.ones(self.dim))

    # ---- the enrichment at the data ------------------------------------------------------------------
    def enrichment(self, phys: np.ndarray) -> np.ndarray:
        """E at the data (W, n): the reference's surrogate at the field's theta (W, 4)."""
        return self.field.predict(np.atleast_2d(phys))

    # ---- prior and support -----------------------------------------------------------------------------
    def log_prior(self, phi: torch.Tensor, shift: np.ndarray | None = None) -> torch.Tensor:
        """log N(phi; shift, I) up to a constant (shift: the randomise-then-optimise anchor)."""
        c = phi if shift is None else phi - torch.as_tensor(shift, dtype=phi.dtype)
        return -0.5 * (c**2).sum()

    def inside(self, phi: np.ndarray) -> bool:
        return bool(self.post.inside(np.asarray(phi, float)[None])[0])

    # ---- the non-dimensional pieces of phi --------------------------------------------------------------
    def coefficients(self, phi: torch.Tensor):
        """(EI of each piece / EI_ref (..., PIECES), pinned support rows, load factor 1) of phi (..., 4)."""
        theta = self.ei_pieces(phi) / self.scales.EI_ref
        batch = phi.shape[:-1]
        pin = torch.tensor([1.0, 0.0], dtype=phi.dtype).expand(*batch, 2)
        return theta, pin, pin, torch.ones(batch, dtype=phi.dtype)

    def ei_pieces(self, phi: torch.Tensor) -> torch.Tensor:
        """Each piece's compliance-averaged EI [N m^2] (..., PIECES) of phi (..., 4): `LocalLoss.EI_pieces`
        in torch (differentiable)."""
        lo, hi = self.loss.width_range
        nd = torch.special.ndtr
        level = torch.exp(self.loss.m + self.loss.sd * phi[..., 0])
        depth, pos = nd(phi[..., 1]), self.loss.length * nd(phi[..., 2])
        width = lo * torch.exp(math.log(hi / lo) * nd(phi[..., 3]))
        x = (torch.arange(PIECES * SUB, dtype=phi.dtype) + 0.5) * self.loss.length / (PIECES * SUB)
        g = torch.exp(-0.5 * ((x - pos[..., None]) / width[..., None]) ** 2)
        ei = level[..., None] * (1.0 - depth[..., None] * g)
        return 1.0 / (1.0 / ei).reshape(*ei.shape[:-1], PIECES, SUB).mean(-1)

    def field_posterior(
        self, phi: np.ndarray, sigma: np.ndarray, diagnostics: dict, runtime: float
    ) -> FieldPosterior:
        """The field posterior of draws phi (N, 4) and sigma (N,)."""
        return FieldPosterior(
            self.loss,
            np.asarray(phi, float),
            np.asarray(sigma, float),
            float(self.nominal),
            diagnostics=diagnostics,
            runtime_s=runtime,
        )


def make_problem(data: Measurements, cfg: Config) -> GirderProblem:
    """The girder PINN's problem for `cfg`: a smooth field's, or EI per segment's."""
    if cfg.model.EI_field == "smooth":
        return FieldGirderProblem(data, cfg)
    return GirderProblem(data, cfg)
