"""`bayespinn bench`'s training-step floor: the FLOPs are counted, the floor follows its formula."""

import math

import pytest
import torch

from bayespinn.pinn.bench import analytic_matmul_flops, bench_derivatives, count_flops

FLOOR_KEYS = (
    "gflop_per_step",
    "gflop_matmul",
    "gflop_elementwise",
    "gflop_matmul_analytic",
    "matmul_gflops",
    "matmul_gflops_large",
    "floor_ms",
    "floor_ratio",
    "floor_ratio_large",
)


@pytest.fixture(scope="module")
def small():
    return bench_derivatives(
        points=120, width=12, depth=3, repeats=2, warmup=1, compile=False, large=256
    )


def test_derivatives_block_carries_the_floor_and_its_formula(small):
    d = small
    for k in ("autograd_ms", "taylor_ms", "speedup", "max_rel_diff", *FLOOR_KEYS):
        assert isinstance(d[k], float) and math.isfinite(d[k]) and d[k] > 0, k
    assert d["floor_ratio"] == pytest.approx(
        d["taylor_ms"] / (1000 * d["gflop_per_step"] / d["matmul_gflops"]), rel=1e-12
    )
    assert d["floor_ratio_large"] == pytest.approx(
        d["taylor_ms"] / (1000 * d["gflop_per_step"] / d["matmul_gflops_large"]), rel=1e-12
    )
    assert d["gflop_per_step"] == pytest.approx(d["gflop_matmul"] + d["gflop_elementwise"])
    assert d["matmul_shape"] == [7 * 120, 12, 12]


def test_counted_matmul_flops_equal_the_hand_count(small):
    """torch's counter over the whole step (forward, residual, backward, Adam) equals the count by hand;
    a network one layer deeper or wider gives another count (the comparison can fail)."""
    assert small["gflop_matmul"] * 1e9 == analytic_matmul_flops(120, 12, 3)
    assert analytic_matmul_flops(120, 12, 4) != analytic_matmul_flops(120, 12, 3)
    assert analytic_matmul_flops(120, 13, 3) != analytic_matmul_flops(120, 12, 3)


def test_count_flops_counts_products_and_elementwise_work():
    a, b = torch.ones(5, 7), torch.ones(7, 3)
    c = count_flops(lambda: torch.tanh(a @ b) + 1.0)
    assert c["matmul"] == 2 * 5 * 7 * 3
    assert c["elementwise"] == 2 * 5 * 3  # tanh and the addition, one per output element
    assert c["total"] == c["matmul"] + c["elementwise"]
