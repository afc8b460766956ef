"""Training settings: one frozen, self-validating dataclass and three named profiles.

* ``smoke``: a few seconds, for tests (small network, few points, few steps); not accurate.
* ``fast``: the default, minutes on a 2-core CPU. The paper's network (5 x 64 tanh) and loss terms
  (Eq. 10-15, 23), trained differently: variable projection (the output layer and EI solved by least
  squares at every step, `varpro`); an output layer that also carries the exact quasi-static deflection
  of the Gaussian loads and the free vibrations of the first three modes started at each axle event
  (`enrich`), each with its own free coefficient; the PDE residual in units of P / L (not of the
  Gaussian's peak); beta = 0.01 L; 100 Adam steps on a cosine schedule, the points resampled every 25
  (four point sets). EI's posterior comes from each member's exact last-layer marginal, so the steps
  only need to give the hidden layers features that hold the deflection, not to converge the fit:
  measured on the quick start (Exeter girder, 10 dB, seed 0) against its record at 600 steps resampled
  every 100, 200 steps (every 50) moved the ensemble's EI mean by +0.07 reference sd and its sd by +1.3 %,
  100 steps (every 25) by +0.07 sd and +1.1 %, and the B-PINN (from member 0's fit) by +0.24 sd and
  -3.4 %, with the ensemble's training a sixth of what it was (earlier, halving 1200 steps to 600 had
  moved the mean by 0.15 and 0.04 reference sd on that girder and on the family's bridge 9).
* ``paper``: the paper's Table 1: 5 x 64 tanh, 2500 PDE / 2000 BC / 1000 IC points, Adam for 60 000
  epochs with the quadratic schedule phi_i = (1 - (i/N)^2) phi_0 + (i/N)^2 phi_1, phi_0 = 1e-2,
  phi_1 = 0.7 phi_0, adaptive loss weights, no L-BFGS, no resampling (meant for a GPU).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace

SCHEDULES = ("paper", "cosine", "exp", "constant")
PROFILE_NAMES = ("smoke", "fast", "paper")


@dataclass(frozen=True)
class TrainSettings:
    """How one PINN fit trains.

    Attributes
    ----------
    profile : name of the profile these settings came from (informational)
    optimizer : 'adam' (every parameter by Adam, as the paper) or 'varpro' (output layer and log EI
        solved by least squares at every step, hidden layers by Adam; see `varpro`)
    width, depth : hidden-layer width and number of hidden layers
    epochs : Adam steps
    lr : phi_0, initial learning rate
    lr_final : learning rate at the last Adam step (the paper: 0.7 lr)
    schedule : 'paper' (quadratic in i/N), 'cosine', 'exp' (geometric) or 'constant'
    lr_ei_factor : learning rate of log EI relative to the network's
    n_pde, n_bc, n_ic : collocation points per member (PDE residual, supports, initial time)
    load_fraction : share of the PDE points drawn around the axle paths (0: uniform, as the paper)
    resample_every : draw fresh collocation points every this many Adam steps (0: never)
    lbfgs_iters : L-BFGS iterations after Adam (0: none), on a fixed set of points
    lbfgs_chunk : L-BFGS iterations between checkpoints / divergence checks
    weighting : 'fixed' or 'adaptive' (paper Table 1: alpha_k = L_k / min L, detached)
    w_pde, w_ic, w_bc, w_data : fixed weights of the four terms
    pde_norm : 'peak': the PDE residual is divided by the peak intensity of the Gaussian load (so it is
        O(1) at the load, and smooth errors count (beta sqrt(pi) / L)^2 less); 'load': by q = P / L
    beta_rel : Gaussian delta width beta / L (used when the Problem does not set beta)
    beta_start, beta_anneal : continuation in the Gaussian width: beta starts at beta_start times its
        value and shrinks geometrically to it over the first beta_anneal share of the Adam steps (1.0: off)
    images : Gaussian loads with their mirror images about the supports, as in the modal solution the
        bias correction uses (`losses.moving_load`); False is the paper's plain Gaussian
    correct_beta : divide the fitted EI by `beta.beta_bias_factor` (the O(beta^2) bias of the Gaussian
        load against point-load data, from the modal solution)
    hard_bc, hard_ic : exact boundary / initial conditions by construction (off: the paper's soft terms)
    time_features : add sin and cos of the first natural frequency (at the current EI) times t as
        network inputs, so the free vibration of mode 1 (about 24 cycles over a crossing of the
        Exeter girder) is representable; off in the paper profile
    oscillator : modulated output layer: the last hidden features also times sin and cos of the first
        natural frequency (at the current EI) times t (`network` module docstring), so the free
        vibration of mode 1 is representable; off in the paper profile
    enrich : static enrichment of the output layer: one more basis function, the quasi-static deflection
        of the Gaussian loads, with a free coefficient (`enrich`); off in the paper profile
    enrich_forced : the enrichment is the loads' forced moving-load response at the current EI (each mode's
        static part amplified by 1 / (1 - (alpha / n)^2)), not their quasi-static deflection: without it
        the enrichment's coefficient mistakes the first mode's amplification for flexibility and EI comes
        out low by about alpha^2 (`enrich` module docstring)
    free_modes : number of modes K whose free vibrations, started at every axle entry and exit, are output
        basis functions (`enrich.FreeVibration`; 0: none; off in the paper profile); 'auto': K_v from the
        bridge's speed parameter (`enrich.transient_modes`: 3 at alpha = 0.02, 5 at 0.2)
    tie_vibration : the free vibrations carry the amplitudes the axles give them, one column per mode
        (`enrich.TiedVibration`; needs the forced enrichment), not two free coefficients per mode and axle
        event: those are fitted to noise and widen and bias EI on trucks with many axles
    engine : 'taylor' (default), 'taylor-unfused' or 'autograd' (nested autograd, slow reference)
    compile : torch.compile the loss ('auto': on for CUDA, off for CPU; falls back to eager on failure)
    dtype : 'float32' (the paper's FP32) or 'float64'
    checkpoint_every : steps between checkpoints when a checkpoint file is given
    log_every : steps between history records
    max_log_ei : divergence guard: |log(EI / EI_ref)| beyond this counts as diverged
    """

    profile: str = "fast"
    optimizer: str = "varpro"
    width: int = 64
    depth: int = 5
    epochs: int = 100
    lr: float = 5e-3
    lr_final: float = 2e-4
    schedule: str = "cosine"
    lr_ei_factor: float = 1.0
    n_pde: int = 2000
    n_bc: int = 400
    n_ic: int = 400
    load_fraction: float = 0.3
    resample_every: int = 25
    lbfgs_iters: int = 0
    lbfgs_chunk: int = 50
    weighting: str = "fixed"
    w_pde: float = 1.0
    w_ic: float = 1.0
    w_bc: float = 1.0
    w_data: float = 1.0
    pde_norm: str = "load"
    beta_rel: float = 0.01
    beta_start: float = 1.0
    beta_anneal: float = 0.5
    images: bool = True
    correct_beta: bool = True
    hard_bc: bool = False
    hard_ic: bool = False
    time_features: bool = False
    oscillator: bool = False
    enrich: bool = True
    enrich_forced: bool = True
    free_modes: int | str = "auto"
    tie_vibration: bool = True
    engine: str = "taylor"
    compile: str | bool = "auto"
    dtype: str = "float32"
    checkpoint_every: int = 500
    log_every: int = 50
    max_log_ei: float = 3.0

    def __post_init__(self) -> None:
        pos_int = (
            "width",
            "depth",
            "n_pde",
            "n_bc",
            "n_ic",
            "lbfgs_chunk",
            "checkpoint_every",
            "log_every",
        )
        for name in pos_int:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"TrainSettings.{name}: got {v!r}, expected an integer >= 1")
        for name in ("epochs", "resample_every", "lbfgs_iters", "free_modes"):
            v = getattr(self, name)
            if name == "free_modes" and v == "auto":
                continue
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ValueError(
                    f"TrainSettings.{name}: got {v!r}, expected an integer >= 0"
                    + (" or 'auto'" if name == "free_modes" else "")
                )
        for name in (
            "lr",
            "lr_final",
            "lr_ei_factor",
            "beta_rel",
            "max_log_ei",
            "beta_start",
            "beta_anneal",
        ):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(f"TrainSettings.{name}: got {v!r}, expected a finite number > 0")
        for name in ("w_pde", "w_ic", "w_bc", "w_data"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise ValueError(f"TrainSettings.{name}: got {v!r}, expected a finite number >= 0")
        if self.beta_start < 1.0 or self.beta_anneal > 1.0:
            raise ValueError(
                f"TrainSettings.beta_start / beta_anneal: got {self.beta_start!r} / {self.beta_anneal!r}, "
                "expected beta_start >= 1 and beta_anneal in (0, 1]"
            )
        if not 0.0 <= self.load_fraction < 1.0:
            raise ValueError(
                f"TrainSettings.load_fraction: got {self.load_fraction!r}, expected a number in [0, 1)"
            )
        choices = {
            "schedule": SCHEDULES,
            "optimizer": ("adam", "varpro"),
            "weighting": ("fixed", "adaptive"),
            "engine": ("taylor", "taylor-unfused", "autograd"),
            "dtype": ("float32", "float64"),
            "compile": ("auto", True, False),
            "pde_norm": ("peak", "load"),
        }
        for name, allowed in choices.items():
            if getattr(self, name) not in allowed:
                raise ValueError(
                    f"TrainSettings.{name}: got {getattr(self, name)!r}, expected one of {allowed}"
                )
        if self.enrich and not self.images:
            raise ValueError(
                "TrainSettings.enrich: got True with images=False, expected images=True "
                "(the enrichment solves the Gaussian loads with their images)"
            )
        if self.tie_vibration and self.free_modes and not (self.enrich and self.enrich_forced):
            raise ValueError(
                "TrainSettings.tie_vibration: got True without the forced enrichment, expected "
                "enrich=True and enrich_forced=True (the tied amplitudes cancel the forced response's jumps)"
            )
        if self.n_bc < 2:
            raise ValueError(f"TrainSettings.n_bc: got {self.n_bc}, expected >= 2 (both supports)")

    @classmethod
    def for_profile(cls, name: str = "fast", **overrides) -> TrainSettings:
        """The named profile ('smoke', 'fast', 'paper'), with optional field overrides."""
        if name not in PROFILES:
            raise ValueError(
                f"unknown training profile {name!r}; expected one of {', '.join(PROFILE_NAMES)}"
            )
        return replace(PROFILES[name], **overrides)

    def learning_rate(self, i: int) -> float:
        """Adam learning rate at step i (0 <= i < epochs)."""
        N = max(self.epochs, 1)
        r = min(i / N, 1.0)
        if self.schedule == "paper":
            return (1.0 - r * r) * self.lr + r * r * self.lr_final
        if self.schedule == "cosine":
            return self.lr_final + 0.5 * (self.lr - self.lr_final) * (1.0 + math.cos(math.pi * r))
        if self.schedule == "exp":
            return self.lr * (self.lr_final / self.lr) ** r
        return self.lr

    def beta_factor(self, i: int) -> float:
        """Multiple of the final Gaussian width at Adam step i (continuation; 1 after the anneal)."""
        n = max(1.0, self.beta_anneal * self.epochs)
        return self.beta_start ** max(0.0, 1.0 - i / n)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> TrainSettings:
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in names})


PROFILES: dict[str, TrainSettings] = {
    "smoke": TrainSettings(
        profile="smoke",
        width=16,
        depth=2,
        epochs=60,
        lr=1e-2,
        lr_final=1e-3,
        n_pde=200,
        n_bc=40,
        n_ic=40,
        resample_every=20,
        lbfgs_iters=20,
        lbfgs_chunk=10,
        checkpoint_every=20,
        log_every=10,
    ),
    "fast": TrainSettings(),
    "paper": TrainSettings(
        profile="paper",
        optimizer="adam",
        width=64,
        depth=5,
        epochs=60_000,
        lr=1e-2,
        lr_final=0.7e-2,
        schedule="paper",
        n_pde=2500,
        n_bc=2000,
        n_ic=1000,
        load_fraction=0.0,
        resample_every=0,
        lbfgs_iters=0,
        weighting="adaptive",
        images=False,
        time_features=False,
        pde_norm="peak",
        oscillator=False,
        enrich=False,
        free_modes=0,
        tie_vibration=False,
        beta_rel=0.025,
        checkpoint_every=2000,
        log_every=200,
    ),
}
