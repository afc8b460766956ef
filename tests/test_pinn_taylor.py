"""Taylor-mode derivatives against nested autograd (the reference), and the fused layer's backward."""

import pytest
import torch

from bayespinn.pinn.enrich import FreeVibration, StaticEnrichment, TiedVibration
from bayespinn.pinn.network import PINN

#: float32 agreement: both engines round differently through 5 layers; observed ~5e-7, 1e-4 is the brief's bar
TOL_F32 = 1e-4
#: float64 agreement: observed ~1e-15
TOL_F64 = 1e-10

CASES = [
    dict(),
    dict(hard_bc=True, hard_ic=True),
    dict(time_frequency=40.0),
    dict(hard_bc=True, time_frequency=40.0),
    dict(oscillator=40.0),
    dict(hard_bc=True, hard_ic=True, oscillator=25.0),
    dict(oscillator=40.0, extras=(StaticEnrichment((1.0, 0.8), (0.0, 0.3), 1.2, 0.05),)),
    dict(
        extras=(
            StaticEnrichment((1.0, 0.8), (0.0, 0.3), 1.2, 0.05),
            FreeVibration((0.0, 0.3, 0.7), 2, 30.0, 0.02),
        )
    ),
    dict(
        extras=(
            StaticEnrichment((1.0, 0.8), (0.0, 0.3), 1.2, 0.05, frequency=30.0, damping=0.02),
            TiedVibration((0.0, 0.3, 0.7), 3, 30.0, 0.02, (1.0, 0.8), (0.0, 0.3), 1.2, 0.05),
        )
    ),
]


def _net(dtype, members=2, **kw):
    gens = [torch.Generator().manual_seed(10 + m) for m in range(members)]
    net = PINN(24, 3, members=members, generators=gens, dtype=dtype, **kw)
    with torch.no_grad():
        net.log_ei.copy_(torch.linspace(-0.1, 0.2, members))
        # the modulated coefficients start at zero: make them count, or the check would be empty
        net.osc_head.copy_(
            torch.randn(net.osc_head.shape, generator=gens[0], dtype=torch.float64).to(dtype)
        )
        net.extra_head.copy_(
            torch.randn(net.extra_head.shape, generator=gens[0], dtype=torch.float64).to(dtype)
        )
    return net


def _points(dtype, members=2, n=40):
    g = torch.Generator().manual_seed(3)
    return torch.rand(members, n, generator=g, dtype=dtype), torch.rand(
        members, n, generator=g, dtype=dtype
    )


def _max_rel(a, b):
    comps = [(a.dx(k), b.dx(k)) for k in range(5)] + [(a.dt(k), b.dt(k)) for k in (1, 2)]
    return max(
        float((x - y).abs().max() / y.abs().max())
        for x, y in ((x.detach(), y.detach()) for x, y in comps)
    )


@pytest.mark.parametrize("kw", CASES)
@pytest.mark.parametrize("dtype,tol", [(torch.float32, TOL_F32), (torch.float64, TOL_F64)])
def test_taylor_matches_autograd(kw, dtype, tol):
    net = _net(dtype, **kw)
    xi, tau = _points(dtype)
    ref = net.jet(xi, tau, 4, 2, engine="autograd")
    for engine in ("taylor", "taylor-unfused"):
        assert _max_rel(net.jet(xi, tau, 4, 2, engine=engine), ref) < tol


def test_parameter_gradients_agree():
    """One ordinary backward through the fused jets gives the nested-autograd parameter gradients."""
    net = _net(torch.float64)
    xi, tau = _points(torch.float64)
    grads = {}
    for engine in ("taylor", "taylor-unfused", "autograd"):
        net.zero_grad()
        j = net.jet(xi, tau, 4, 2, engine=engine)
        loss = ((net.EI_ratio[:, None] * j.dx(4) / 48 + 0.1 * j.dt(2) - 1) ** 2).mean() + (
            j.dx(2) ** 2
        ).mean()
        loss = loss + (j.dt(1) ** 2).mean() + (j.value**2).mean()
        loss.backward()
        grads[engine] = torch.cat([p.grad.flatten() for p in net.parameters() if p.numel()])
    ref = grads["autograd"]
    for engine in ("taylor", "taylor-unfused"):
        assert float((grads[engine] - ref).abs().max() / ref.abs().max()) < TOL_F64


def test_lower_orders_are_consistent():
    """Asking for fewer derivatives gives the same leading components."""
    net = _net(torch.float64)
    xi, tau = _points(torch.float64)
    full = net.jet(xi, tau, 4, 2)
    part = net.jet(xi, tau, 2, 1)
    assert torch.allclose(part.value, full.value, rtol=0, atol=1e-14)
    assert torch.allclose(part.dx(2), full.dx(2), rtol=1e-12, atol=1e-12)
    assert torch.allclose(part.dt(1), full.dt(1), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("kw", CASES)
def test_basis_jet_contracts_to_the_output(kw):
    net = _net(torch.float64, **kw)
    xi, tau = _points(torch.float64)
    j, B, c = net.jet(xi, tau, 4, 2), net.basis_jet(xi, tau, 4, 2), net.head
    contract = lambda t: torch.einsum("mnd,md->mn", t, c)  # noqa: E731
    for k in range(5):
        assert torch.allclose(contract(B.dx(k)), j.dx(k), rtol=1e-10, atol=1e-10)
    for k in (1, 2):
        assert torch.allclose(contract(B.dt(k)), j.dt(k), rtol=1e-10, atol=1e-10)


def test_members_are_independent():
    """Member m of a batched network computes what the same weights compute alone."""
    net = _net(torch.float64, members=3)
    xi, tau = _points(torch.float64, members=3)
    j = net.jet(xi, tau, 4, 2)
    single = PINN(24, 3, members=1, dtype=torch.float64)
    state = {k: v[1:2] for k, v in net.state_dict().items()}
    single.load_state_dict(state)
    js = single.jet(xi[1:2], tau[1:2], 4, 2)
    assert torch.allclose(js.dx(4), j.dx(4)[1:2], rtol=1e-12, atol=1e-9)


def test_hard_constraints_hold_exactly():
    net = _net(torch.float64, hard_bc=True, hard_ic=True)
    t = torch.rand(2, 30, dtype=torch.float64)
    for end in (0.0, 1.0):
        j = net.jet(torch.full_like(t, end), t, 2, 0)
        assert float(j.value.abs().max()) < 1e-12 and float(j.dx(2).abs().max()) < 1e-10
    j = net.jet(
        torch.rand(2, 30, dtype=torch.float64), torch.zeros(2, 30, dtype=torch.float64), 0, 1
    )
    assert float(j.value.abs().max()) < 1e-14 and float(j.dt(1).abs().max()) < 1e-12


def test_static_enrichment_solves_the_gaussian_load():
    """E_xixixixi / 48 is the Gaussian load with its images; E and E_xixi vanish at both supports."""
    from bayespinn.pinn.losses import moving_load
    from bayespinn.pinn.problem import ProblemTensors

    enr = StaticEnrichment((0.7, 1.0), (0.0, 0.25), 1.3, 0.03)
    g = torch.Generator().manual_seed(5)
    xi, tau = (
        torch.rand(1, 500, generator=g, dtype=torch.float64),
        torch.rand(1, 500, generator=g, dtype=torch.float64),
    )
    z = torch.zeros(1, dtype=torch.float64)
    pt = ProblemTensors(
        xi,
        tau,
        z,
        z,
        z,
        False,
        True,
        None,
        None,
        torch.tensor(enr.loads, dtype=torch.float64),
        torch.tensor(enr.delays, dtype=torch.float64),
        enr.speed,
        torch.tensor(enr.beta_rel, dtype=torch.float64),
        1 / 48,
        0.0,
    )
    f = moving_load(xi, tau, pt, images=True)
    j = enr.jet(xi, tau, 4, 2)
    # series truncated where g_n < 1e-9 (enrich.SERIES_TOL); the load peaks at ~1/(beta sqrt(pi)) ~ 19
    assert float((j.dx(4)[..., 0] / 48 - f).abs().max()) < 1e-6
    for end in (0.0, 1.0):
        jb = enr.jet(torch.full_like(tau, end), tau, 2, 0)
        assert float(jb.value.abs().max()) < 1e-12 and float(jb.dx(2).abs().max()) < 1e-10


def test_free_vibrations_solve_the_homogeneous_equation():
    """Each free-vibration feature solves theta / 48 w_xixixixi + c w_tautau = 0 after its event (undamped),
    with c = theta pi^4 / (48 W_1^2 exp(s)) fixed by the dispersion relation, and vanishes at the supports."""
    fv = FreeVibration((0.0, 0.4), 2, 30.0, 0.0)
    g = torch.Generator().manual_seed(6)
    xi, tau = (
        torch.rand(1, 400, generator=g, dtype=torch.float64),
        torch.rand(1, 400, generator=g, dtype=torch.float64),
    )
    s = torch.tensor([0.1], dtype=torch.float64)
    j = fv.jet(xi, tau, 4, 2, s)
    theta = float(torch.exp(s))
    c = theta * torch.pi**4 / (48 * 30.0**2 * theta)
    r = theta / 48 * j.dx(4) + c * j.dt(2)
    assert float(r.abs().max()) < 1e-9 * float(j.dx(4).abs().max())
    jb = fv.jet(torch.ones_like(tau), tau, 2, 0, s)
    assert float(jb.value.abs().max()) < 1e-12 and float(jb.dx(2).abs().max()) < 1e-9


def test_static_enrichment_reuses_the_jet_of_the_same_points():
    """The enrichment's jet is kept per point set: the same tensors give the same Jet object, new or
    modified tensors a fresh one, and a copy made by pickling starts empty (it carries no tensors)."""
    import pickle

    enr = StaticEnrichment((0.7, 1.0), (0.0, 0.25), 1.3, 0.03)
    xi, tau = torch.rand(1, 50, dtype=torch.float64), torch.rand(1, 50, dtype=torch.float64)
    j = enr.jet(xi, tau, 4, 2)
    assert enr.jet(xi, tau, 4, 2) is j
    assert enr.jet(xi, tau, 2, 0) is not j  # other orders: another entry
    other = xi.clone()
    j2 = enr.jet(other, tau, 4, 2)
    assert j2 is not j and torch.equal(j2.dx(4), j.dx(4))
    other.mul_(0.5)  # modified in place: a miss, and the new values
    assert torch.equal(enr.jet(other, tau, 4, 2).value, enr._jet(other, tau, 4, 2).value)
    grad_xi = xi.clone().requires_grad_(True)  # points with gradients are never cached
    assert enr.jet(grad_xi, tau, 1, 0).value.requires_grad
    copy = pickle.loads(pickle.dumps(enr))
    assert copy == enr and not copy._cache.items and len(pickle.dumps(enr)) < 2000
