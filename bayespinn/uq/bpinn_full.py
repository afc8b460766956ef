"""Full-weight B-PINN: NUTS on every hidden weight of the network, on log EI and on log sigma.

The model is the last-layer B-PINN's (`lastlayer`: the same data likelihood, the same PDE, boundary and
initial pseudo-observations with the same stated scales, the same Gaussian prior on the stiffness-scaled
output weights gamma = theta beta, the same priors on EI and sigma) with the hidden layers no longer
frozen at the deterministic fit: they get the prior of Yang, Meng & Karniadakis's B-PINNs, independent
N(0, `HIDDEN_PRIOR_SD`^2) on every weight and bias, and are sampled. Given the hidden weights every term is
still linear in the output weights, so these are integrated out exactly at each step (a collapsed
sampler: the output layer's posterior is Gaussian given the rest and is drawn exactly for predictions).
That removes the stiffest, most correlated directions from the chain without changing the posterior.

    log p(h, theta, sigma | y) = log p(y, pseudo-observations | h, theta, sigma) + log N(h; 0, s_h^2 I)
                                 + log p(EI) + log p(sigma) + c,

the first term being `LastLayer.log_marginal` of the design rows at hidden weights h (`LastLayer.rows`,
`LastLayer.with_rows`, at the same points). At h = h_fit it is the last-layer model exactly (tested).
The first mode's free vibration, where the profile has one, stays at the fitted EI like the higher modes.

Cost: each NUTS step evaluates the network's jets to fourth order at every point and back-propagates
through them and through one (H+1) x (H+1) Cholesky factorisation; a trajectory takes up to
2^max_tree_depth such steps. It runs only when asked for (`--bpinn-variant full`): every default, on a
GPU too, is the last-layer variant (`bpinn_core.resolve_variant` says why).

Measured on a 2-core CPU (float64, one gradient of the potential): paper profile (16 832 hidden weights,
2500 / 2000 / 1000 points) 0.17 s with two threads, 0.30 s with one. The paper profile's 4 x 2000
iterations of up to 2^10 - 1 steps are therefore hours to days here. A short run on the fast-profile fit of
the 20 dB must-show data (500 PDE points, 4 chains x (40 + 40) iterations, tree depth 5, 560 s) stayed
near the modal posterior (mean 0.78 modal sd below it) but was far from converged: R-hat 4.2, bulk ESS 5,
chain means 5 modal sds apart. The R-hat/ESS warning then says so. With the smoke network's loose physics
the free hidden weights let EI drift far (R-hat 2-3.5). No run long enough to converge has been made.

Measured on an H100 (torch 2.11, CUDA 13; `bayespinn run --snr 20 --method bpinn --bpinn-variant full
--device cuda --seed 11`, fast profile): the fit trains at ~20 steps/s (73 s), one gradient of the potential
takes 0.086 s (only 2x the 2-core CPU: the 5 x 64 network's fourth-order jets are many small kernels,
launch-bound), and NUTS warm-up cut its step size to 2.4e-4 within three iterations, the third taking 16 s.
At the depth-8 limit (255 gradients, ~22 s per iteration) the fast profile's 3 200 iterations are ~20 h.
`bayespinn run --snr 20 --method modal,ensemble,bpinn --profile smoke --device cuda --seed 11 --bpinn-variant
full` ended its chains with R-hat 4.5, bulk ESS 7.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from .. import seeding
from ..config import Config
from ..data.measurements import Measurements
from ..pinn.network import PINN
from ..pinn.taylor import Jet
from ..threads import torch_threads
from .bpinn_core import assemble, last_layer_map, log_shift, no_data, warm_start_fit
from .lastlayer import LastLayer
from .nuts import NUTSSettings, Whitened, nuts_health, run_nuts, sample_stats, valid_start
from .posterior import Posterior
from .priors import EIPrior, NoisePrior

log = logging.getLogger(__name__)

FULL_VARIANT = (
    "full-weight B-PINN (NUTS on every hidden weight, log EI and log sigma; output weights "
    "marginalised analytically)"
)
#: prior sd of every hidden weight and bias (B-PINNs: standard normal)
HIDDEN_PRIOR_SD = 1.0
#: hidden-weight draws kept for the posterior predictive (evenly spaced over all chains)
PREDICTIVE_DRAWS = 100


@dataclass(frozen=True)
class FullHMCSettings(NUTSSettings):
    """`nuts.NUTSSettings` with a lower maximum tree depth (a trajectory costs up to 2^depth - 1 gradients)."""

    max_tree_depth: int = 8

    @classmethod
    def for_profile(cls, profile: str) -> FullHMCSettings:
        return {"smoke": cls(4, 15, 15, 4), "fast": cls(), "paper": cls(4, 1000, 1000, 10)}[profile]


class _Basis(nn.Module):
    """The network's output-layer basis as a module call, so `torch.func.functional_call` can swap weights."""

    def __init__(self, net: PINN):
        super().__init__()
        self.net = net

    def forward(self, xi, tau, kx: int, kt: int) -> Jet:
        return self.net.basis_jet(xi, tau, kx, kt)


class FullWeight:
    """log p(y, pseudo-observations | hidden weights h, theta, sigma) with the output weights integrated out.

    ll : the last-layer model of the fit (points, scales, priors), first mode held
    net : the fitted single-member network (float64)
    device : where the jets and the linear algebra run
    """

    def __init__(self, ll: LastLayer, net: PINN, device: str | torch.device = "cpu"):
        if ll.fv is not None:
            raise ValueError(
                "the full-weight model needs a last-layer model whose first mode is held"
            )
        self.device = torch.device(device)
        self.ll = _moved(ll, self.device)
        net = net.double().to(self.device)
        fixed = {id(p) for p in net.head_parameters()} | {id(net.log_ei)}
        self.names, self.shapes, flat = [], [], []
        for n, p in net.named_parameters():
            if id(p) not in fixed:
                self.names.append("net." + n)
                self.shapes.append(p.shape)
                flat.append(p.detach().reshape(-1))
        self.h_fit = torch.cat(flat)
        self.dim = self.h_fit.numel()
        self.wrap = _Basis(net)

    def params(self, h: torch.Tensor) -> dict[str, torch.Tensor]:
        out, i = {}, 0
        for n, shp in zip(self.names, self.shapes, strict=True):
            k = math.prod(shp)
            out[n] = h[i : i + k].view(shp)
            i += k
        return out

    def jet(self, h: torch.Tensor):
        """jet(xi, tau, kx, kt) -> Jet (N, k) of the basis at hidden weights h."""
        from torch.func import functional_call

        p = self.params(h)

        def f(xi, tau, kx, kt):
            j = functional_call(self.wrap, p, (xi.unsqueeze(0), tau.unsqueeze(0), kx, kt))
            return j.map(lambda c: c[0])

        return f

    def model_at(self, h: torch.Tensor) -> LastLayer:
        """The last-layer model with the design rows of the network at hidden weights h."""
        return self.ll.with_rows(*self.ll.rows(self.jet(h)))

    def log_marginal(
        self, h: torch.Tensor, log_theta: torch.Tensor, log_sigma: torch.Tensor
    ) -> torch.Tensor:
        return self.model_at(h).log_marginal(log_theta, log_sigma)


def _moved(ll: LastLayer, device: torch.device) -> LastLayer:
    """A copy of ll with its tensors on device (the object itself when already there)."""
    import copy

    if device.type == "cpu":
        return ll
    out = copy.copy(ll)
    for k, v in vars(ll).items():
        if isinstance(v, torch.Tensor):
            setattr(out, k, v.to(device))
    return out


class _FullPotential:
    """-log posterior in whitened coordinates (v, u): hidden weights h = m + s_h v (m, s_h the hidden weights'
    prior mean and sd, so the prior term is |v|^2 / 2), and z = (log theta, log sigma) = z_map + L u (L the
    Laplace factor of the last-layer posterior, as in `nuts.Whitened`). The model's prior is m = 0,
    s_h = `HIDDEN_PRIOR_SD`; the tests also use a prior held tightly at the fit, under which this posterior
    must reduce to the last-layer one."""

    def __init__(
        self,
        fw: FullWeight,
        z_pot,
        z_map: np.ndarray,
        L: np.ndarray,
        prior_mean: torch.Tensor | None = None,
        prior_sd: float = HIDDEN_PRIOR_SD,
    ):
        self.fw, self.z_pot = fw, z_pot
        self.zw = Whitened(z_pot, z_map, L, fw.device)
        self.m = torch.zeros_like(fw.h_fit) if prior_mean is None else prior_mean.to(fw.h_fit)
        self.s_h = float(prior_sd)

    def h(self, v):
        return self.m + self.s_h * v

    def v_fit(self) -> torch.Tensor:
        return (self.fw.h_fit - self.m) / self.s_h

    def __call__(self, params: dict) -> torch.Tensor:
        v, z = params["v"], self.zw.z(params["u"])
        lt, ls = z[0], z[1]
        return -(
            self.fw.log_marginal(self.h(v), lt, ls)
            - 0.5 * (v * v).sum()
            + self.z_pot.log_prior(lt, ls)
        )


def full_nuts(pot: _FullPotential, s: FullHMCSettings, seed, progress: bool):
    """`s.chains` NUTS chains one after another, each from the fitted hidden weights and a dispersed
    (log theta, log sigma) (2 Laplace sds around the last-layer MAP), a diagonal mass matrix adapted in
    warm-up. Returns z draws (chain, draw, 2), a thinned set of hidden-weight draws (S, dim) with their z
    (S, 2), and the chains' runs (sample statistics, warnings)."""
    dev = pot.fw.device
    zs, hs, hz, runs = [], [], [], []
    keep = max(1, math.ceil(PREDICTIVE_DRAWS / s.chains))
    for c in range(s.chains):
        cs = seeding.child(seed, "pyro-full", c)
        d = torch.tensor(
            np.random.default_rng(cs).standard_normal(2), dtype=torch.float64, device=dev
        )
        u0 = valid_start(pot, d, v=pot.v_fit())
        run = run_nuts(
            pot,
            {"v": pot.v_fit(), "u": u0},
            warmup=s.warmup,
            samples=s.samples,
            seed=cs,
            full_mass=False,
            max_tree_depth=s.max_tree_depth,
            progress=progress,
        )
        smp = run.samples
        z = pot.zw.z_draws(smp["u"])
        zs.append(z)
        idx = np.linspace(0, s.samples - 1, min(keep, s.samples)).round().astype(int)
        hs.append(pot.h(smp["v"].detach()[idx]).cpu())
        hz.append(z[idx])
        runs.append(run)
    return np.stack(zs), torch.cat(hs), np.concatenate(hz), runs


def full_posterior(
    data: Measurements,
    cfg: Config,
    *,
    seed: int | np.random.SeedSequence,
    profile: str,
    device: str,
    noise: NoisePrior,
    progress: bool = False,
    fit_seed=None,
) -> Posterior:
    """Fit a PINN, then sample the full-weight B-PINN posterior (every hidden weight, log EI, log sigma)
    with NUTS, starting from the last-layer model's MAP with the first mode held."""
    t0 = time.perf_counter()
    if len(data) == 0:
        return no_data(cfg, seed, t0)
    res, problem, settings, warm = warm_start_fit(
        data, cfg, seed, profile, device, progress, fit_seed
    )
    ei_prior = EIPrior.from_spec(cfg.prior)
    shift = log_shift(res, problem)
    with torch_threads(1):  # the last-layer MAP it starts from: tiny linear algebra
        start = last_layer_map(
            res,
            problem,
            data,
            seed,
            noise,
            settings,
            ei_prior,
            shift,
            vary_first_mode=False,
            conditioned=False,  # its rows change with the hidden weights (`LastLayer.with_rows`)
        )
    draws, diag, pred, stats = sample_full(start, seed, profile, device, progress, shift)
    return assemble(
        draws,
        diag,
        pred,
        stats,
        res=res,
        shift=shift,
        ei_prior=ei_prior,
        variant="full",
        name=FULL_VARIANT,
        t0=t0,
        warm_start=warm,
    )


def sample_full(start, seed, profile: str, device: str, progress: bool, shift: float):
    """The full-weight sampler, from `bpinn_core.last_layer_map`'s (model, LastLayer with the
    first mode held, potential, MAP, Laplace factor): z draws (chain, draw, 2), diagnostics, predictor and
    the chains' sample statistics."""
    model, ll, z_pot, z_map, L = start
    fw = FullWeight(ll, model.member(0), device)
    pot = _FullPotential(fw, z_pot, z_map, L)
    s = FullHMCSettings.for_profile(profile)
    # one gradient's cost, so the log says what the chains will take
    tg = time.perf_counter()
    probe = {
        "v": pot.v_fit().requires_grad_(True),
        "u": torch.zeros(2, dtype=torch.float64, device=fw.device),
    }
    pot(probe).backward()
    g = time.perf_counter() - tg
    n_iter = s.chains * (s.warmup + s.samples)
    log.info(
        "[bpinn] NUTS: %s; %d hidden weights; one gradient %.3g s, so %d iterations take between %.3g s "
        "and %.3g s (max tree depth %d)",
        FULL_VARIANT,
        fw.dim,
        g,
        n_iter,
        n_iter * g,
        n_iter * g * (2**s.max_tree_depth - 1),
        s.max_tree_depth,
    )
    draws, h_draws, hz, runs = full_nuts(pot, s, seed, progress)
    diag = {
        "chains": s.chains,
        "warmup": s.warmup,
        "samples": s.samples,
        **nuts_health(runs),
        "hidden_weights": fw.dim,
        "hidden_prior_sd": HIDDEN_PRIOR_SD,
        "gradient_s": g,
        "pseudo_sd": {"pde": ll.s_f, "bc": ll.s_b, "ic": ll.s_i},
        "first_mode": {
            "follows_EI": False,
            "vibration_z2": ll.vibration_z2,
            "threshold": ll.vibration_threshold,
        },
    }
    pred = FullWeightPredictor(fw, h_draws, hz[:, 0], hz[:, 1], shift)
    return draws, diag, pred, sample_stats(runs)


class FullWeightPredictor:
    """Posterior predictive of the full-weight model: per kept draw (h, theta, sigma) the output weights drawn
    from their exact Gaussian conditional, then deflection, curvature or moment."""

    def __init__(
        self,
        fw: FullWeight,
        h: torch.Tensor,
        log_theta: np.ndarray,
        log_sigma: np.ndarray,
        shift: float,
    ):
        self.fw, self.h, self.lt, self.ls, self.shift = (
            fw,
            h,
            np.asarray(log_theta),
            np.asarray(log_sigma),
            shift,
        )
        self._weights: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}

    def _output_weights(self, i: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Mean and Cholesky factor of the output weights' Gaussian given kept draw i (cached: each costs the
        design rows at every point)."""
        if i not in self._weights:
            fw = self.fw
            view = fw.model_at(self.h[i].to(fw.device))
            mean, cov = view.weights_posterior(float(self.lt[i]), float(self.ls[i]))
            eye = torch.eye(fw.ll.k, dtype=torch.float64, device=fw.device)
            self._weights[i] = (mean, torch.linalg.cholesky(cov + 1e-30 * eye))
        return self._weights[i]

    def __call__(
        self, x, t, quantity: str = "deflection", n_draws: int = 200, rng=None
    ) -> np.ndarray:
        if quantity not in ("deflection", "curvature", "moment"):
            raise ValueError(f"quantity must be deflection, moment or curvature, got {quantity!r}")
        rng = rng or np.random.default_rng(0)
        fw, dev = self.fw, self.fw.device
        ll = fw.ll
        kx = 0 if quantity == "deflection" else 2
        sc = ll.sc
        T = lambda a: torch.as_tensor(np.array(a, float).ravel(), dtype=torch.float64, device=dev)  # noqa: E731
        xi, tau = T(x) / sc.L, T(t) / sc.T
        idx = rng.choice(len(self.lt), size=min(n_draws, len(self.lt)), replace=False)
        out = np.empty((idx.size, xi.numel()))
        with torch.no_grad():
            for r, i in enumerate(idx):
                mean, Lc = self._output_weights(int(i))
                Phi = fw.jet(self.h[i].to(dev))(xi, tau, kx, 0).dx(kx)
                z = torch.as_tensor(rng.standard_normal(ll.k), dtype=torch.float64, device=dev)
                out[r] = (Phi @ (mean + Lc @ z)).cpu().numpy() * sc.U / sc.L**kx
        if quantity == "moment":
            out = -np.exp(self.lt[idx] + self.shift)[:, None] * out
        return out
