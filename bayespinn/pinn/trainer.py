"""The state of one PINN fit and its steps (`_Trainer`, driven by `pinn.train.fit`): the network built
from the settings, each member's seed streams, the optimisers, the loss (in varpro mode with the head and
log EI solved first), the divergence guard, the Adam and L-BFGS steps, and checkpoints of it all.

Apart from `fit`, which decides the phases, the schedule and the result, because the benchmarks
(`pinn.bench`) and the memory probe (`networks_per_batch`) time and measure the same steps.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np
import torch

from ..errors import TrainingDiverged
from .losses import TERMS, Objective, field_jets, prior_term, terms_from_jets
from .network import PINN
from .problem import Problem
from .sampling import Collocation, sample_collocation
from .settings import TrainSettings
from .taylor import contract_jet
from .varpro import head_system, solve_head

#: the training loop's logger: its warnings read as they did when this was part of `pinn.train`
log = logging.getLogger("bayespinn.pinn.train")

CHECKPOINT_SCHEMA = "bayespinn.pinn.checkpoint/1"
#: varpro: the golden-section bracket for log EI around its current value, per step
VARPRO_HALF_WIDTH = 0.25


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

    # ------------------------------------------------------------------ the loop's view (`train.run_steps`)
    def postfix(self) -> dict:
        """The progress bar's fields: the members' median EI and the last recorded total loss."""
        return {
            "EI": f"{np.median(self.EI_raw()):.4g}",
            "loss": f"{self.history['total'][-1].sum():.3g}",
        }

    def callback_info(self, phase: str) -> dict:
        return {"phase": phase, "EI_raw": self.EI_raw(), "model": self.model}

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
