"""B-PINN in Pyro: NUTS on (log EI, log sigma) of a last-layer Bayesian PINN.

The variant (after Yang, Meng & Karniadakis's B-PINNs, with the linear output layer integrated out
analytically, see `lastlayer`): a deterministic PINN fit (the one training loop) provides the hidden
features; the output weights get a Gaussian prior and are marginalised exactly; the data likelihood
is Gaussian with unknown sigma; PDE, boundary and initial residuals enter as Gaussian pseudo-observations
with stated scales. Pyro's NUTS samples the two remaining parameters through a `potential_fn` (no
tracing per step), several chains from a dispersed start around the MAP; ArviZ gives R-hat and ESS, and
`nuts` the divergences, tree depths and warnings, all of which decide whether the run counts as converged.

This is the fast default. `bpinn_full` samples every hidden weight too (the same model with the hidden
layers free); `resolve_variant` picks it for the paper profile, `--bpinn-variant` chooses
explicitly, and the summary's `info.variant` names the one that ran.
"""

from __future__ import annotations

import logging
import math
import time
import warnings
from dataclasses import dataclass

import numpy as np
import torch

from .. import seeding
from ..config import Config
from ..data.measurements import Measurements
from ..threads import torch_threads
from .lastlayer import LastLayer
from .nuts import nuts_health, problems, run_nuts
from .posterior import Posterior, mcmc_diagnostics
from .priors import EIPrior, NoisePrior

log = logging.getLogger(__name__)

VARIANT = "last-layer B-PINN (output weights marginalised analytically; NUTS on log EI, log sigma)"
#: `--bpinn-variant` choices; 'auto' is `resolve_variant`'s rule
VARIANTS = ("auto", "last-layer", "full")


def resolve_variant(name: str, profile: str) -> str:
    """'last-layer' or 'full': 'auto' runs the full-weight sampler (`bpinn_full`) for the paper profile, the
    last-layer one otherwise, on a GPU too.

    The device does not decide it: measured on an H100 (fast profile, 20 dB), one gradient of the full
    potential took 0.086 s (0.17 s on the 2-core CPU; the small 5 x 64 network's fourth-order jets are
    launch-bound, not arithmetic-bound) and NUTS warm-up cut its step size to 2.4e-4, the third iteration taking
    16 s, so the fast profile's 3 200 iterations would take hours on a GPU as well (~20 h at the tree-depth
    limit); the fast profile promises minutes."""
    if name not in VARIANTS:
        raise ValueError(f"B-PINN variant must be one of {', '.join(VARIANTS)}, got {name!r}")
    if name != "auto":
        return name
    return "full" if profile == "paper" else "last-layer"


#: EI counts as identified when the posterior sd of log EI is below this fraction of the prior's
IDENTIFIED_FRACTION = 0.5


@dataclass(frozen=True)
class NUTSSettings:
    chains: int = 4
    warmup: int = 300
    samples: int = 500
    max_tree_depth: int = 10  # Pyro's and Stan's default: up to 1023 leapfrog steps per iteration

    @classmethod
    def for_profile(cls, profile: str) -> NUTSSettings:
        return {"smoke": cls(4, 60, 60), "fast": cls(), "paper": cls(4, 1000, 1000)}[profile]


def identified(log_ei_draws: np.ndarray, prior: EIPrior) -> bool:
    """Do the data move EI away from its prior? (posterior sd of log EI < half the prior sd)"""
    return bool(np.std(log_ei_draws) < IDENTIFIED_FRACTION * prior.log_sd)


class _Potential:
    """-log posterior of z = (log theta, log sigma); theta = EI / EI_ref before the beta correction."""

    def __init__(self, ll: LastLayer, ei_prior: EIPrior, noise: NoisePrior, log_shift: float):
        self.ll, self.ei_prior, self.noise, self.shift = ll, ei_prior, noise, log_shift

    def log_ei(self, log_theta):
        return log_theta + self.shift

    def log_prior(self, lt, ls):
        """log p(EI) + log p(sigma) in (log theta, log sigma), up to a constant."""
        lp = -0.5 * ((self.log_ei(lt) - self.ei_prior.loc) / self.ei_prior.log_sd) ** 2
        if self.noise.kind == "snr":
            lp = lp - 0.5 * ((ls - math.log(self.noise.center)) / self.noise.log_sd) ** 2
        # vague: log-uniform sigma, constant density; its bounds lie far outside any posterior mass
        return lp

    def __call__(self, params: dict) -> torch.Tensor:
        z = params["z"]
        lt, ls = z[0], z[1]
        return -(self.ll.log_marginal(lt, ls) + self.log_prior(lt, ls))


def _map(pot: _Potential, z0: np.ndarray) -> np.ndarray:
    z = torch.tensor(z0, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.LBFGS(
        [z], lr=1.0, max_iter=200, line_search_fn="strong_wolfe", tolerance_grad=1e-10
    )

    def closure():
        opt.zero_grad()
        v = pot({"z": z})
        v.backward()
        return v

    opt.step(closure)
    return z.detach().numpy()


def _laplace_factor(pot: _Potential, z: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor of the Laplace covariance (inverse Hessian) at the MAP; a diagonal fallback of
    0.1 when the Hessian is not positive definite there."""
    zt = torch.tensor(z, dtype=torch.float64)
    H = torch.autograd.functional.hessian(lambda v: pot({"z": v}), zt).numpy()
    try:
        return np.linalg.cholesky(np.linalg.inv(0.5 * (H + H.T)))
    except np.linalg.LinAlgError:
        log.warning(
            "[bpinn] the posterior's Hessian at the MAP is not positive definite; NUTS starts unscaled"
        )
        return np.diag([0.1, 0.1])


class _Whitened:
    """The potential in whitened coordinates u, z = z_map + L u (L the Laplace factor; constant Jacobian).

    In z the posterior of (log theta, log sigma) can be very narrow and correlated (sds of 1e-3 or less with
    clean or low-noise data), so NUTS with a unit mass matrix starts at a tiny step size and the maximum tree
    depth until its mass-matrix windows catch up (measured: 2.7 s per iteration at the clean level); in u it
    is about a unit Gaussian from the first step."""

    def __init__(
        self, pot: _Potential, z_map: np.ndarray, L: np.ndarray, device: str | torch.device = "cpu"
    ):
        self.pot = pot
        self.z_map = torch.tensor(z_map, dtype=torch.float64, device=device)
        self.L = torch.tensor(L, dtype=torch.float64, device=device)

    def z(self, u):
        return self.z_map + self.L @ u

    def z_draws(self, u: torch.Tensor) -> np.ndarray:
        """Draws of z (n, 2) from draws of u (n, 2)."""
        return (self.z_map[None, :] + u.detach().to(torch.float64) @ self.L.T).cpu().numpy()

    def __call__(self, params: dict) -> torch.Tensor:
        return self.pot({"z": self.z(params["u"])})


#: dispersion of the chains' starts, in Laplace sds around the MAP, tried in turn until the potential is finite
START_SCALES = (2.0, 1.0, 0.5, 0.25, 0.0)


def valid_start(pot, direction: torch.Tensor, key: str = "u", **fixed) -> torch.Tensor:
    """The first of `START_SCALES` * direction where the whitened potential is finite (a chain cannot start
    where the density is zero or undefined, e.g. far out on an improper posterior's flank)."""
    for k in START_SCALES:
        u = k * direction
        try:
            with torch.no_grad():
                ok = bool(torch.isfinite(pot({key: u, **fixed})))
        except torch.linalg.LinAlgError:
            ok = False
        if ok:
            return u
    raise RuntimeError(
        "the B-PINN posterior cannot be evaluated even at its MAP: the last-layer model is "
        "degenerate for these data"
    )


def nuts(pot: _Potential, z_map: np.ndarray, L: np.ndarray, s: NUTSSettings, seed, progress: bool):
    """Run `s.chains` NUTS chains (one after another, each on its own seed) on the whitened potential, each
    from a dispersed start (2 Laplace sds around the MAP); draws of z (chain, draw, 2) and the chains' runs
    (sample statistics, warnings)."""
    wpot = _Whitened(pot, z_map, L)
    out, runs = [], []
    for c in range(s.chains):
        cs = seeding.child(seed, "pyro", c)
        u0 = valid_start(
            wpot, torch.tensor(np.random.default_rng(cs).standard_normal(2), dtype=torch.float64)
        )
        run = run_nuts(
            wpot,
            {"u": u0},
            warmup=s.warmup,
            samples=s.samples,
            seed=cs,
            full_mass=True,
            max_tree_depth=s.max_tree_depth,
            progress=progress,
        )
        out.append(wpot.z_draws(run.samples["u"]))
        runs.append(run)
    return np.stack(out), runs


def bpinn_posterior(
    data: Measurements,
    cfg: Config,
    *,
    seed: int | np.random.SeedSequence,
    opts,
    noise: NoisePrior,
) -> Posterior:
    """Fit a PINN, then sample the last-layer B-PINN posterior of (EI, sigma) with NUTS."""
    from ..pinn import Problem, TrainSettings, fit

    t0 = time.perf_counter()
    if len(data) == 0:
        from .modal_mcmc import prior_only

        log.warning("[bpinn] no measurements: EI is not identified, returning the prior")
        return prior_only(EIPrior.from_spec(cfg.prior), seed, t0, method="bpinn")
    settings = TrainSettings.for_profile(opts.profile)
    problem = Problem.from_config(cfg, data)
    log.info("[bpinn] deterministic warm-start fit (%s profile)", opts.profile)
    res = fit(
        problem,
        settings,
        seed=seeding.stream(seed, "init"),
        device=opts.device,
        quiet=not opts.progress,
    )
    return _sample(res, problem, data, cfg, seed, opts, noise, settings, t0)


def _sample(res, problem, data, cfg, seed, opts, noise, settings, t0) -> Posterior:
    ei_prior = EIPrior.from_spec(cfg.prior)
    # EI = EI_ref theta / beta_factor
    shift = math.log(problem.EI_ref) - math.log(res.beta_factor)
    variant = resolve_variant(opts.bpinn_variant, opts.profile)
    if variant == "full":
        from .bpinn_full import FULL_VARIANT, sample_full

        with torch_threads(1):  # the last-layer MAP it starts from: tiny linear algebra
            start = last_layer_map(
                res, problem, data, seed, noise, settings, ei_prior, shift, vary_first_mode=False
            )
        draws, diag, pred = sample_full(start, seed, opts, shift)
        name = FULL_VARIANT
    else:
        with torch_threads(1):  # tiny linear algebra (see `threads`)
            draws, diag, pred = _sample_last_layer(
                res, problem, data, seed, opts, noise, settings, ei_prior, shift
            )
        name = VARIANT
    log_ei = draws[:, :, 0] + shift
    EI, sigma = np.exp(log_ei), np.exp(draws[:, :, 1])
    diag = {**mcmc_diagnostics(EI), **diag}
    trouble = problems(diag)
    converged = not trouble
    if not converged:
        msg = "B-PINN NUTS did not converge: " + "; ".join(trouble)
        warnings.warn(msg, RuntimeWarning, stacklevel=2)
        diag["problems"] = trouble
    ident = identified(log_ei.ravel(), ei_prior)
    diag.update(
        converged=converged,
        fit_EI=float(res.EI),
        fit_runtime_s=res.runtime_s,
        beta_factor=res.beta_factor,
    )
    info = {"variant": name, "identified": ident}
    if not ident:
        info["note"] = "EI is not identified by these data"
    if variant == "last-layer":
        # self-check: the last-layer posterior linearises around the fit; it must stay near it
        moved = abs(float(log_ei.mean()) - math.log(res.EI)) / max(float(log_ei.std()), 1e-12)
        diag["moved_from_fit_sd"] = moved
        if moved > MAX_MOVE_SD:
            msg = (
                f"the last-layer posterior (EI mean {float(EI.mean()):.4g} N m^2) lies {moved:.1f} posterior sd "
                f"from the PINN fit it is built on ({float(res.EI):.4g} N m^2): the network has not learnt the "
                "physics well enough for this approximation, so this interval is not trustworthy"
            )
            warnings.warn("B-PINN: " + msg, RuntimeWarning, stacklevel=2)
            info["warnings"] = [msg]
    return Posterior(
        "bpinn",
        EI,
        sigma,
        diagnostics=diag,
        info=info,
        runtime_s=time.perf_counter() - t0,
        predictor=pred,
    )


def last_layer_map(
    res, problem, data, seed, noise, settings, ei_prior, shift, vary_first_mode=None
):
    """The fit's last-layer model, its potential in (log theta, log sigma), the MAP there and the Laplace
    factor: (model, LastLayer, potential, z_map, L)."""
    model = res.model("cpu")
    rng = np.random.default_rng(seeding.stream(seed, "collocation"))
    ll = LastLayer(
        model,
        0,
        problem,
        data,
        rng,
        n_pde=settings.n_pde,
        n_bc=settings.n_bc,
        n_ic=settings.n_ic,
        beta_rel=settings.beta_rel,
        images=settings.images,
        vary_first_mode=vary_first_mode,
    )
    pot = _Potential(ll, ei_prior, noise, shift)
    sigma0 = max(math.sqrt(ll.fit_rss / max(ll.n, 1)), noise.low * 10)
    z_map = _map(pot, np.array([math.log(ll.theta_fit), math.log(sigma0)]))
    return model, ll, pot, z_map, _laplace_factor(pot, z_map)


def _sample_last_layer(res, problem, data, seed, opts, noise, settings, ei_prior, shift):
    """NUTS on (log theta, log sigma) of the last-layer model: z draws (chain, draw, 2), diagnostics, predictor."""
    _, ll, pot, z_map, L = last_layer_map(
        res, problem, data, seed, noise, settings, ei_prior, shift
    )
    log.info("[bpinn] NUTS: %s", VARIANT)
    s = NUTSSettings.for_profile(opts.profile)
    draws, runs = nuts(pot, z_map, L, s, seed, opts.progress)
    diag = {
        "chains": s.chains,
        "warmup": s.warmup,
        "samples": s.samples,
        **nuts_health(runs),
        "pseudo_sd": {"pde": ll.s_f, "bc": ll.s_b, "ic": ll.s_i},
        "first_mode": {
            "follows_EI": ll.first_mode_varies,
            "vibration_z2": ll.vibration_z2,
            "threshold": ll.vibration_threshold,
        },
    }
    pred = LastLayerPredictor(ll, draws[:, :, 0].ravel(), draws[:, :, 1].ravel(), shift)
    return draws, diag, pred


#: a last-layer posterior further than this many of its own sds from the fit it linearises is flagged
MAX_MOVE_SD = 3.0


class LastLayerPredictor:
    """Posterior predictive of a last-layer model: deflection, curvature or moment for (EI, sigma) draws."""

    def __init__(self, ll: LastLayer, log_theta: np.ndarray, log_sigma: np.ndarray, shift: float):
        self.ll, self.lt, self.ls, self.shift = ll, log_theta, log_sigma, shift

    def __call__(
        self, x, t, quantity: str = "deflection", n_draws: int = 200, rng=None
    ) -> np.ndarray:
        rng = rng or np.random.default_rng(0)
        idx = rng.choice(self.lt.size, size=min(n_draws, self.lt.size), replace=False)
        if quantity == "deflection":
            return self.ll.predictive(x, t, 0, self.lt[idx], self.ls[idx], rng)
        if quantity in ("curvature", "moment"):
            k = self.ll.predictive(x, t, 2, self.lt[idx], self.ls[idx], rng)
            return -np.exp(self.lt[idx] + self.shift)[:, None] * k if quantity == "moment" else k
        raise ValueError(f"quantity must be deflection, moment or curvature, got {quantity!r}")
