"""Thread control for small tensor work.

Tiny linear algebra (the last-layer model's 65 x 65 Cholesky, NUTS steps) runs ~100x slower with two
OpenMP threads than with one when the other core is busy (measured: 22 ms vs 0.13 ms per factorise +
gradient), so such work runs single-threaded; training keeps torch's setting.
"""

from __future__ import annotations

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
