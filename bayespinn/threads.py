"""Thread control for small tensor work.

Tiny linear algebra (the last-layer model's 65 x 65 Cholesky, NUTS steps) runs ~100x slower with two
OpenMP threads than with one when the other core is busy (measured: 22 ms vs 0.13 ms per factorise +
gradient), so such work runs single-threaded; training keeps torch's setting.
"""

from __future__ import annotations

import functools
from contextlib import contextmanager


@contextmanager
def torch_threads(n: int = 1):
    """Temporarily run torch with n intra-op threads."""
    import torch

    old = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old)


def one_blas_thread(fn):
    """Run fn with one BLAS thread: its floating-point result then never depends on the machine's thread
    count (the FE solve's last bits do: 1 vs 2 OpenBLAS threads give different rounding), so a cached
    result that a forked worker inherits equals one computed afresh in a Ray worker. Also faster for
    these small banded systems (measured 1.27 s vs 1.74 s for the default FE crossing)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        from threadpoolctl import threadpool_limits

        with threadpool_limits(1):
            return fn(*args, **kwargs)

    return wrapper
