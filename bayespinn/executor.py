"""Where independent tasks run: a local process pool (default) or an existing Ray cluster.

Every task carries its own seed, so results never depend on the executor or the number of workers;
results come back in task order. Workers run one torch/BLAS thread each, so the pool never runs more
busy threads than it has processes.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass

from .errors import InputError

log = logging.getLogger(__name__)

_THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


def _worker_init(log_level: int | None) -> None:
    """A local pool worker: one thread (`_single_thread`), and bayespinn's messages to stderr at the
    parent's level (a worker from the fork server does not inherit the parent's logging handlers)."""
    _single_thread()
    if log_level is not None:
        import sys

        lg = logging.getLogger("bayespinn")
        if not lg.handlers:
            h = logging.StreamHandler(sys.stderr)
            h.setFormatter(logging.Formatter("%(message)s"))
            lg.addHandler(h)
        lg.setLevel(log_level)
        lg.propagate = False


def _parent_log_level() -> int | None:
    """bayespinn's logging level in this process when it has a handler of its own (the CLI's), else None."""
    lg = logging.getLogger("bayespinn")
    return lg.level if lg.handlers else None


def _single_thread() -> None:
    """Process-wide: one BLAS/OpenMP/torch thread (pool and Ray workers)."""
    for v in _THREAD_VARS:
        os.environ[v] = "1"
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)
    try:
        import torch

        torch.set_num_threads(1)
    except Exception:  # noqa: BLE001 - torch is optional for pure-numpy tasks
        pass


class _OneThread:
    """Call fn(task) with one BLAS and one torch thread, so floating-point results never depend on where a
    task ran (a worker process, a Ray worker, or this process when there is one worker)."""

    def __init__(self, fn: Callable):
        self.fn = fn

    def __call__(self, task):
        import sys
        from contextlib import nullcontext

        from threadpoolctl import threadpool_limits

        from .threads import torch_threads

        # torch only when the task's process has it loaded: pure-numpy tasks never import it
        with torch_threads(1) if "torch" in sys.modules else nullcontext(), threadpool_limits(1):
            return self.fn(task)


#: share of a GPU a Ray task asks for when it trains on CUDA (four tasks per GPU)
GPU_FRACTION = 0.25


def task_resources(device: str | None) -> dict:
    """Ray resources of one task: a CPU, and a share of a GPU when it trains on CUDA (a Ray worker sees no
    GPU unless its task asks for one)."""
    out: dict = {"num_cpus": 1}
    if str(device or "cpu").startswith("cuda"):
        out["num_gpus"] = GPU_FRACTION
    return out


def cpu_count() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


#: modules the fork server imports once, before it forks any worker: the workers then start in
#: milliseconds (no torch import each) and the server itself never runs autograd
_PRELOAD = ["torch", "bayespinn.uq.ensemble", "bayespinn.uq.bpinn"]


def _context():
    """How the local pool starts its workers: from a fork server (`forkserver`), never by forking this
    process. Torch refuses a forked child's autograd once the parent has run autograd itself (CUDA in
    every version; from 2.14 also on the CPU: "Unable to handle autograd's threading in combination with
    fork-based multiprocessing"), and `run` trains and differentiates in this process before its NUTS
    chains and ensemble phases go to the pool. The fork server is a fresh interpreter that imports
    `_PRELOAD` once and forks each worker from itself, so a worker starts clean and fast; where there is
    no fork server (not POSIX) workers are spawned."""
    import multiprocessing as mp

    _open_files_limit()  # workers send tensors back as shared memory, one descriptor each
    if "forkserver" in mp.get_all_start_methods():
        ctx = mp.get_context("forkserver")
        ctx.set_forkserver_preload(_PRELOAD)
        return ctx
    return mp.get_context("spawn")  # pragma: no cover - not POSIX


def _open_files_limit() -> None:
    """Raise this process's soft limit on open files to the hard limit."""
    try:
        import resource

        soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
        if soft != hard:
            resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
    except (ImportError, OSError, ValueError):  # pragma: no cover - not POSIX, or not allowed
        pass


@dataclass(frozen=True)
class Executor:
    """kind 'local' (process pool of `workers`, default one per core) or 'ray' (`address`, e.g. 'auto').

    resources : per-task Ray resources, e.g. {"num_cpus": 1, "num_gpus": 0.25}
    """

    kind: str = "local"
    workers: int | None = None
    address: str | None = None

    def __post_init__(self) -> None:
        if self.kind not in ("local", "ray"):
            raise InputError("--executor", self.kind, "local or ray")
        if self.workers is not None and self.workers < 1:
            raise InputError("--workers", self.workers, "an integer >= 1")

    def map(
        self,
        fn: Callable,
        tasks: Sequence,
        *,
        desc: str = "tasks",
        progress: bool = True,
        resources: dict | None = None,
        on_result: Callable[[int, object], None] | None = None,
    ) -> list:
        """[fn(t) for t in tasks], in parallel, in task order.

        on_result : called in this process as on_result(i, result) as soon as task i finishes (in completion
            order), e.g. to checkpoint long studies
        """
        tasks = list(tasks)
        fn = _OneThread(fn)
        done = on_result or (lambda i, r: None)
        if self.kind == "ray":
            return _ray_map(
                fn, tasks, self.address, resources or {"num_cpus": 1}, desc, progress, done
            )
        n = min(self.workers or cpu_count(), len(tasks)) if tasks else 1
        bar = _bar(len(tasks), desc, progress)
        if n <= 1:
            out = []
            for i, t in enumerate(tasks):
                out.append(fn(t))
                done(i, out[-1])
                bar.update(1)
            bar.close()
            return out
        results: list = [None] * len(tasks)
        with ProcessPoolExecutor(
            max_workers=n,
            initializer=_worker_init,
            initargs=(_parent_log_level(),),
            mp_context=_context(),
        ) as pool:
            futs = {pool.submit(fn, t): i for i, t in enumerate(tasks)}
            try:
                for f in as_completed(futs):
                    results[futs[f]] = f.result()
                    done(futs[f], results[futs[f]])
                    bar.update(1)
            except BaseException:
                for f in futs:
                    f.cancel()
                raise
            finally:
                bar.close()
        return results


def _bar(total: int, desc: str, progress: bool):
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="task", disable=not progress, leave=False)


def _ray_map(
    fn: Callable,
    tasks: list,
    address: str | None,
    resources: dict,
    desc: str,
    progress: bool,
    on_result: Callable[[int, object], None],
) -> list:
    try:
        import ray
    except ImportError:
        raise InputError(
            "--executor", "ray", "Ray installed (pip install 'bayespinn[ray]')"
        ) from None
    if not ray.is_initialized():
        try:
            ray.init(
                address=address,
                ignore_reinit_error=True,
                log_to_driver=False,
                include_dashboard=False,
            )
        except (ConnectionError, ValueError) as exc:
            raise InputError("--address", address, f"a reachable Ray cluster ({exc})") from None

    @ray.remote(**resources)
    def _call(t):
        _single_thread()
        return fn(t)

    refs = [_call.remote(t) for t in tasks]
    index = {r: i for i, r in enumerate(refs)}
    bar = _bar(len(refs), desc, progress)
    pending = list(refs)
    while pending:
        done, pending = ray.wait(pending, num_returns=1)
        for r in done:
            on_result(index[r], ray.get(r))
        bar.update(len(done))
    bar.close()
    return ray.get(refs)


def run_all(fn: Callable, tasks: Iterable, executor: Executor | None = None, **kw) -> list:
    """Convenience: map over tasks with the given (or default local) executor."""
    return (executor or Executor()).map(fn, list(tasks), **kw)
