"""SIGINT and SIGTERM to a real run stop every worker within 5 s and leave no half-written output."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(
    not Path("/proc").is_dir(), reason="reads the process table in /proc"
)


def children(pid: int) -> set[int]:
    """All descendants of pid (from /proc)."""
    parent = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
            except OSError:
                continue
            parent[int(d.name)] = int(stat.rsplit(")", 1)[1].split()[1])
    out, todo = set(), [pid]
    while todo:
        p = todo.pop()
        kids = [c for c, pp in parent.items() if pp == p]
        out.update(kids)
        todo.extend(kids)
    return out


def alive(pids) -> set[int]:
    out = set()
    for p in pids:
        try:
            state = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z":
            out.add(p)
    return out


def cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()[:200]
    except OSError:
        return "?"


@pytest.mark.slow  # two real runs (~12 s); the in-process test below covers the handler in the default run
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_stops_every_worker_and_leaves_nothing(tmp_path, sig):
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "bayespinn", "run", "--snr", "20", "--method", "ensemble"]
    cmd += ["--profile", "smoke", "--members", "4", "--workers", "2", "--out", str(out), "--quiet"]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        workers: set[int] = set()
        while time.monotonic() < deadline and len(workers) < 2:  # the pool's workers are training
            time.sleep(0.2)
            workers = alive(children(proc.pid))
        assert len(workers) >= 2, "the run never started its worker processes"
        time.sleep(1.0)
        t0 = time.monotonic()
        proc.send_signal(sig)
        family = workers | children(proc.pid)  # the workers, the fork server, the resource tracker
        rc = proc.wait(timeout=30)
        waited = time.monotonic() - t0
        left = alive(family)
        while left and time.monotonic() - t0 < 5.0:  # a helper may still be exiting as the run ends
            time.sleep(0.05)
            left = alive(left)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert waited < 5.0 and not left, (waited, {p: cmdline(p) for p in left})
    assert rc == 1, proc.stderr.read()  # the contract: 1 for any failure other than bad input
    assert not out.exists(), "a stopped run left a (half-written) output folder"


def test_the_handler_kills_workers_in_process(tmp_path):
    """The same from Python: inside `stop_cleanly`, the signal becomes KeyboardInterrupt after the pool's
    workers are gone."""
    from concurrent.futures import ProcessPoolExecutor

    from bayespinn.stopping import stop_cleanly

    before = children(os.getpid())  # e.g. a fork server an earlier test of this process started
    with pytest.raises(KeyboardInterrupt), stop_cleanly():
        with ProcessPoolExecutor(2) as pool:
            futs = [pool.submit(time.sleep, 30) for _ in range(2)]
            time.sleep(0.5)
            pids = set(children(os.getpid())) - before
            assert len(pids) >= 2
            os.kill(os.getpid(), signal.SIGTERM)
            for f in futs:
                f.result()
    assert not alive(pids)


def test_a_worker_forked_but_not_yet_registered_is_stopped_too():
    """The race a signal can hit: the fork server has forked a worker whose start the signal interrupted,
    so the worker is not yet among this process' children. `stop_workers` must kill it with the server
    (before, it survived the run as an orphan); the started worker is taken out of multiprocessing's
    registry to stand for that moment."""
    import multiprocessing
    import multiprocessing.process as mp_process

    from bayespinn.stopping import stop_workers

    ctx = multiprocessing.get_context("forkserver")
    p = ctx.Process(target=time.sleep, args=(60,))
    p.start()
    try:
        mp_process._children.discard(
            p
        )  # the parent no longer knows it: as if start() was interrupted
        assert p not in multiprocessing.active_children()
        stop_workers()
        deadline = time.monotonic() + 5.0
        while alive({p.pid}) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not alive({p.pid}), cmdline(p.pid)
    finally:
        if alive({p.pid}):
            os.kill(p.pid, signal.SIGKILL)


def test_a_pool_started_after_a_stop_gets_a_new_fork_server():
    """A process that stopped its workers (a signal handled in an interactive session, or one test after
    another) must be able to start workers again: the killed fork server is forgotten, not reused."""
    import multiprocessing

    from bayespinn.stopping import stop_workers

    ctx = multiprocessing.get_context("forkserver")
    for _ in range(3):
        p = ctx.Process(target=time.sleep, args=(60,))
        p.start()
        try:
            stop_workers()
            assert not alive({p.pid}), cmdline(p.pid)
        finally:
            if alive({p.pid}):
                os.kill(p.pid, signal.SIGKILL)
