"""What a PINN fit needs to know: the girder, the axles, the data, the scales and the objective's extras.

`Problem` is the physical description (SI units, numpy); `Problem.tensors` turns it into the
non-dimensional torch tensors the loss terms use.

Scales (see `network`): L span, T duration, P the largest total load on the span at once (the sum of the
axle loads whose offsets fit within L; for both case studies all axles), U = P L^3 / (48 EI_ref) the
midspan static deflection of P at EI_ref, q = P / L the load-intensity scale of the PDE residual.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from ..config import Beam, Config, Vehicle
from ..data.measurements import Measurements
from .enrich import FreeVibration, StaticEnrichment, TiedVibration, transient_modes

#: default Gaussian delta width as a fraction of the span (beta = 0.025 L)
DEFAULT_BETA_REL = 0.025


@dataclass(frozen=True)
class Scales:
    """Non-dimensionalisation constants (SI units).

    L [m], T [s], P [N], EI_ref [N m^2], U [m] = P L^3 / (48 EI_ref), mu [kg/m].
    """

    L: float
    T: float
    P: float
    EI_ref: float
    mu: float

    @property
    def U(self) -> float:
        """Deflection scale [m]."""
        return self.P * self.L**3 / (48.0 * self.EI_ref)

    @property
    def q(self) -> float:
        """Load-intensity scale P / L [N/m] dividing the PDE residual."""
        return self.P / self.L

    @property
    def inertia(self) -> float:
        """mu U / (T^2 q): coefficient of w_tautau in the non-dimensional PDE residual [-]."""
        return self.mu * self.U / (self.T**2 * self.q)

    @property
    def time_frequency(self) -> float:
        """omega_1(EI_ref) T [rad]: the first natural circular frequency at EI_ref times T."""
        return (math.pi / self.L) ** 2 * math.sqrt(self.EI_ref / self.mu) * self.T

    @property
    def stiffness(self) -> float:
        """EI_ref U / (L^4 q) = 1/48: coefficient of (EI/EI_ref) w_xixixixi in the residual [-]."""
        return self.EI_ref * self.U / (self.L**4 * self.q)


@dataclass(frozen=True)
class Problem:
    """An inverse problem: find EI from measurements of a girder under moving axles.

    Parameters
    ----------
    beam : the girder (beam.EI is *not* used: it is the unknown)
    vehicle : the axles and speed
    data : Measurements, or a tuple of M Measurements with the same rows' kind and y (different values, e.g.
        perturbed copies for the M members of an ensemble trained together, or different sample points
        x, t: the datasets of several ensembles trained as one network)
    EI_ref : float, reference rigidity [N m^2] (the prior median); the network starts at EI_ref
    beta : float or None, Gaussian delta width [m] (paper Eq. 5); None: the training settings' beta_rel L
    noise_sd : float or None, measurement noise sd (units of the values). When given, the objective is
        *posterior-scaled*: sum over data of (r / noise_sd)^2 / 2, physics penalties scaled by the same
        factor, plus the prior term (see `losses.Objective`). A sequence gives one sd per member (members
        that belong to different datasets, trained as one network)
    anchor : None or (loc, sd): a Gaussian term 0.5 ((log EI - loc) / sd)^2 on log EI [log N m^2];
        loc may be a sequence (M,), one anchor per member
    duration : float or None, T [s]; default max(vehicle duration, last data time)
    noise_ar1 : None or rho in (-1, 1): the noise is AR(1) with coefficient rho along each sensor's series
        (`uq.ar1`), and the data term is the sum of squares of the whitened (scaled) residuals; one layout
        of the data only
    """

    beam: Beam
    vehicle: Vehicle
    data: Measurements | tuple[Measurements, ...]
    EI_ref: float = 1.0e9
    beta: float | None = None
    noise_sd: float | Sequence[float] | None = None
    anchor: tuple[float | Sequence[float], float] | None = None
    duration: float | None = None
    noise_ar1: float | None = None

    def __post_init__(self) -> None:
        data = self.data if isinstance(self.data, tuple | list) else (self.data,)
        first = data[0]
        for d in data[1:]:
            if len(d) != len(first) or not (
                np.array_equal(d.kind, first.kind) and np.array_equal(d.y, first.y, equal_nan=True)
            ):
                raise ValueError(
                    "all Measurements of a Problem must have the same number of rows of the same kinds "
                    "(kind and y per row)"
                )
        object.__setattr__(self, "data", tuple(data) if len(data) > 1 else first)
        if self.beta is not None and not (self.beta > 0 and math.isfinite(self.beta)):
            raise ValueError(f"beta must be a finite width > 0 m, got {self.beta}")
        if self.noise_sd is not None:
            sds = np.atleast_1d(np.asarray(self.noise_sd, float))
            if sds.ndim != 1 or not np.all(sds > 0) or not np.all(np.isfinite(sds)):
                raise ValueError(
                    f"noise_sd must be > 0 (or a sequence of sds > 0), got {self.noise_sd}"
                )
            if np.ndim(self.noise_sd):
                object.__setattr__(self, "noise_sd", tuple(float(v) for v in sds))
        if self.noise_ar1 is not None:
            rho = float(self.noise_ar1)
            if not (abs(rho) < 1.0):
                raise ValueError(f"noise_ar1 must lie in (-1, 1), got {self.noise_ar1}")
            if any(not np.array_equal(d.t, first.t) for d in data[1:]):
                raise ValueError(
                    "noise_ar1 needs one layout (the same sample times) for all datasets"
                )
            object.__setattr__(self, "noise_ar1", rho)
        if self.duration is None:
            T = max(self.vehicle.duration(self.beam.length), max(float(d.t.max()) for d in data))
            object.__setattr__(self, "duration", T)

    @classmethod
    def from_config(cls, cfg: Config, data: Measurements | Sequence[Measurements], **kw) -> Problem:
        """Problem for a configuration: its beam and vehicle, EI_ref = the prior median."""
        kw.setdefault("EI_ref", cfg.prior.EI_median)
        d = tuple(data) if isinstance(data, list | tuple) else data
        return cls(cfg.beam, cfg.vehicle, d, **kw)

    # ------------------------------------------------------------------ derived
    @property
    def datasets(self) -> tuple[Measurements, ...]:
        """The data as a tuple (length M_data: 1, or one per member)."""
        return self.data if isinstance(self.data, tuple) else (self.data,)

    @property
    def scales(self) -> Scales:
        L = self.beam.length
        offs, loads = self.vehicle.offsets, self.vehicle.loads
        # largest total load on the span at once: axles within a window of length L behind each axle
        P = max(float(loads[(offs >= o) & (offs <= o + L)].sum()) for o in offs)
        return Scales(L, float(self.duration), P, float(self.EI_ref), self.beam.mass_per_length)

    def row_scales(self) -> np.ndarray:
        """Per-observation value scale s_i (P,): U for deflection, 12 |y| U / L^2 for strain
        (the peak deflection and strain of P at midspan at EI_ref)."""
        sc = self.scales
        a_u, a_xx = self.datasets[0].weights
        return np.abs(a_u) * sc.U + np.abs(a_xx) * 12.0 * sc.U / sc.L**2

    def beta_for(self, beta_rel: float = DEFAULT_BETA_REL) -> float:
        """The Gaussian width [m]: `beta` if set, else beta_rel L."""
        return float(self.beta) if self.beta is not None else beta_rel * self.beam.length

    def enrichment(
        self, beta_rel: float = DEFAULT_BETA_REL, forced: bool = False
    ) -> StaticEnrichment:
        """The axles as the non-dimensional enrichment of the output layer (see `enrich`): the quasi-static
        deflection of the loads, or with ``forced`` their forced moving-load response at the current EI."""
        sc = self.scales
        return StaticEnrichment(
            loads=tuple(float(p) for p in self.vehicle.loads / sc.P),
            delays=tuple(float(d) for d in self.vehicle.delays / sc.T),
            speed=float(self.vehicle.speed * sc.T / sc.L),
            beta_rel=float(self.beta_for(beta_rel) / sc.L),
            frequency=sc.time_frequency if forced else None,
            damping=float(self.beam.damping_ratio) if forced else 0.0,
        )

    def free_vibration(
        self, modes: int, tied: bool = False, beta_rel: float = DEFAULT_BETA_REL
    ) -> FreeVibration:
        """Free vibrations of the first `modes` modes from each axle entry and exit inside [0, T) (`enrich`):
        with free amplitudes, or with ``tied`` the amplitudes the axles give them (`enrich.TiedVibration`,
        for the Gaussian loads of width ``beta_rel``)."""
        sc = self.scales
        d = self.vehicle.delays
        times = np.concatenate([d, d + self.beam.length / self.vehicle.speed]) / sc.T
        events = tuple(sorted({round(float(e), 12) for e in times if 0.0 <= e < 1.0}))
        common = dict(
            events=events,
            modes=int(modes),
            frequency=sc.time_frequency,
            damping=float(self.beam.damping_ratio),
        )
        if not tied:
            return FreeVibration(**common)
        E = self.enrichment(beta_rel)
        return TiedVibration(
            **common, loads=E.loads, delays=E.delays, speed=E.speed, beta_rel=E.beta_rel
        )

    def transient_modes(self) -> int:
        """K_v for this bridge (`enrich.transient_modes`): from its speed parameter at EI_ref."""
        E = self.enrichment()
        return transient_modes(math.pi * E.speed / self.scales.time_frequency)

    def tensors(
        self,
        members: int,
        device: str | torch.device = "cpu",
        dtype=torch.float32,
        beta_rel: float = DEFAULT_BETA_REL,
        pde_norm: str = "peak",
    ) -> ProblemTensors:
        """Non-dimensional torch tensors for M members (data broadcast when shared)."""
        sc = self.scales
        ds = self.datasets
        if len(ds) not in (1, members):
            raise ValueError(f"Problem holds {len(ds)} datasets, cannot train {members} members")
        s = self.row_scales()
        a_u, a_xx = ds[0].weights
        vals = np.stack([d.value for d in ds]) / s[None, :]
        if len(ds) == 1:
            vals = np.repeat(vals, members, axis=0)
        t = lambda a: torch.as_tensor(np.array(a, float), dtype=dtype, device=device)  # noqa: E731
        xi = np.stack([d.x for d in ds]) / sc.L  # each member's own sample points
        tau = np.stack([d.t for d in ds]) / sc.T
        if len(ds) == 1:
            xi, tau = (np.broadcast_to(a, (members, len(s))) for a in (xi, tau))
        noise = None
        if isinstance(self.noise_sd, tuple):  # one sd per member
            if len(self.noise_sd) != members:
                raise ValueError(
                    f"Problem holds {len(self.noise_sd)} noise sds, cannot train {members} members"
                )
            noise = t([0.5 * float(np.sum((s / sd) ** 2)) for sd in self.noise_sd])
        elif self.noise_sd is not None:
            noise = 0.5 * float(np.sum((s / self.noise_sd) ** 2))
        anchor = None
        if self.anchor is not None:
            loc, sd = self.anchor
            loc = np.broadcast_to(np.asarray(loc, float), (members,)) - math.log(sc.EI_ref)
            anchor = (t(loc), float(sd))
        whiten = None
        if self.noise_ar1:  # rho = 0 is the white-noise objective exactly
            from ..uq.ar1 import AR1Noise

            ar = AR1Noise.of(ds[0])
            idx = lambda a: torch.as_tensor(np.asarray(a, np.int64), device=device)  # noqa: E731
            rho = self.noise_ar1
            whiten = (idx(ar.cur), idx(ar.prev), rho, 1.0 / math.sqrt(1.0 - rho * rho))
        return ProblemTensors(
            xi=t(xi),
            tau=t(tau),
            a_u=t(a_u * sc.U / s),
            a_xx=t(a_xx * sc.U / sc.L**2 / s),
            value=t(vals),
            needs_curvature=bool(np.any(a_xx != 0)),
            needs_value=bool(np.any(a_u != 0)),
            data_scale=noise,
            anchor=anchor,
            loads=t(self.vehicle.loads / sc.P),
            delays=t(self.vehicle.delays / sc.T),
            speed=self.vehicle.speed * sc.T / sc.L,
            beta=torch.tensor(self.beta_for(beta_rel) / sc.L, dtype=dtype, device=device),
            stiffness=sc.stiffness,
            inertia=sc.inertia,
            pde_norm=pde_norm,
            whiten=whiten,
        )


@dataclass(frozen=True)
class ProblemTensors:
    """Non-dimensional data and constants on the training device.

    xi, tau : (M, P) data coordinates; a_u, a_xx : (P,) weights so that the scaled observation is
    a_u w + a_xx w_xixi; value : (M, P) scaled observed values; data_scale : None, or the factor
    0.5 sum_i (s_i / sigma)^2 that turns the mean squared scaled residual into the Gaussian negative log
    likelihood (a float, or a tensor (M,) when the members' noise sds differ); anchor : None or ((M,) loc of log(EI/EI_ref), sd); loads (J,) axle loads / P;
    delays (J,) entry times / T; speed v T / L; beta / L (a 0-d tensor, so a
    training schedule can change it in place without recompiling); stiffness = 1/48 and inertia coefficients;
    pde_norm : 'peak' (PDE residual divided by the peak Gaussian intensity) or 'load' (by q = P / L);
    whiten : None (white noise), or (current rows, previous rows, rho, 1 / sqrt(1 - rho^2)) of the AR(1)
    noise series: the data rows are whitened (`losses.whiten_rows`) before they are squared.
    """

    xi: torch.Tensor
    tau: torch.Tensor
    a_u: torch.Tensor
    a_xx: torch.Tensor
    value: torch.Tensor
    needs_curvature: bool
    needs_value: bool
    data_scale: float | torch.Tensor | None
    anchor: tuple[torch.Tensor, float] | None
    loads: torch.Tensor
    delays: torch.Tensor
    speed: float
    beta: torch.Tensor
    stiffness: float
    inertia: float
    pde_norm: str = "peak"
    whiten: tuple | None = None
