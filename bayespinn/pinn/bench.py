"""Performance figures of the PINN engine (the `bayespinn bench` command calls these).

Every figure is the median wall time of repeated full training steps -- forward pass, PDE residual with
u_xxxx and u_tt, backward pass, optimiser step -- after a warm-up, with the variants compared measured
in the same process and interleaved round by round, so a change in machine load hits all of them alike.
"""

from __future__ import annotations

import logging
import statistics
import time
from collections.abc import Callable

import numpy as np
import torch

from ..config import preset
from ..data.synthetic import sample_layout
from .losses import pde_residual
from .network import PINN
from .problem import Problem
from .settings import TrainSettings

log = logging.getLogger(__name__)


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _timed(fn: Callable[[], None], device: torch.device) -> float:
    _sync(device)
    t0 = time.perf_counter()
    fn()
    _sync(device)
    return 1e3 * (time.perf_counter() - t0)


def _rounds(
    steps: dict[str, Callable[[], None]], device, warmup: int, repeats: int
) -> dict[str, list[float]]:
    """ms of each call of each step function, `repeats` rounds round-robin after `warmup` calls each."""
    for fn in steps.values():
        for _ in range(warmup):
            fn()
    times: dict[str, list[float]] = {k: [] for k in steps}
    for _ in range(repeats):
        for k, fn in steps.items():
            times[k].append(_timed(fn, device))
    return times


def _interleaved(
    steps: dict[str, Callable[[], None]], device, warmup: int, repeats: int
) -> dict[str, float]:
    """Median ms per call of each step function, measured round-robin after `warmup` calls each."""
    return {k: statistics.median(v) for k, v in _rounds(steps, device, warmup, repeats).items()}


#: aten ops (pointwise) that do two floating-point operations per output element
_TWO_FLOP = ("addcmul", "addcdiv", "lerp", "addcmul_", "addcdiv_", "lerp_")


def _numel(x) -> int:
    if isinstance(x, torch.Tensor):
        return x.numel() if x.is_floating_point() else 0
    if isinstance(x, list | tuple):
        return sum(_numel(a) for a in x)
    return 0


def count_flops(fn: Callable[[], None]) -> dict:
    """Floating-point operations of one call of `fn`, counted op by op as torch dispatches them.

    - matmul: torch's own count (`torch.utils.flop_counter.FlopCounterMode`: 2 m k n per product, every
      mm / bmm / addmm / baddbmm, forward and backward);
    - elementwise: every other floating-point aten op that torch tags pointwise, one operation per output
      element (two for addcmul, addcdiv, lerp), reductions (sum, mean, ...) one per input element, the
      optimiser's foreach ops one per element of their first tensor list.

    Returns {"matmul": FLOPs, "elementwise": FLOPs, "total": FLOPs}. Transcendental functions (tanh, exp)
    count as one operation, so the total is a lower bound on the work.
    """
    from torch.utils._python_dispatch import TorchDispatchMode
    from torch.utils.flop_counter import FlopCounterMode

    counted = {"elementwise": 0}
    reductions = ("sum", "mean", "amax", "amin", "max", "min", "norm", "linalg_vector_norm", "prod")

    class _Elementwise(TorchDispatchMode):
        def __torch_dispatch__(self, func, types, args=(), kwargs=None):
            out = func(*args, **(kwargs or {}))
            name = func.overloadpacket.__name__
            if name.startswith("_foreach_"):
                counted["elementwise"] += _numel(args[0] if args else ())
            elif name in reductions:
                counted["elementwise"] += _numel(args[0] if args else ())
            elif torch.Tag.pointwise in func.tags:
                counted["elementwise"] += _numel(out) * (2 if name in _TWO_FLOP else 1)
            return out

    with FlopCounterMode(display=False) as fc, _Elementwise():
        fn()
    mm = int(fc.get_total_flops())
    return {
        "matmul": mm,
        "elementwise": counted["elementwise"],
        "total": mm + counted["elementwise"],
    }


def matmul_rate(
    m: int, k: int, n: int, device, dtype=torch.float32, *, seconds: float = 0.5, batch: int = 1
) -> float:
    """Measured dense matrix-multiply rate [GFLOP/s] of torch.bmm of (batch, m, k) by (batch, k, n) on
    `device` in `dtype` with torch's current thread setting: the median of 5 timed blocks, each as many
    products as fill seconds / 5, after a warm-up."""
    dev = torch.device(device)
    g = torch.Generator().manual_seed(0)
    a = torch.randn(batch, m, k, generator=g, dtype=dtype).to(dev)
    b = torch.randn(batch, k, n, generator=g, dtype=dtype).to(dev)
    torch.bmm(a, b)
    _sync(dev)
    t0, reps = time.perf_counter(), 0
    while reps < 3 or time.perf_counter() - t0 < 0.05:
        torch.bmm(a, b)
        reps += 1
    _sync(dev)
    per = (time.perf_counter() - t0) / reps
    block = max(1, int(seconds / 5 / max(per, 1e-9)))
    times = []
    for _ in range(5):
        _sync(dev)
        t0 = time.perf_counter()
        for _ in range(block):
            torch.bmm(a, b)
        _sync(dev)
        times.append((time.perf_counter() - t0) / block)
    return 2.0 * batch * m * k * n / statistics.median(times) / 1e9


def analytic_matmul_flops(points: int, width: int, depth: int) -> int:
    """Matrix-multiply FLOPs of one training step of the plain `PINN` (`depth` tanh layers of `width`, one
    output) on the Taylor-mode residual at `points` points, by hand, to check `count_flops` against.

    The input jet (xi, tau) has a full value (N, 2) and two constant first derivatives (1, 2); after the
    first layer all K = 1 + 4 + 2 components are full, so each further layer multiplies (K N, w) by (w, w)
    and the output layer (K N, w) by (w, 1). A product C = A B costs 2 m k n forward; backward, 2 m k n for
    the weight's gradient and as much again for A's where A depends on the weights (not the first layer's
    input).
    """
    N, w, K = points, width, 1 + 4 + 2
    first = 2 * N * 2 * w + 2 * (2 * 1 * 2 * w)  # the value and the two constant derivatives
    hidden = (depth - 1) * 2 * K * N * w * w
    out = 2 * K * N * w
    return first + hidden + out + first + 2 * hidden + 2 * out


#: products of the step's shape per timed sample of the matrix-multiply rate (about a step's worth of them)
MATMULS_PER_SAMPLE = 12

#: the large product whose rate `bench_derivatives` reports beside the step's own shape
LARGE_MATMUL = 2048


def _deflection_problem() -> Problem:
    cfg = preset("deflection")
    return Problem.from_config(cfg, sample_layout(cfg, 0))


def bench_derivatives(
    points: int = 2500,
    width: int = 64,
    depth: int = 5,
    device: str = "cpu",
    *,
    repeats: int = 15,
    warmup: int = 3,
    compile: bool | None = None,
    seed: int = 0,
    large: int = LARGE_MATMUL,
) -> dict:
    """Training-step time with nested autograd versus Taylor-mode derivatives.

    Parameters
    ----------
    points : PDE collocation points; width, depth : the MLP (paper: 2500, 64, 5)
    device : 'cpu' or 'cuda'
    repeats, warmup : timed and untimed steps per variant
    compile : also time the Taylor step under torch.compile (default: yes if a compiler works)
    large : side of the large square product whose rate is reported beside the step's own

    Returns
    -------
    dict with points, width, depth, threads, autograd_ms, taylor_ms (eager Taylor mode, the engine's
    default on CPU), speedup = autograd_ms / taylor_ms, max_rel_diff (largest of max|Taylor - autograd|
    / max|autograd| over u, u_xx, u_xxxx, u_t, u_tt at the points, float32), and, when compiled,
    taylor_compiled_ms, compiled_speedup, compile_s (first compiled step, compilation included); and the
    Taylor step's floor (`step_floor`): gflop_per_step, matmul_gflops, floor_ratio and their parts, with
    gflop_matmul_analytic (`analytic_matmul_flops`, which the counted gflop_matmul must equal).
    """
    dev = torch.device(device)
    pt = _deflection_problem().tensors(1, dev)
    g = torch.Generator().manual_seed(seed)
    xi = torch.rand(1, points, generator=g).to(dev)
    tau = torch.rand(1, points, generator=g).to(dev)
    nets, opts = {}, {}
    variants = ["autograd", "taylor"]
    for name in variants + ["compiled"]:
        nets[name] = PINN(width, depth, generators=[torch.Generator().manual_seed(seed)]).to(dev)
        opts[name] = torch.optim.Adam(nets[name].parameters(), lr=1e-4)

    def make_step(name: str, engine: str, loss_fn=None):
        net, opt = nets[name], opts[name]

        def loss():
            return (pde_residual(net, xi, tau, pt, engine=engine) ** 2).mean()

        fn = loss_fn(loss) if loss_fn is not None else loss

        def step():
            opt.zero_grad(set_to_none=True)
            fn().backward()
            opt.step()

        return step

    steps = {"autograd": make_step("autograd", "autograd"), "taylor": make_step("taylor", "taylor")}
    # the step's hidden-layer product, timed in the same rounds (its rate sets the step's floor)
    shape = ((1 + 4 + 2) * points, width, width)
    mm_a = torch.randn(1, shape[0], shape[1], generator=g).to(dev)
    mm_b = torch.randn(1, shape[1], shape[2], generator=g).to(dev)

    def matmuls():
        for _ in range(MATMULS_PER_SAMPLE):
            torch.bmm(mm_a, mm_b)

    steps["matmul"] = matmuls
    out: dict = {
        "points": points,
        "width": width,
        "depth": depth,
        "threads": torch.get_num_threads(),
    }
    want_compile = compile if compile is not None else True
    if want_compile:
        try:
            cstep = make_step(
                "compiled", "taylor-unfused", lambda f: torch.compile(f, dynamic=False)
            )
            out["compile_s"] = _timed(cstep, dev) / 1e3
            steps["compiled"] = cstep
        except Exception as exc:  # pragma: no cover - depends on the installation
            log.warning("torch.compile unavailable for the benchmark: %s", exc)
    med = _interleaved(steps, dev, warmup, repeats)
    out["autograd_ms"] = med["autograd"]
    out["taylor_ms"] = med["taylor"]
    out["speedup"] = med["autograd"] / med["taylor"]
    if "compiled" in med:
        out["taylor_compiled_ms"] = med["compiled"]
        out["compiled_speedup"] = med["autograd"] / med["compiled"]
    # agreement of the two engines on the same (freshly initialised) network
    net = PINN(width, depth, generators=[torch.Generator().manual_seed(seed)]).to(dev)
    a = net.jet(xi, tau, 4, 2, engine="taylor")
    b = net.jet(xi, tau, 4, 2, engine="autograd")
    with torch.no_grad():  # a number to report, not a graph to keep
        diffs = [_rel_diff(a.dx(k), b.dx(k)) for k in (0, 2, 4)] + [
            _rel_diff(a.dt(k), b.dt(k)) for k in (1, 2)
        ]
    out["max_rel_diff"] = max(diffs)
    mm_ms = med["matmul"] / MATMULS_PER_SAMPLE
    out.update(step_floor(steps["taylor"], out["taylor_ms"], mm_ms, shape, dev, large))
    out["gflop_matmul_analytic"] = analytic_matmul_flops(points, width, depth) / 1e9
    return out


def step_floor(
    step: Callable[[], None],
    step_ms: float,
    matmul_ms: float,
    shape,
    device,
    large: int = LARGE_MATMUL,
) -> dict:
    """The training step's arithmetic floor: its counted floating-point work (`count_flops` of one call of
    `step`) at this machine's measured matrix-multiply rate, and how far `step_ms` is from it.

    The rate (`matmul_gflops`) is that of the step's own hidden-layer product (`shape` = (m, k, n): the
    stacked jet, 7 components x the points, times a width x width weight; float32, torch's thread
    setting), timed as `matmul_ms` in the same rounds as the step; a large square product's rate
    (side `large`, the machine's best) is reported beside it with its own ratio.

    Returns gflop_per_step (matmul + elementwise, counted), gflop_matmul, gflop_elementwise,
    matmul_gflops, matmul_shape, matmul_gflops_large, floor_ms = 1000 gflop_per_step / matmul_gflops,
    floor_ratio = step_ms / floor_ms, floor_ratio_large (the same against the large product's rate).
    """
    flops = count_flops(step)
    gflop = flops["total"] / 1e9
    m, k, n = shape
    rate = 2.0 * m * k * n / (matmul_ms * 1e-3) / 1e9
    big = matmul_rate(large, large, large, device)
    floor_ms = 1e3 * gflop / rate
    return {
        "gflop_per_step": gflop,
        "gflop_matmul": flops["matmul"] / 1e9,
        "gflop_elementwise": flops["elementwise"] / 1e9,
        "matmul_gflops": rate,
        "matmul_shape": list(shape),
        "matmul_gflops_large": big,
        "floor_ms": floor_ms,
        "floor_ratio": step_ms / floor_ms,
        "floor_ratio_large": step_ms / (1e3 * gflop / big),
    }


def _member_settings(points: int, width: int, depth: int, optimizer: str) -> TrainSettings:
    return TrainSettings.for_profile(
        "fast",
        optimizer=optimizer,
        width=width,
        depth=depth,
        n_pde=points,
        n_bc=max(points // 5, 2),
        n_ic=max(points // 5, 1),
        compile=False,
        resample_every=0,
        lbfgs_iters=0,
    )


def _train_member_steps(task: tuple) -> float:
    """One member built and stepped `steps` times in this process (an executor task); returns its seconds."""
    from .train import _Trainer

    m, steps, points, width, depth, optimizer = task
    t0 = time.perf_counter()
    tr = _Trainer(
        _deflection_problem(),
        _member_settings(points, width, depth, optimizer),
        np.random.SeedSequence(0, spawn_key=(m,)),
        1,
        torch.device("cpu"),
    )
    for _ in range(steps):
        tr.adam_step()
    return time.perf_counter() - t0


def bench_ensemble(
    members: int = 8,
    points: int = 1000,
    width: int = 64,
    depth: int = 5,
    device: str = "cpu",
    *,
    optimizer: str = "adam",
    repeats: int = 8,
    warmup: int = 2,
    parallel_steps: int = 60,
    parallel_rounds: int = 3,
    workers: int | None = None,
) -> dict:
    """M members trained one after another versus in parallel, measured in the same run.

    One "epoch" is one training step of every member (all loss terms, backward, Adam step).

    - sequential: M single networks stepped in turn in this process (torch's thread setting);
    - batched: one `PINN` with M members (weights (M, d_in, d_out), torch.bmm), as the ensemble trains
      on CUDA; median of `repeats` rounds interleaved with the sequential ones;
    - parallel (CPU): how the ensemble trains on a CPU: each member one task of the local executor (a
      process pool of `workers`, default one per core, one torch thread per process), `parallel_steps`
      steps each, end to end (building the networks and the pool's start included), against the same
      work done one member after another in this process. The two alternate for `parallel_rounds`
      rounds and the medians are compared, so one noisy moment on a shared machine does not decide the
      ratio. (A fast-profile member trains well over a thousand steps per phase; at 20 steps the pool's
      start weighed on the ratio: 1.15x to 1.24x on 2 cores, against 1.36x to 1.56x at 60 to 150 steps.)

    Returns
    -------
    dict with members, points, sequential_ms_per_epoch, batched_ms_per_epoch, `together` (what the
    ensemble uses on this device: "parallel processes" on a CPU, "batched" on CUDA) and `speedup`
    (sequential / together, as the contract defines it); on a CPU also workers, parallel_steps,
    sequential_s, parallel_s (medians over the rounds), the rounds' own `sequential_rounds_s` and
    `parallel_rounds_s`, parallel_ms_per_epoch, parallel_speedup (= speedup) and batched_speedup.
    """
    from ..executor import Executor, cpu_count
    from .train import _Trainer  # the training loop's own step

    dev = torch.device(device)
    prob = _deflection_problem()
    s = _member_settings(points, width, depth, optimizer)
    seq = [
        _Trainer(prob, s, np.random.SeedSequence(0, spawn_key=(m,)), 1, dev) for m in range(members)
    ]
    bat = _Trainer(prob, s, 0, members, dev)

    def sequential():
        for tr in seq:
            tr.adam_step()

    med = _interleaved({"seq": sequential, "bat": bat.adam_step}, dev, warmup, repeats)
    out = {
        "members": members,
        "points": points,
        "sequential_ms_per_epoch": med["seq"],
        "batched_ms_per_epoch": med["bat"],
        "speedup": med["seq"] / med["bat"],
    }
    if dev.type == "cpu" and parallel_steps > 0:
        tasks = [(m, parallel_steps, points, width, depth, optimizer) for m in range(members)]
        n = min(workers or cpu_count(), members)
        ms = _rounds(
            {
                "seq": lambda: [_train_member_steps(t) for t in tasks],
                "par": lambda: Executor("local", workers=n).map(
                    _train_member_steps, tasks, desc="bench members", progress=False
                ),
            },
            dev,
            0,
            max(1, parallel_rounds),
        )
        seq_s, par_s = [1e-3 * v for v in ms["seq"]], [1e-3 * v for v in ms["par"]]
        t_seq, t_par = statistics.median(seq_s), statistics.median(par_s)
        out.update(
            workers=n,
            parallel_steps=parallel_steps,
            parallel_rounds=len(seq_s),
            sequential_s=t_seq,
            parallel_s=t_par,
            sequential_rounds_s=seq_s,
            parallel_rounds_s=par_s,
            parallel_ms_per_epoch=1e3 * t_par / parallel_steps,
            parallel_speedup=t_seq / t_par,
            batched_speedup=out["speedup"],
            speedup=t_seq / t_par,
        )
    out["together"] = "parallel processes" if "parallel_speedup" in out else "batched"
    return out


def _rel_diff(a: torch.Tensor, b: torch.Tensor) -> float:
    """max |a - b| / max |b|, detached."""
    a, b = a.detach(), b.detach()
    return float((a - b).abs().max() / b.abs().max())
