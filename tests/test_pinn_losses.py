"""Each loss term vanishes on an exact solution; the load matches physics.loads; scaling is consistent."""

import dataclasses
import math

import numpy as np
import pytest
import torch

from bayespinn.config import preset
from bayespinn.data.measurements import Measurements
from bayespinn.physics.loads import distributed_load
from bayespinn.pinn.losses import (
    bc_loss,
    data_prediction,
    ic_loss,
    moving_load,
    pde_residual_from_jet,
)
from bayespinn.pinn.problem import Problem
from bayespinn.pinn.taylor import Jet

DD = torch.float64
#: float64 round-off on O(1..1e3) quantities
TOL = 1e-10


def _sin_jet(n: float, xi, W: float, tau, kx=4, kt=2, phase=0.0):
    """Jet of w = sin(n pi xi) sin(W tau + phase), exact derivatives."""
    a = n * math.pi
    sx = [
        torch.sin(a * xi),
        a * torch.cos(a * xi),
        -(a**2) * torch.sin(a * xi),
        -(a**3) * torch.cos(a * xi),
        a**4 * torch.sin(a * xi),
    ]
    st = [
        torch.sin(W * tau + phase),
        W * torch.cos(W * tau + phase),
        -(W**2) * torch.sin(W * tau + phase),
    ]
    return Jet(
        sx[0] * st[0],
        tuple(sx[k] * st[0] for k in range(1, kx + 1)),
        tuple(sx[0] * st[k] for k in range(1, kt + 1)),
    )


@pytest.fixture(scope="module")
def problem():
    cfg = preset("deflection")
    d = Measurements(
        np.array([3.0, 9.0]),
        np.array([0.5, 1.0]),
        np.zeros(2),
        np.array(["deflection"] * 2),
        np.full(2, np.nan),
        np.array(["", ""]),
    )
    return Problem.from_config(cfg, d)


def test_pde_residual_zero_on_free_vibration(problem):
    """With no load, w = sin(n pi xi) sin(W_n tau) at the natural frequency solves the PDE exactly."""
    pt = dataclasses.replace(problem.tensors(1, dtype=DD), loads=torch.zeros(1, dtype=DD))
    g = torch.Generator().manual_seed(0)
    xi, tau = torch.rand(1, 200, generator=g, dtype=DD), torch.rand(1, 200, generator=g, dtype=DD)
    s = torch.tensor([0.07], dtype=DD)  # some EI / EI_ref
    for n in (1, 2, 3):
        W = math.sqrt(pt.stiffness * math.exp(0.07) * (n * math.pi) ** 4 / pt.inertia)
        R = pde_residual_from_jet(_sin_jet(n, xi, W, tau), torch.exp(s), xi, tau, pt)
        scale = pt.stiffness * math.exp(0.07) * (n * math.pi) ** 4  # size of each of the two terms
        assert float(R.abs().max()) / scale < TOL
        # and a wrong frequency does not
        R_bad = pde_residual_from_jet(_sin_jet(n, xi, 1.1 * W, tau), torch.exp(s), xi, tau, pt)
        assert float(R_bad.abs().max()) / scale > 1e-3


@pytest.mark.parametrize("case", ["deflection", "strain"])
def test_moving_load_matches_physics(case):
    cfg = preset(case)
    prob = Problem.from_config(
        cfg,
        Measurements(
            np.array([1.0]),
            np.array([0.1]),
            np.zeros(1),
            np.array(["deflection"]),
            np.full(1, np.nan),
            np.array([""]),
        ),
        beta=0.3,
    )
    sc = prob.scales
    pt = prob.tensors(1, dtype=DD)
    rng = np.random.default_rng(1)
    x, t = rng.uniform(0, sc.L, 500), rng.uniform(-0.2, sc.T + 0.2, 500)
    ref = distributed_load(cfg.beam, cfg.vehicle, x, t, 0.3) / sc.q
    got = moving_load(torch.tensor(x / sc.L)[None], torch.tensor(t / sc.T)[None], pt)[0].numpy()
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())


def test_image_load_vanishes_at_supports(problem):
    pt = problem.tensors(1, dtype=DD, beta_rel=0.1)
    tau = torch.rand(1, 50, dtype=DD)
    for end in (0.0, 1.0):
        f = moving_load(torch.full_like(tau, end), tau, pt, images=True)
        assert float(f.abs().max()) < 1e-12


def test_ic_and_bc_zero_on_exact_functions():
    g = torch.Generator().manual_seed(0)
    xi = torch.rand(2, 100, generator=g, dtype=DD)
    # w = sin(pi xi) * (1 - cos(W tau)) has w = w_tau = 0 at tau = 0
    W = 7.0
    zero = torch.zeros_like(xi)
    j_ic = Jet(
        torch.sin(math.pi * xi) * (1 - torch.cos(W * zero)),
        (),
        (torch.sin(math.pi * xi) * W * torch.sin(W * zero),),
    )
    assert float(ic_loss(j_ic).max()) < TOL
    # simply supported shapes: w = sin(n pi xi) f(tau) has w = w_xx = 0 at xi = 0, 1
    tau = torch.rand(2, 100, generator=g, dtype=DD)
    ends = torch.cat([torch.zeros(2, 50, dtype=DD), torch.ones(2, 50, dtype=DD)], 1)
    j_bc = _sin_jet(2, ends, 3.0, tau, kx=2, kt=0)
    assert float(bc_loss(j_bc).max()) < TOL
    # and a non-simply-supported shape does not
    j_bad = _sin_jet(2, ends, 3.0, tau, kx=2, kt=0, phase=0.0)
    j_bad = Jet(j_bad.value + 0.1, j_bad.x, j_bad.t)
    assert float(bc_loss(j_bad).min()) > 1e-3


def test_data_term_zero_on_exact_values():
    """Mixed deflection and strain rows: predictions from the exact jet equal the values."""
    cfg = preset("strain")
    L = cfg.beam.length
    rng = np.random.default_rng(0)
    n = 40
    x, t = rng.uniform(0, L, n), rng.uniform(0, cfg.duration, n)
    kind = np.where(np.arange(n) % 2 == 0, "deflection", "strain")
    y = np.where(kind == "strain", rng.choice([-0.46, 0.46], n), np.nan)
    prob = Problem.from_config(cfg, Measurements(x, t, np.zeros(n), kind, y, np.full(n, "")))
    sc = prob.scales
    W = 5.0
    u = lambda x, t: sc.U * np.sin(math.pi * x / L) * np.sin(W * t / sc.T)  # noqa: E731
    u_xx = lambda x, t: -((math.pi / L) ** 2) * u(x, t)  # noqa: E731
    values = np.where(kind == "strain", -y * u_xx(x, t), u(x, t))
    prob = Problem.from_config(cfg, Measurements(x, t, values, kind, y, np.full(n, "")))
    pt = prob.tensors(1, dtype=DD)
    j = _sin_jet(1, pt.xi, W, pt.tau, kx=2, kt=0)
    r = data_prediction(j, pt) - pt.value
    assert float(r.abs().max()) < TOL
    # the scaled residual is the physical one divided by the row scale
    scale = prob.row_scales()
    assert np.all(scale > 0)


def test_posterior_scale_is_gaussian_nll(problem):
    """data_scale * mean((r / s_i)^2) = sum((value - pred)^2) / (2 sigma^2)."""
    sigma = 2e-4
    prob = dataclasses.replace(problem, noise_sd=sigma)
    pt = prob.tensors(1, dtype=DD)
    r_phys = np.array([1e-4, -3e-4])
    r_scaled = r_phys / prob.row_scales()
    assert math.isclose(
        pt.data_scale * np.mean(r_scaled**2), np.sum(r_phys**2) / (2 * sigma**2), rel_tol=1e-12
    )
