"""The one PINN training loop (`run_steps`, which the real girder's network trains by too,
`uq.girder_net.train_fit`) and the uniform girder's fit: every method that trains a uniform-girder PINN
calls `fit`.

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
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .beta import beta_bias_factor
from .network import PINN
from .problem import Problem
from .settings import TrainSettings
from .trainer import _build_model, _dtype, _Trainer

log = logging.getLogger(__name__)

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


def _resolve_device(device: str | torch.device) -> torch.device:
    if str(device) == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(device)


def run_steps(
    tr,
    adam_steps: int,
    lbfgs_steps: int = 0,
    *,
    lbfgs_chunk: int = 1,
    desc: str = "PINN",
    quiet: bool = False,
    log_every: int = 1,
    save: Callable[[], None] | None = None,
    checkpoint_every: int = 0,
    callback: Callable[[int, dict], None] | None = None,
) -> None:
    """The one training loop, for every network the toolkit trains: Adam steps of the trainer `tr` until
    its step count reaches `adam_steps`, then L-BFGS in chunks of `lbfgs_chunk` iterations up to
    ``adam_steps + lbfgs_steps``, with a progress bar (unless `quiet`), a checkpoint (`save`) every
    `checkpoint_every` Adam steps and after each L-BFGS chunk, and ``callback(step, info)`` after each
    step or chunk (an exception raised by it stops the loop; the checkpoint stays).

    `tr` carries `step` (steps done: a resumed trainer starts where it stopped), `adam_step()`,
    `lbfgs_chunk(n)` (when `lbfgs_steps` > 0), `postfix()` (the bar's fields, asked every `log_every`
    steps) and, when a `callback` is given, `callback_info(phase)` ('adam' or 'lbfgs'). The uniform girder's `_Trainer` and the real
    girder's `GirderTrainer` (`uq.girder_net`) are such trainers."""
    from tqdm.auto import tqdm

    n_total = adam_steps + lbfgs_steps
    bar = tqdm(
        total=n_total,
        initial=min(tr.step, n_total),
        disable=quiet,
        desc=desc,
        unit="step",
        leave=False,
        dynamic_ncols=True,
    )
    try:
        while tr.step < adam_steps:
            tr.adam_step()
            bar.update(1)
            if tr.step % log_every == 0 or tr.step == adam_steps:
                bar.set_postfix(**tr.postfix(), refresh=False)
            if save is not None and checkpoint_every and tr.step % checkpoint_every == 0:
                save()
            if callback is not None:
                callback(tr.step, tr.callback_info("adam"))
        while tr.step < n_total:
            n = min(lbfgs_chunk, n_total - tr.step)
            tr.lbfgs_chunk(n)
            bar.update(n)
            if save is not None:
                save()
            if callback is not None:
                callback(tr.step, tr.callback_info("lbfgs"))
    finally:
        bar.close()


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
    elapsed0 = tr.elapsed

    def save_now():
        if path is not None:
            tr.elapsed = elapsed0 + time.perf_counter() - t0
            tr.save(path)

    run_steps(
        tr,
        s.epochs,
        s.lbfgs_iters,
        lbfgs_chunk=s.lbfgs_chunk,
        desc="PINN",
        quiet=quiet,
        log_every=s.log_every,
        save=save_now if path is not None else None,
        checkpoint_every=s.checkpoint_every,
        callback=callback,
    )
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


__all__ = ["FitResult", "fit", "networks_per_batch", "rel_error", "run_steps"]
