"""The enrichment carries the forced moving-load response, and that is what keeps EI unbiased on fast
crossings: it solves the beam equation with inertia at the current EI, and fitted with the free vibrations to
the exact response of a moving load its coefficient is 1 at every speed, where the quasi-static enrichment's
is 1 / (1 - alpha^2) (the amplified first mode mistaken for flexibility: the drift of issue 21)."""

from __future__ import annotations

import math
import pickle

import pytest
import torch

from bayespinn.pinn.enrich import FreeVibration, StaticEnrichment
from bayespinn.pinn.losses import moving_load
from bayespinn.pinn.problem import ProblemTensors

W1 = 30.0  # omega_1(EI_ref) T [rad]
F64 = torch.float64


def _points(n=800, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(1, n, generator=g, dtype=F64), torch.rand(1, n, generator=g, dtype=F64)


def _enrichment(alpha, *, forced=True, damping=0.0, loads=(0.7, 1.0), delays=(0.0, 0.1)):
    speed = alpha * W1 / math.pi  # r_1 = pi (v T / L) / W_1 = alpha at EI_ref
    return StaticEnrichment(
        loads, delays, speed, 0.02, frequency=W1 if forced else None, damping=damping
    )


def _load(enr, xi, tau):
    z = torch.zeros(1, dtype=F64)
    pt = ProblemTensors(
        xi, tau, z, z, z, False, True, None, None,
        torch.tensor(enr.loads, dtype=F64), torch.tensor(enr.delays, dtype=F64), enr.speed,
        torch.tensor(enr.beta_rel, dtype=F64), 1 / 48, math.pi**4 / (48 * W1**2),
    )  # fmt: skip
    return moving_load(xi, tau, pt, images=True), pt.inertia


@pytest.mark.parametrize("alpha", [0.021, 0.064, 0.2])
@pytest.mark.parametrize("log_ei", [0.0, 0.2])
def test_forced_enrichment_solves_the_beam_equation_with_inertia(alpha, log_ei):
    """theta E_xixixixi / 48 + inertia E_tautau = theta f at the EI it was evaluated at (its coefficient is
    then 1 / theta); the quasi-static enrichment leaves the inertia of the whole series, of order alpha^2 / 10 of the
    load's peak (the negative control)."""
    xi, tau = _points()
    theta = math.exp(log_ei)
    s = torch.tensor([log_ei], dtype=F64)
    for forced, bound in ((True, 1e-7), (False, None)):
        enr = _enrichment(alpha, forced=forced)
        f, inertia = _load(enr, xi, tau)
        j = enr.jet(xi, tau, 4, 2, s)
        res = theta / 48 * j.dx(4)[..., 0] + inertia * j.dt(2)[..., 0] - theta * f
        rel = float(res.abs().max() / f.abs().max())
        if forced:
            assert rel < bound, rel
        else:
            assert rel > alpha**2 / 40, rel  # observed 2.8e-5, 5.8e-4, 5.0e-3


def _exact_single_axle(alpha, xi, tau, beta_rel=0.02, n_max=400):
    """The exact response w (units of U) of one Gaussian load (with images) crossing at v T / L = 1 from
    rest, while on the span, on a girder with W_1 = pi / alpha (so r_n = alpha / n): each mode's forced
    response minus the free vibration at omega_n that starts it from rest."""
    n = torch.arange(1, n_max + 1, dtype=F64)
    k = math.pi * n
    g = 2.0 * torch.exp(-((k * beta_rel) ** 2) / 4.0) / k**4 * 48.0
    r = alpha / n
    Wn = math.pi / alpha * n**2
    t = tau.unsqueeze(-1)
    q = (torch.sin(k * t) - r * torch.sin(Wn * t)) / (1 - r**2)
    return (g * torch.sin(k * xi.unsqueeze(-1)) * q).sum(-1)[0]


@pytest.mark.parametrize("alpha", [0.021, 0.064, 0.11, 0.2])
def test_fitted_coefficient_is_one_with_the_forced_response_and_amplified_without(alpha):
    """The issue's lead, checked: least squares of the exact response on [enrichment, free vibrations of the
    first three modes] gives the forced enrichment a coefficient of 1 (to 1e-4) at every alpha, and the
    quasi-static one 1 / (1 - alpha^2): the PDE turns that coefficient into an EI low by the same factor."""
    xi, tau = _points(1500, seed=1)
    W = math.pi / alpha
    s = torch.zeros(1, dtype=F64)
    free = FreeVibration((0.0,), 3, W).jet(xi, tau, 0, 0, s).value[0]
    w = _exact_single_axle(alpha, xi, tau)
    for forced, want, tol in ((True, 1.0, 1e-4), (False, 1.0 / (1.0 - alpha**2), 3e-4)):
        enr = StaticEnrichment((1.0,), (0.0,), 1.0, 0.02, frequency=W if forced else None)
        A = torch.cat([enr.jet(xi, tau, 0, 0, s).value[0], free], dim=-1)
        c = torch.linalg.lstsq(A, w.unsqueeze(-1)).solution[:, 0]
        assert float(c[0]) == pytest.approx(want, rel=tol)


def test_amplified_modes_follow_the_bridge():
    """K_a grows with alpha (5 at the Exeter girder's 0.021, 10 at 0.2); quasi-static: none."""
    assert _enrichment(0.0207).amplified_modes == 5
    assert _enrichment(0.2).amplified_modes == 10
    assert _enrichment(0.2, forced=False).amplified_modes == 0
    ks = [_enrichment(a).amplified_modes for a in (0.015, 0.03, 0.06, 0.12, 0.2)]
    assert ks == sorted(ks)


def test_damping_is_continuous_and_the_parts_are_kept_per_point_set():
    """A tiny damping ratio gives (nearly) the undamped response; the EI-dependent parts are computed once
    per point set, whatever EI; a pickled copy carries no tensors."""
    xi, tau = _points(300, seed=2)
    s = torch.tensor([0.1], dtype=F64)
    j0 = _enrichment(0.1).jet(xi, tau, 4, 2, s)
    jd = _enrichment(0.1, damping=1e-9).jet(xi, tau, 4, 2, s)
    for a, b in zip((j0.value, *j0.x, *j0.t), (jd.value, *jd.x, *jd.t), strict=True):
        assert torch.allclose(a, b, rtol=1e-6, atol=1e-6 * float(a.abs().max()))
    enr = _enrichment(0.1, damping=0.02)
    enr.jet(xi, tau, 4, 2, s)
    parts = enr._modes.items[next(iter(enr._modes.items))][3]
    enr.jet(xi, tau, 4, 2, s + 0.3)
    assert enr._modes.items[next(iter(enr._modes.items))][3] is parts
    copy = pickle.loads(pickle.dumps(enr))
    assert copy == enr and not copy._modes.items
