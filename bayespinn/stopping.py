"""Stopping cleanly: SIGINT (Ctrl-C) or SIGTERM (what a scheduler or `docker stop` sends) to the main
process stops every worker process at once and unwinds the main process as a KeyboardInterrupt, so that
run folders are not half-written (`pipeline.staged_output` removes its staging folder) and a coverage
study or sweep keeps its finished tasks for a resume (their checkpoints are written by the main process).

Workers hold nothing that must be cleaned up (their results travel back to the main process), so they are
killed (SIGKILL) rather than asked: a polite signal would only reach the task they are running, which the
pool would report and then carry on with the next one.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import threading
from contextlib import contextmanager

SIGNALS = (signal.SIGINT, signal.SIGTERM)


def stop_workers() -> int:
    """Kill this process's worker processes (multiprocessing children); returns how many."""
    children = multiprocessing.active_children()
    for p in children:
        p.kill()
    for p in children:
        p.join(timeout=2)
    _stop_fork_server()
    return len(children)


def _stop_fork_server() -> None:
    """Kill the fork server the local pool starts its workers from (it runs no task and would otherwise
    linger until it notices this process has gone), and every process it forked: a worker whose start
    the signal interrupted is forked but not yet among this process' children, and would outlive the
    run. The server is stopped first, so that it forks nothing while its children are found."""
    from multiprocessing import forkserver

    server = getattr(forkserver, "_forkserver", None)
    pid = getattr(server, "_forkserver_pid", None)
    if not pid:  # not reaped here: the next pool's `ensure_running` reaps it and starts a new one
        return
    try:
        os.kill(pid, signal.SIGSTOP)
    except OSError:
        return
    for child in _children_of(pid):
        try:
            os.kill(child, signal.SIGKILL)
        except OSError:
            pass
    try:
        os.kill(pid, signal.SIGKILL)
    except OSError:
        pass
    _forget_fork_server(server, pid)


def _forget_fork_server(server, pid: int) -> None:
    """Reap the killed server and clear multiprocessing's record of it, so that the next pool of this
    process starts a new one. Left as it was, the record names a server that is dying but not yet reaped:
    `ensure_running` took it for alive and the next worker's start failed with EOFError."""
    try:
        os.waitpid(pid, 0)
    except ChildProcessError:  # not our child (or already reaped): nothing to wait for
        pass
    fd = getattr(server, "_forkserver_alive_fd", None)
    if fd is not None:
        try:
            os.close(fd)
        except OSError:
            pass
    for name in ("_forkserver_alive_fd", "_forkserver_address", "_forkserver_pid"):
        if hasattr(server, name):
            setattr(server, name, None)


def _children_of(pid: int) -> list[int]:
    """The processes whose parent is pid, from /proc (none where there is no /proc)."""
    out = []
    try:
        entries = os.listdir("/proc")
    except OSError:
        return out
    for name in entries:
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/stat", encoding="ascii", errors="replace") as f:
                stat = f.read()
        except OSError:
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
            out.append(int(name))
    return out


def _stop(signum, frame):  # noqa: ARG001 - signal handler signature
    stop_workers()
    raise KeyboardInterrupt(signal.Signals(signum).name)


@contextmanager
def stop_cleanly():
    """Within this block (main thread only), SIGINT and SIGTERM kill the worker processes and raise
    KeyboardInterrupt in the main process. Elsewhere it does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.signal(s, _stop) for s in SIGNALS}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)
