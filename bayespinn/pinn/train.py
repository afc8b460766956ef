"""The one PINN training loop: every method that trains a PINN calls `fit`.

Adam (with the chosen learning-rate schedule and collocation resampling), then an optional L-BFGS polish
on a fixed set of points. M members can train together as one batched network (`members=M`); their
objectives are independent and summed. Deterministic on the CPU for a given seed and thread count:
each member draws its initial weights and collocation points from its own torch.Generator, made from
the seed (a numpy SeedSequence or an int); nothing global is seeded.

Checkpointing: with ``checkpoint=path`` the state (weights, optimiser, generators, points, history) is
written atomically every ``settings.checkpoint_every`` steps and at the end; a later call with the same
path and ``resume=True`` continues from it and ends with the same numbers as an uninterrupted run.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..errors import TrainingDiverged
from .beta import beta_bias_factor
from .losses import TERMS, Objective, field_jets, prior_term, terms_from_jets
from .network import PINN
from .problem import Problem
from .sampling import Collocation, sample_collocation
from .settings import TrainSettings
from .taylor import contract_jet
from .varpro import head_system, solve_head

log = logging.getLogger(__name__)

CHECKPOINT_SCHEMA = "bayespinn.pinn.checkpoint/1"
#: varpro: the golden-section bracket for log EI around its current value, per step
VARPRO_HALF_WIDTH = 0.25
#: varpro: the final head and EI solve uses this many times the training's collocation points
FINAL_POINTS = 4


@dataclass
class FitResult:
    """The outcome of `fit`.

    Attributes
    ----------
    EI : float (single network) or array (M,) (``members=M``): estimated flexural rigidity [N m^2],
        divided by the Gaussian-delta bias factor when ``settings.correct_beta``
    EI_raw : same shape, exp(log_ei) EI_ref before the beta correction [N m^2]
    beta_factor : float, the bias factor used (1.0 when not corrected); an array (G,) for a fit of G seeds
    losses : dict term -> float or array (M,): final pde, ic, bc, data (+ prior) terms and 'total'
    history : dict of arrays: 'step' (R,), 'lr' (R,), each term and 'total' (R, M), 'EI_raw' (R, M)
    state : dict, the trained PINN's state_dict (CPU tensors); `model()` rebuilds the network
    runtime_s : wall time of this call [s] (plus that of the interrupted run when resumed)
    steps : Adam steps + L-BFGS iterations done
    settings : TrainSettings
    members : M, or None for a single network
    problem : Problem the fit solved
    """

    EI: float | np.ndarray
    EI_raw: float | np.ndarray
    beta_factor: float | np.ndarray
    losses: dict[str, Any]
    history: dict[str, np.ndarray]
    state: dict
    runtime_s: float
    steps: int
    settings: TrainSettings
    members: int | None
    problem: Problem = field(repr=False)

    def model(self, device: str | torch.device = "cpu") -> PINN:
        """The trained network (all members), in eval mode on `device`."""
        net = _build_model(self.problem, self.settings, self.members or 1)
        net.load_state_dict(self.state)
        return net.to(device).eval()

    def predict(self, x: np.ndarray, t: np.ndarray, kx: int = 0) -> np.ndarray:
        """Deflection u [m] (kx = 0) or curvature u_xx [1/m] (kx = 2) at x [m], t [s] (P,) -> (M, P) or (P,)."""
        sc = self.problem.scales
        net = self.model()
        M = self.members or 1
        dt = _dtype(self.settings.dtype)
        xi = torch.tensor(np.broadcast_to(np.asarray(x, float) / sc.L, (M, np.size(x))), dtype=dt)
        tau = torch.tensor(np.broadcast_to(np.asarray(t, float) / sc.T, (M, np.size(t))), dtype=dt)
        with torch.no_grad():
            j = net.jet(xi, tau, kx, 0)
        out = j.dx(kx).double().numpy() * sc.U / sc.L**kx
        return out if self.members else out[0]


def _build_model(problem: Problem, s: TrainSettings, members: int, generators=None) -> PINN:
    tf = problem.scales.time_frequency if s.time_features else None
    osc = problem.scales.time_frequency if s.oscillator else None
    extras = []
    if s.enrich:
        extras.append(problem.enrichment(s.beta_rel, forced=s.enrich_forced))
    if s.free_modes:
        K = problem.transient_modes() if s.free_modes == "auto" else s.free_modes
        extras.append(problem.free_vibration(K, tied=s.tie_vibration, beta_rel=s.beta_rel))
    return PINN(
        s.width,
        s.depth,
        members=members,
        generators=generators,
        hard_bc=s.hard_bc,
        hard_ic=s.hard_ic,
        time_frequency=tf,
        oscillator=osc,
        extras=extras,
        dtype=_dtype(s.dtype),
    )


def _dtype(name: str) -> torch.dtype:
    return torch.float64 if name == "float64" else torch.float32


def _member_seeds(
    seed: int | np.random.SeedSequence, members: int, first: int = 0
) -> list[tuple[int, int]]:
    """(init seed, collocation seed) for members first .. first + members - 1: member m's streams depend
    on (seed, m) only."""
    root = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(int(seed))
    out = []
    for m in range(first, first + members):
        key = tuple(root.spawn_key) + (m,)
        s = [
            np.random.SeedSequence(root.entropy, spawn_key=key + (k,)).generate_state(2, np.uint64)
            for k in (0, 1)
        ]
        out.append(tuple(int(a[0] >> np.uint64(1)) for a in s))
    return out


def _seeds(seed, members: int, first: int = 0) -> list[tuple[int, int]]:
    """Member seeds of a fit: `_member_seeds` of one seed, or, for a list of G seeds (G independent
    ensembles trained as one network of G x k members), the k members of each seed in turn."""
    if not isinstance(seed, list | tuple):
        return _member_seeds(seed, members, first)
    G = len(seed)
    if G < 1 or members % G:
        raise ValueError(f"{members} members cannot be split evenly over {G} seeds")
    return [s for g in seed for s in _member_seeds(g, members // G, first)]


def _resolve_device(device: str | torch.device) -> torch.device:
    if str(device) == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(device)


def _want_compile(settings: TrainSettings, device: torch.device) -> bool:
    if settings.compile == "auto":
        return device.type == "cuda"
    return bool(settings.compile) and settings.engine != "autograd"


class _Trainer:
    """State of one fit: network, points, optimisers. `fit` drives it."""

    def __init__(
        self,
        problem: Problem,
        s: TrainSettings,
        seed,
        members: int,
        device: torch.device,
        first_member: int = 0,
    ):
        self.problem, self.s, self.M, self.device = problem, s, members, device
        self.dtype = _dtype(s.dtype)
        seeds = _seeds(seed, members, first_member)
        init_gens = [torch.Generator().manual_seed(a) for a, _ in seeds]
        self.col_gens = [torch.Generator().manual_seed(b) for _, b in seeds]
        self.model = _build_model(problem, s, members, init_gens).to(device)
        self.beta = problem.beta_for(s.beta_rel)
        self.pt = problem.tensors(
            members, device, self.dtype, beta_rel=s.beta_rel, pde_norm=s.pde_norm
        )
        self.varpro = s.optimizer == "varpro"
        if self.varpro and s.engine == "autograd":
            raise ValueError("optimizer 'varpro' needs a Taylor engine")
        self.compiled = _want_compile(s, device)
        self._set_engine(s.engine)
        head_params = self.model.head_parameters()
        head = {id(p) for p in head_params} | {id(self.model.log_ei)}
        self.hidden = [p for p in self.model.parameters() if id(p) not in head]
        if self.varpro:
            groups = [{"params": self.hidden}]
        else:
            groups = [
                {"params": self.hidden + head_params},
                {"params": [self.model.log_ei], "lr_factor": s.lr_ei_factor},
            ]
        # on a GPU one fused kernel updates every parameter (launches, not arithmetic, bound the step)
        fused = {"fused": True} if device.type == "cuda" else {}
        self.adam = torch.optim.Adam(groups, lr=s.lr, **fused)
        self.lbfgs: torch.optim.LBFGS | None = None
        self.col: Collocation | None = None
        self.prev_terms: dict | None = None
        self.step = 0
        self.history: dict[str, list] = {k: [] for k in ("step", "lr", "total", "EI_raw", *TERMS)}
        self.elapsed = 0.0

    def _set_engine(self, engine: str) -> None:
        s = self.s
        if self.compiled and engine == "taylor":
            engine = "taylor-unfused"  # inductor fuses the plain formulas better than the custom Function
        self.objective = Objective(
            s.weighting, s.w_pde, s.w_ic, s.w_bc, s.w_data, engine=engine, images=s.images
        )
        fn = self._basis if self.varpro else self._eval
        if self.compiled:
            try:
                fn = torch.compile(fn, dynamic=False)
            except Exception as exc:  # pragma: no cover - depends on the installation
                log.warning("torch.compile unavailable (%s); training eagerly", exc)
                self.compiled = False
        self._fn = fn

    def _call(self, col: Collocation):
        try:
            return self._fn(col)
        except Exception as exc:
            if not self.compiled:
                raise
            log.warning(
                "torch.compile failed (%s: %s); falling back to eager", exc.__class__.__name__, exc
            )
            self.compiled = False
            self._set_engine(self.s.engine)
            return self._fn(col)

    # ------------------------------------------------------------------ pieces
    def sample(self, factor: int = 1) -> Collocation:
        """Fresh collocation points from the members' generators (``factor`` times the usual counts)."""
        s, pt = self.s, self.pt
        col = sample_collocation(
            self.col_gens,
            factor * s.n_pde,
            factor * s.n_bc,
            factor * s.n_ic,
            load_fraction=s.load_fraction,
            speed=pt.speed,
            delays=pt.delays,
            beta=float(pt.beta),
        )
        return col.to(self.device, self.dtype)

    def _eval(self, col: Collocation):
        terms = self.objective.terms(self.model, self.pt, col)
        total, per = self.objective.total(terms, self.pt)
        return total, per, terms

    def _basis(self, col: Collocation):
        return field_jets(self.model, self.pt, col, self.objective.engine, basis=True)

    def loss(self, col: Collocation, solve: bool = True, exact_frequency: bool = False):
        """(total, per-member totals (M,), terms). In varpro mode the head and log EI are first solved
        (unless ``solve=False``) and written into the model; with ``exact_frequency`` the free vibrations
        are evaluated at every EI the solve tries (`varpro.VaryingColumns`)."""
        if not self.varpro:
            return self._call(col)
        basis = self._call(col)
        model, pt = self.model, self.pt
        if solve:
            posterior = pt.data_scale is not None
            prev = self.prev_terms if self.s.weighting == "adaptive" else None
            weights = (
                self.objective.weights(prev, posterior)
                if prev is not None
                else (
                    self.objective.weights(
                        {k: torch.ones(self.M, device=self.device) for k in TERMS}, posterior
                    )
                    if self.s.weighting == "adaptive"
                    else self.objective.weights({}, posterior)
                )
            )
            vary = model.free_vibration if exact_frequency else None
            system = head_system(basis, pt, col, weights, self.objective.images, vary=vary)
            c, sol = solve_head(
                system,
                model.log_ei.detach(),
                half_width=VARPRO_HALF_WIDTH,
                s_max=self.s.max_log_ei,
                data_scale=pt.data_scale,
                anchor=pt.anchor,
            )
            model.set_head(c.to(self.dtype))
            with torch.no_grad():
                model.log_ei.copy_(sol.to(self.dtype))
            if vary is not None:  # the frequency moved with EI: the basis at the solved EI
                basis = self._call(col)
        c = model.head.detach()
        jets = {k: contract_jet(j, c) for k, j in basis.items()}
        terms = terms_from_jets(jets, model.EI_ratio.detach(), pt, col, self.objective.images)
        if pt.anchor is not None:
            terms["prior"] = prior_term(model.log_ei.detach(), pt)
        total, per = self.objective.total(terms, pt)
        self.prev_terms = {k: v.detach() for k, v in terms.items()}
        return total, per, terms

    def guard(self, total: torch.Tensor, where: str) -> None:
        # one device-to-host read per step (a GPU waits for each): every check as one tensor
        lei = self.model.log_ei.detach()
        finite = torch.stack(
            [torch.isfinite(total).all()]
            + [torch.isfinite(p).all() for p in self.model.parameters()]
        ).all()
        far = (lei.abs() > self.s.max_log_ei).any()
        if bool(far | ~finite):
            bad = not bool(finite)
            what = (
                f"non-finite loss or parameter (loss = {float(total):.3g})"
                if bad
                else f"log(EI/EI_ref) = {lei.cpu().numpy().round(3).tolist()} beyond +-{self.s.max_log_ei}"
            )
            exc = TrainingDiverged(f"PINN training diverged at step {self.step} ({where}): {what}")
            exc.step = self.step
            raise exc

    def record(self, lr: float, total_per: torch.Tensor, terms: dict) -> None:
        h = self.history
        h["step"].append(self.step)
        h["lr"].append(lr)
        h["total"].append(total_per.detach().cpu().double().numpy())
        for k in TERMS:
            h[k].append(terms[k].detach().cpu().double().numpy())
        h["EI_raw"].append(self.EI_raw())

    def EI_raw(self) -> np.ndarray:
        return self.problem.EI_ref * np.exp(self.model.log_ei.detach().cpu().double().numpy())

    # ------------------------------------------------------------------ phases
    def set_beta(self, factor: float) -> None:
        """Set the Gaussian width used by the loss to factor * beta (continuation)."""
        self.pt.beta.fill_(factor * self.beta / self.problem.scales.L)

    def adam_step(self) -> None:
        s = self.s
        if s.beta_start > 1.0:
            self.set_beta(s.beta_factor(self.step))
        if self.col is None or (s.resample_every and self.step % s.resample_every == 0):
            self.col = self.sample()
        lr = s.learning_rate(self.step)
        for g in self.adam.param_groups:
            g["lr"] = lr * g.get("lr_factor", 1.0)
        self.adam.zero_grad(set_to_none=True)
        total, per, terms = self.loss(self.col)
        self.guard(total.detach(), "Adam")
        total.backward()
        self.adam.step()
        if self.step % s.log_every == 0:
            self.record(lr, per, terms)
        self.step += 1

    def _make_lbfgs(self) -> torch.optim.LBFGS:
        params = self.hidden if self.varpro else list(self.model.parameters())
        return torch.optim.LBFGS(
            params,
            lr=1.0,
            history_size=50,
            tolerance_grad=0.0,
            tolerance_change=0.0,
            line_search_fn="strong_wolfe",
        )

    def lbfgs_chunk(self, n: int) -> None:
        self.set_beta(1.0)
        if self.lbfgs is None:
            self.col = self.sample()
            self.lbfgs = self._make_lbfgs()
        for g in self.lbfgs.param_groups:
            g["max_iter"] = n
            g["max_eval"] = int(n * 1.25)

        last = {"f": None}

        def closure():
            self.lbfgs.zero_grad(set_to_none=True)
            total, per, terms = self.loss(self.col)
            if bool(torch.isfinite(total)):
                total.backward()
                last["f"] = float(total.detach())
                return total
            # a trial step the loss cannot be evaluated at: report a much larger finite loss so the strong-Wolfe
            # line search backs off (a NaN there ends in an IndexError inside torch, an inf in a NaN step)
            f0 = last["f"] if last["f"] is not None else 1.0
            return torch.tensor(abs(f0) * 1e6 + 1e6, dtype=total.dtype, device=total.device)

        self.lbfgs.step(closure)
        total, per, terms = self.loss(
            self.col
        )  # (with grad: no_grad would make torch.compile recompile)
        self.guard(total.detach(), "L-BFGS")
        self.step += n
        self.record(0.0, per, terms)

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict:
        return {
            "schema": CHECKPOINT_SCHEMA,
            "settings": self.s.to_dict(),
            "members": self.M,
            "step": self.step,
            "model": self.model.state_dict(),
            "adam": self.adam.state_dict(),
            "lbfgs": None if self.lbfgs is None else self.lbfgs.state_dict(),
            "col_gens": [g.get_state() for g in self.col_gens],
            "col": None if self.col is None else tuple(tuple(a.cpu() for a in p) for p in self.col),
            "history": self.history,
            "elapsed": self.elapsed,
        }

    def load_state_dict(self, st: dict) -> None:
        if (
            st.get("schema") != CHECKPOINT_SCHEMA
            or st["settings"] != self.s.to_dict()
            or st["members"] != self.M
        ):
            raise ValueError("checkpoint was written by a fit with different settings or members")
        self.model.load_state_dict(st["model"])
        self.adam.load_state_dict(st["adam"])
        for g, state in zip(self.col_gens, st["col_gens"], strict=True):
            g.set_state(state)
        self.col = (
            None if st["col"] is None else Collocation(*st["col"]).to(self.device, self.dtype)
        )
        self.step, self.history, self.elapsed = st["step"], st["history"], st["elapsed"]
        if st["lbfgs"] is not None:
            self.lbfgs = self._make_lbfgs()
            self.lbfgs.load_state_dict(st["lbfgs"])

    def save(self, path: Path) -> None:
        tmp = path.with_name(f".{path.name}.tmp")
        torch.save(self.state_dict(), tmp)
        os.replace(tmp, path)


def fit(
    problem: Problem,
    settings: TrainSettings | str | None = None,
    seed: int | np.random.SeedSequence = 0,
    *,
    members: int | None = None,
    device: str | torch.device = "cpu",
    quiet: bool = False,
    checkpoint: str | Path | None = None,
    resume: bool = True,
    init_state: dict | None = None,
    callback: Callable[[int, dict], None] | None = None,
    first_member: int = 0,
) -> FitResult:
    """Train a PINN (or M of them together) on a problem and return the EI estimate.

    Parameters
    ----------
    problem : Problem, the girder, axles, (possibly perturbed) data, EI_ref and optional noise sd /
        anchor (posterior-scaled objective, see `losses`)
    settings : TrainSettings, or a profile name ('smoke', 'fast', 'paper'); default 'fast'
    seed : int or numpy SeedSequence; member m uses independent streams derived from (seed, m). A list of
        G seeds trains G independent ensembles of M / G members each as one network (the members of
        seed g are members g M/G .. (g+1) M/G - 1 and draw their streams from (seed g, m)); each gets
        its own beta correction (``beta_factor`` is then an array (G,))
    members : None for one network (scalar results) or M >= 1 to train M members together as one
        batched network (array results of shape (M,)); member m starts from the same weights and draws
        the same points as a single fit with the same seed would for m = 0
    device : 'cpu', 'cuda' or 'auto'
    quiet : no progress bar
    checkpoint : file to save the state to (and resume from, with ``resume=True``)
    init_state : a state_dict to start from (e.g. `FitResult.state` of an earlier fit) instead of the
        seeded initial weights
    callback : called as callback(step, info) after each Adam step / L-BFGS chunk, info holding
        'phase' ('adam' or 'lbfgs'), 'EI_raw' (M,) and 'model' (the PINN being trained); an exception raised by it stops the fit (the checkpoint stays)
    first_member : the index of the first member trained: ``fit(..., members=1, first_member=m)`` trains
        member m of a ``members=M`` fit on its own (its initial weights and points; how the ensemble
        spreads members over processes)

    Returns
    -------
    FitResult

    Raises
    ------
    TrainingDiverged : a non-finite loss or parameter, or log(EI/EI_ref) beyond settings.max_log_ei;
        the message and the exception's ``step`` attribute name the step.
    """
    if settings is None or isinstance(settings, str):
        settings = TrainSettings.for_profile(settings or "fast")
    M = 1 if members is None else int(members)
    if M < 1:
        raise ValueError(f"members must be >= 1, got {members}")
    dev = _resolve_device(device)
    t0 = time.perf_counter()
    if first_member < 0:
        raise ValueError(f"first_member must be >= 0, got {first_member}")
    tr = _Trainer(problem, settings, seed, M, dev, first_member)
    if init_state is not None:
        tr.model.load_state_dict(init_state)
    path = Path(checkpoint) if checkpoint is not None else None
    if path is not None and resume and path.exists():
        tr.load_state_dict(torch.load(path, map_location=dev, weights_only=False))
        log.info("resumed PINN fit from %s at step %d", path, tr.step)
    s = settings
    n_total = s.epochs + s.lbfgs_iters
    elapsed0 = tr.elapsed

    def save_now():
        if path is not None:
            tr.elapsed = elapsed0 + time.perf_counter() - t0
            tr.save(path)

    from tqdm.auto import tqdm

    bar = tqdm(
        total=n_total,
        initial=min(tr.step, n_total),
        disable=quiet,
        desc="PINN",
        unit="step",
        leave=False,
        dynamic_ncols=True,
    )
    try:
        while tr.step < s.epochs:
            tr.adam_step()
            bar.update(1)
            if tr.step % s.log_every == 0 or tr.step == s.epochs:
                bar.set_postfix(
                    EI=f"{np.median(tr.EI_raw()):.4g}",
                    loss=f"{tr.history['total'][-1].sum():.3g}",
                    refresh=False,
                )
            if path is not None and tr.step % s.checkpoint_every == 0:
                save_now()
            if callback is not None:
                callback(tr.step, {"phase": "adam", "EI_raw": tr.EI_raw(), "model": tr.model})
        while tr.step < n_total:
            n = min(s.lbfgs_chunk, n_total - tr.step)
            tr.lbfgs_chunk(n)
            bar.update(n)
            save_now()
            if callback is not None:
                callback(tr.step, {"phase": "lbfgs", "EI_raw": tr.EI_raw(), "model": tr.model})
    finally:
        bar.close()
    # final losses at the final Gaussian width; varpro re-solves the head and EI for the final hidden layers
    # on a fresh point set FINAL_POINTS times the usual size, so that the estimate does not hinge on the
    # last (smaller) set the optimiser saw
    tr.set_beta(1.0)
    if tr.col is None or (tr.varpro and s.epochs > 0):
        tr.col = tr.sample(FINAL_POINTS if tr.varpro else 1)
        if tr.compiled:  # a compiled loss is specialised to the point counts
            tr.compiled = False
            tr._set_engine(s.engine)
    total, per, terms = tr.loss(tr.col, exact_frequency=tr.varpro)
    tr.guard(total.detach(), "final")
    losses = {k: terms[k].detach().cpu().double().numpy() for k in terms}
    losses["total"] = per.detach().cpu().double().numpy()
    save_now()
    EI_raw = tr.EI_raw()
    groups = len(seed) if isinstance(seed, list | tuple) else 1
    factors = np.ones(groups)
    if s.correct_beta:  # per ensemble: at its members' median, for its own sample points
        ds = problem.datasets
        for g, part in enumerate(np.split(EI_raw, groups)):
            d = ds[g * len(ds) // groups] if len(ds) > 1 else ds[0]
            factors[g] = beta_bias_factor(
                problem.beam, problem.vehicle, d, tr.beta, EI=float(np.median(part))
            )
    EI = EI_raw / np.repeat(factors, M // groups)
    factor = float(factors[0]) if groups == 1 else factors
    hist = {k: np.asarray(v) for k, v in tr.history.items()}
    runtime = elapsed0 + time.perf_counter() - t0
    single = members is None
    squeeze = (
        (lambda a: float(np.asarray(a).reshape(-1)[0])) if single else (lambda a: np.asarray(a))
    )  # noqa: E731
    log.debug(  # one line per network fit: shown with --verbose
        "PINN fit: EI = %s N m^2 (raw %s, beta factor %s) in %.1f s",
        np.round(EI, 0),
        np.round(EI_raw, 0),
        np.round(factor, 6),
        runtime,
    )
    return FitResult(
        EI=squeeze(EI),
        EI_raw=squeeze(EI_raw),
        beta_factor=factor,
        losses={k: squeeze(v) for k, v in losses.items()},
        history=hist,
        state={k: v.detach().cpu().clone() for k, v in tr.model.state_dict().items()},
        runtime_s=runtime,
        steps=tr.step,
        settings=s,
        members=members,
        problem=problem,
    )


#: networks measured by `networks_per_batch` to learn a member's memory
PROBE_NETWORKS = 8


def networks_per_batch(
    problem: Problem, settings: TrainSettings, device: str | torch.device, fraction: float = 0.5
) -> int:
    """How many networks of `settings` on `problem` train as one on a CUDA device: `fraction` of its free
    memory over a member's peak, measured by one eager training step and the final (larger) evaluation of
    `PROBE_NETWORKS` members. Anywhere else there is no device memory to fill: returns 2**31 - 1."""
    from dataclasses import replace

    dev = _resolve_device(device)
    if dev.type != "cuda":
        return 2**31 - 1
    torch.cuda.synchronize(dev)
    torch.cuda.empty_cache()
    free, _ = torch.cuda.mem_get_info(dev)
    before = torch.cuda.memory_allocated(dev)
    torch.cuda.reset_peak_memory_stats(dev)
    tr = _Trainer(problem, replace(settings, compile=False), 0, PROBE_NETWORKS, dev)
    tr.adam_step()
    tr.set_beta(1.0)
    tr.loss(tr.sample(FINAL_POINTS if tr.varpro else 1), exact_frequency=tr.varpro)
    torch.cuda.synchronize(dev)
    per = (torch.cuda.max_memory_allocated(dev) - before) / PROBE_NETWORKS
    del tr
    torch.cuda.empty_cache()
    n = max(1, int(fraction * free / max(per, 1.0)))
    log.info("a network's training takes %.0f MB on %s: %d networks per batch", per / 2**20, dev, n)
    return n


def rel_error(EI: float | np.ndarray, truth: float) -> float | np.ndarray:
    """Relative error (EI - truth) / truth [-]."""
    return (np.asarray(EI) - truth) / truth if np.ndim(EI) else (float(EI) - truth) / truth


__all__ = ["FitResult", "fit", "networks_per_batch", "rel_error"]
