"""The PINN methods on real girders (`uq.girder_pinn`): the pieces of the girder PINN's physics, the exactness
of its last-layer likelihood, and both PINN methods against the modal reference on one damaged girder."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from bayespinn.config import resolve
from bayespinn.data.synthetic import simulate
from bayespinn.methods import REFERENCE_KEY
from bayespinn.uq import girder_net as N
from bayespinn.uq import girder_pinn as G
from bayespinn.uq.girder_reference import girder_reference

REPO = Path(__file__).resolve().parents[1]
DAMAGED = REPO / "examples" / "damaged-girder.toml"


def _cli(*args):
    return subprocess.run(
        [sys.executable, "-m", "bayespinn", *args], capture_output=True, text=True, timeout=900
    )


@pytest.fixture(scope="module")
def damaged():
    """Two segments (the second at 70 %), 60 deflection points at 30 dB: small enough for the default tier."""
    cfg = resolve(
        "deflection",
        {
            "beam": {"EI": [1.03361e9, 7.2353e8]},
            "model": {"EI_segments": 2, "EI_nominal": 1.03361e9},
            "data": {"n_points": 60},
        },
    )
    data = simulate(cfg, 30.0, seed=3)
    return cfg, data


@pytest.fixture(scope="module")
def last_layer(damaged):
    cfg, data = damaged
    pr = G.GirderProblem(data, cfg)
    s = G.GirderNetSettings.for_profile("smoke")
    fit = G.train_fit(pr, s, np.random.SeedSequence(1))
    return pr, G.GirderLastLayer(pr, fit, s, np.random.SeedSequence(2)), fit


def test_segment_indicators_sum_to_one_and_their_derivatives_are_exact(damaged):
    cfg, data = damaged
    pr = G.GirderProblem(data, cfg)
    xi = torch.linspace(0, 1, 201, dtype=torch.float64, requires_grad=True)
    chi, chi1, chi2 = pr.chi(xi)
    assert torch.allclose(chi.sum(0), torch.ones(201, dtype=torch.float64))
    assert torch.allclose(chi1.sum(0), torch.zeros(201, dtype=torch.float64), atol=1e-9)
    assert torch.allclose(chi2.sum(0), torch.zeros(201, dtype=torch.float64), atol=1e-6)
    for s in range(pr.S):
        (d1,) = torch.autograd.grad(pr.chi(xi)[0][s].sum(), xi, create_graph=True)
        (d2,) = torch.autograd.grad(d1.sum(), xi)
        assert torch.allclose(d1, chi1[s], rtol=1e-9, atol=1e-9)
        assert torch.allclose(d2, chi2[s], rtol=1e-7, atol=1e-6)
    # the first segment is 1 at the left support, 0 at the right; the edge sits at xi = 1/2
    assert (
        chi[0, 0] > 0.999 and chi[0, -1] < 1e-3 and abs(float(chi[0, 100].detach()) - 0.5) < 1e-12
    )


def test_support_rows_go_from_a_pin_to_a_clamp():
    """(alpha, beta) of the rows theta w'' -/+ kappa w' (normalised): (1, 0) for pins, (0, -/+1) for clamps."""
    cfg = resolve("deflection", {"model": {"EI_segments": 1, "supports": "springs"}})
    data = simulate(cfg, 30.0, seed=0)
    pr = G.GirderProblem(data, cfg)
    for logk, want_l, want_r in ((-20.0, (1, 0), (1, 0)), (60.0, (0, -1), (0, 1))):
        phi = torch.tensor([np.log(1e9), logk, logk], dtype=torch.float64)
        _, left, right, lam = pr.coefficients(phi)
        assert np.allclose(left.numpy(), want_l, atol=1e-6)
        assert np.allclose(right.numpy(), want_r, atol=1e-6)
        assert float(lam) == 1.0


def test_enrichment_gradient_is_its_derivative(damaged):
    cfg, data = damaged
    pr = G.GirderProblem(data, cfg)
    phi = torch.tensor(pr.phi0, dtype=torch.float64, requires_grad=True)
    w = torch.linspace(-1, 1, len(data), dtype=torch.float64)
    (g,) = torch.autograd.grad(N.enrichment_column(pr, phi) @ w, phi)
    h = 1e-6  # the column's own central differences step 1e-4: truncation ~1e-5 relative
    for i in range(pr.n_phys):
        e = np.zeros(pr.dim)
        e[i] = h
        fd = (pr.enrichment(pr.phi0 + e)[0] - pr.enrichment(pr.phi0 - e)[0]) @ w.numpy() / (2 * h)
        assert abs(float(g[i]) - fd) <= 1e-4 * max(abs(fd), 1e-12)


def test_last_layer_marginal_is_the_dense_gaussian(last_layer):
    """log p(y | phi, sigma) equals log N(y; D mu_p, sigma^2 I + D A_p^-1 D') computed densely, up to one
    constant, at several (phi, sigma); counting the physics as observations instead gives another function
    of phi (negative control)."""
    pr, ll, _ = last_layer
    sig0 = pr.sigma0
    pts = [(pr.phi0, sig0), (pr.phi0 + 0.05, sig0 * 1.3), (pr.phi0 - [0.03, -0.04], sig0 * 0.8)]
    ours, dense, obs = [], [], []
    y = torch.as_tensor(pr.y)
    for phi, sig in pts:
        phit = torch.as_tensor(phi)
        ours.append(float(ll.log_marginal(phit, torch.tensor(np.log(sig), dtype=torch.float64))))
        sc = ll.scales(sig)
        Ap, gp, kp = N.physics(pr, ll.P, phit, sc)
        mu = torch.linalg.solve(Ap, gp)
        E = N.enrichment_column(pr, phit)
        D = torch.cat([ll.P.Phi_d, E[:, None]], 1)
        C = sig**2 * torch.eye(len(y), dtype=torch.float64) + D @ torch.linalg.solve(Ap, D.T)
        r = y - D @ mu
        dense.append(float(-0.5 * r @ torch.linalg.solve(C, r) - 0.5 * torch.linalg.slogdet(C)[1]))
        # physics as observations: the joint Gaussian of data and physics rows with c ~ N(0, s_w^2 I)
        Ad, gd, kd = N.data_terms(pr, ll.P, E, sig)
        A = Ap + Ad
        b = gp + gd
        obs.append(
            float(
                -0.5 * (kd + kp - b @ torch.linalg.solve(A, b))
                - 0.5 * torch.linalg.slogdet(A)[1]
                - len(y) * np.log(sig)
            )
        )
    ours, dense, obs = map(np.array, (ours, dense, obs))
    assert np.allclose(ours - ours[0], dense - dense[0], atol=1e-5)
    assert not np.allclose(obs - obs[0], dense - dense[0], atol=0.1)


def test_batched_log_posterior_equals_the_single_one(last_layer):
    pr, ll, fit = last_layer
    z0 = np.r_[fit.phi, np.log(pr.sigma0)]
    Z = np.vstack([z0, z0 + 0.02, z0 - [0.01, 0.03, 0.1]])
    many = ll.log_post_many(Z)
    one = [float(ll.log_post(torch.as_tensor(z))) for z in Z]
    assert np.allclose(many, one, atol=1e-6)
    far = z0.copy()
    far[0] += 50.0  # outside the prior's support
    assert ll.log_post_many(far[None])[0] == -np.inf


def test_the_network_share_is_the_networks_part(damaged, last_layer, monkeypatch):
    """`network_share` is the share of the fitted response's energy that the network's own columns carry
    beyond the enrichment: within the model, next to nothing (measured 1.6e-6). Negative control: the same
    network trained with the enrichment column set to zero must carry the whole response itself, and its
    share is then 1 (a share that ignored which columns carry the fit would not move)."""
    from bayespinn.uq import girder_lastlayer as GL

    pr, ll, _ = last_layer
    assert 0.0 <= ll.network_share < 1e-3
    zero = lambda problem, phi: torch.zeros(problem.y.size, dtype=torch.float64) + 0 * phi.sum()  # noqa: E731
    monkeypatch.setattr(N, "enrichment_column", zero)
    monkeypatch.setattr(GL, "enrichment_column", zero)
    s = G.GirderNetSettings.for_profile("smoke")
    fit = G.train_fit(pr, s, np.random.SeedSequence(1))
    alone = G.GirderLastLayer(pr, fit, s, np.random.SeedSequence(2))
    assert alone.network_share > 0.9, alone.network_share


def _check(post, ref, S):
    """Per segment: |mean - reference mean| / reference sd and sd / reference sd, in log EI."""
    a = np.log(post.girder.EI_segments.reshape(-1, S))
    b = np.log(ref.girder.EI_segments.reshape(-1, S))
    return (a.mean(0) - b.mean(0)) / b.std(0), a.std(0) / b.std(0)


@pytest.fixture(scope="module")
def reference(damaged):
    cfg, data = damaged
    return girder_reference(data, cfg, seed=np.random.SeedSequence(11), method=REFERENCE_KEY)


def test_importance_sampler_draws_until_its_effective_sample_size_target(last_layer, monkeypatch):
    """A member's importance sampler (adaptive multiple importance sampling, `field_search.amis`) runs at
    least its minimum rounds, then until the pooled effective sample size reaches the convergence verdict's
    target. Negative control: with the target out of reach it draws every round it may, and says the
    effective sample size it reached."""
    from bayespinn.uq import field_search as FS
    from bayespinn.uq import girder_sampling as S

    pr, ll, fit = last_layer
    z = ll.map(ll.start(fit.phi))
    cov = ll.covariance(z)
    smoke = G.GirderNetSettings.for_profile("smoke")
    Z, info = S.importance_sample(ll, z, cov, np.random.default_rng(0), smoke)
    assert Z.shape == (smoke.is_draws, ll.dim)
    assert info["ess"] >= G.ESS_MIN
    assert info["samples"] % FS.DRAWS_PER_ROUND == 0
    assert (
        FS.AMIS_ROUNDS * FS.DRAWS_PER_ROUND
        <= info["samples"]
        < S.IS_MAX_ROUNDS * FS.DRAWS_PER_ROUND
    )
    # the draws are the posterior's: their mean sits at the MAP within a fraction of the Laplace sd
    sd = np.sqrt(np.diag(cov))
    assert np.all(np.abs(Z.mean(0) - z) < 0.5 * sd), (Z.mean(0) - z) / sd
    monkeypatch.setattr(FS, "ESS_MIN", 1e9)
    _, info = S.importance_sample(ll, z, cov, np.random.default_rng(0), smoke)
    assert info["samples"] == S.IS_MAX_ROUNDS * FS.DRAWS_PER_ROUND and info["ess"] < 1e9


def test_pinn_methods_match_the_reference_on_a_damaged_girder(damaged, reference):
    """Smoke profile, two segments (the second at 70 %), 30 dB: each PINN method's segment means within 1.5
    reference sds of the reference's, sds within [0.67, 1.5] of its, the damaged segment flagged. Negative
    control: the same methods on data of axles 15 % heavier than stated (a load the model fixes) miss."""
    cfg, data = damaged
    S = 2
    ens = G.girder_ensemble_posterior(data, cfg, seed=np.random.SeedSequence(5), profile="smoke")
    bp = G.girder_bpinn_posterior(data, cfg, seed=np.random.SeedSequence(6), profile="smoke")
    for post in (ens, bp):
        z, ratio = _check(post, reference, S)
        assert np.all(np.abs(z) < 1.5), (post.method, z)
        assert np.all((ratio > 0.67) & (ratio < 1.5)), (post.method, ratio)
        assert post.girder.p_damaged[1] >= 0.9
        s = post.summary(None)
        assert len(s["EI_segments"]) == S and "p_damaged" in s["EI_segments"][1]
        # within the model the enrichment carries the fit (`test_the_network_share_is_the_networks_part`)
        assert 0.0 <= s["network_share"] < 1e-3, (post.method, s["network_share"])
    # negative control: heavier axles than the configuration states
    heavy = resolve(
        "deflection",
        {
            "beam": {"EI": [1.03361e9, 7.2353e8]},
            "vehicle": {"axles": [{"load": 37000.0 * 1.15, "offset": 0.0}]},
            "data": {"n_points": 60},
        },
    )
    bad = simulate(heavy, 30.0, seed=3)
    miss = G.girder_ensemble_posterior(bad, cfg, seed=np.random.SeedSequence(5), profile="smoke")
    z, _ = _check(miss, reference, S)
    assert np.any(np.abs(z) > 1.5), z


@pytest.fixture(scope="module")
def ar1_damaged():
    """Two segments (the second at 70 %), four strain gauges at 100 Hz, AR(1) noise of coefficient 0.8 at 20
    dB, analysed with the AR(1) likelihood; and the reference on it."""
    cfg = resolve(
        "strain",
        {
            "beam": {"EI": [1.03361e9, 7.2353e8]},
            "model": {"EI_segments": 2, "EI_nominal": 1.03361e9, "noise": "ar1"},
            "data": {"noise_ar1": 0.8, "sample_rate": 100.0},
        },
    )
    data = simulate(cfg, 20.0, seed=3)
    return (
        cfg,
        data,
        girder_reference(data, cfg, seed=np.random.SeedSequence(11), method=REFERENCE_KEY),
    )


def test_ar1_last_layer_batched_equals_the_single_one_and_whitens(ar1_damaged):
    """With AR(1) noise the batched log posterior equals the single one at several (phi, sigma, rho); at rho = 0
    it is the white model's plus the coefficient's prior (the whitening is the identity there), and at the fit
    residuals' rho it is not the white model's (negative control)."""
    from bayespinn.uq.ar1 import AR1Noise

    cfg, data, _ = ar1_damaged
    pr = G.GirderProblem(data, cfg)
    s = G.GirderNetSettings.for_profile("smoke")
    fit = G.train_fit(pr, s, np.random.SeedSequence(1))
    ll = G.GirderLastLayer(pr, fit, s, np.random.SeedSequence(2), AR1Noise.of(data))
    white = G.GirderLastLayer(pr, fit, s, np.random.SeedSequence(2))
    z0 = ll.start(fit.phi)
    assert ll.dim == pr.dim + 2 and 0.6 < np.tanh(z0[-1]) < 0.95
    Z = np.vstack([z0, z0 + 0.02, z0 - [0.01, 0.03, 0.1, 0.2]])
    one = [float(ll.log_post(torch.as_tensor(z))) for z in Z]
    assert np.allclose(ll.log_post_many(Z), one, rtol=0, atol=1e-6 * np.max(np.abs(one)))
    at0 = np.r_[z0[:-1], 0.0]
    w = float(white.log_post(torch.as_tensor(z0[:-1])))
    assert float(ll.log_post(torch.as_tensor(at0))) == pytest.approx(w, abs=1e-6 * abs(w))
    assert abs(one[0] - w) > 10.0


def test_pinn_methods_carry_ar1_noise_on_a_damaged_girder(ar1_damaged):
    """Smoke profile, AR(1) noise (0.8) at 20 dB on two segments: each PINN method's segment means within 1.5
    reference sds of the reference's, sds within [0.67, 1.5] of its, and its coefficient's mean within 2
    reference sds of the reference's. Negative control: the ensemble with the white likelihood on the same
    data is far too narrow (sd ratio under 0.67: correlated noise read as independent)."""
    cfg, data, ref = ar1_damaged
    S = 2
    ens = G.girder_ensemble_posterior(data, cfg, seed=np.random.SeedSequence(5), profile="smoke")
    bp = G.girder_bpinn_posterior(data, cfg, seed=np.random.SeedSequence(5), profile="smoke")
    r_ref = ref.girder.noise_ar1
    for post in (ens, bp):
        z, ratio = _check(post, ref, S)
        assert np.all(np.abs(z) < 1.5), (post.method, z)
        assert np.all((ratio > 0.67) & (ratio < 1.5)), (post.method, ratio)
        r = post.girder.noise_ar1
        assert abs(r.mean() - r_ref.mean()) < 2 * r_ref.std(), (post.method, r.mean(), r_ref.mean())
        assert "noise_ar1" in post.summary(None)
    white = dataclasses.replace(cfg, model=dataclasses.replace(cfg.model, noise="iid"))
    miss = G.girder_ensemble_posterior(data, white, seed=np.random.SeedSequence(5), profile="smoke")
    _, ratio = _check(miss, ref, S)
    assert np.all(ratio < 0.67), ratio


def test_girder_pinns_do_not_depend_on_the_executor(damaged):
    """The girder ensemble's members and the girder B-PINN's chains are executor tasks: one worker and two give
    the same draws (each task single-threaded on its own seed)."""
    from bayespinn.executor import Executor

    cfg, data = damaged
    kw = dict(seed=np.random.SeedSequence(5), members=2, profile="smoke")
    a = G.girder_ensemble_posterior(data, cfg, executor=Executor(workers=1), **kw)
    b = G.girder_ensemble_posterior(data, cfg, executor=Executor(workers=2), **kw)
    assert np.array_equal(a.girder.EI_segments, b.girder.EI_segments)
    kw = dict(seed=np.random.SeedSequence(6), profile="smoke")
    a = G.girder_bpinn_posterior(data, cfg, executor=Executor(workers=1), **kw)
    b = G.girder_bpinn_posterior(data, cfg, executor=Executor(workers=2), **kw)
    assert np.array_equal(a.girder.EI_segments, b.girder.EI_segments)


def test_cli_runs_the_pinn_methods_on_a_girder_with_springs_and_an_uncertain_load(tmp_path):
    """`bayespinn run --method ensemble,bpinn` with springs inferred: summary keys of the contract
    (rotational_stiffness [left, right], EI_segments with p_damaged), fit checks, report written."""
    cfg = tmp_path / "g.toml"
    cfg.write_text(
        '[beam]\nrotational_stiffness = [1.2e8, 1.2e8]\n[model]\nsupports = "springs"\n'
        "[vehicle]\nload_rel_sd = 0.05\n[data]\nn_points = 60\n"
    )
    out = tmp_path / "run"
    r = _cli(
        "run", "--snr", "30", "--method", "ensemble,bpinn", "--profile", "smoke", "--members", "2",
        "--quiet", "--config", str(cfg), "--out", str(out),
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    s = json.loads((out / "summary.json").read_text())
    for key in ("ensemble", "bpinn"):
        m = s["methods"][key]
        assert len(m["rotational_stiffness"]) == 2
        assert m["load_factor"]["ci90"][0] < 1.0 + 0.2 and m["load_factor"]["ci90"][1] > 1.0 - 0.2
        assert m["fit_check"]["verdict"] in ("fits", "misfit")
        assert m["EI"]["ci90"][0] < m["EI"]["ci90"][1]
    assert (
        "B-PINN network: 2 x 16 tanh, enriched with the girder's FE modal response"
        in (out / "report.md").read_text()
    )


def test_pinn_coverage_study_runs_every_method_on_the_reference_datasets(tmp_path):
    """`studies/girder_pinns.py` (1 replicate, smoke profile; the numbers are the plumbing's, not a claim):
    coverage rows per method and parameter, z and sd ratio per segment, and a rerun that recomputes nothing."""
    cfg = tmp_path / "g.toml"
    cfg.write_text(
        "[beam]\nEI = [1.03361e9, 7.2353e8]\n[model]\nEI_segments = 2\n[data]\nn_points = 60\n"
    )
    args = ["--config", str(cfg), "--replicates", "1", "--profile", "smoke", "--members", "2",
            "--out", str(tmp_path), "--quiet"]  # fmt: skip
    script = REPO / "studies" / "girder_pinns.py"
    r = subprocess.run(
        [sys.executable, str(script), *args], capture_output=True, text=True, cwd=REPO
    )
    assert r.returncode == 0, r.stderr[-3000:]
    path = tmp_path / "girder_pinns" / "g-deflection-snr30.json"
    doc = json.loads(path.read_text())
    ms = doc["summary"]["methods"]
    assert set(ms) == {"modal_mcmc", "ensemble", "bpinn"}
    for k in ms:
        assert set(ms[k]["coverage"]) == {"EI", "EI_segments[0]", "EI_segments[1]"}
        assert len(ms[k]["sd_ratio_median"]) == 2
    assert ms["modal_mcmc"]["z_max_abs"] == [0.0, 0.0]
    assert "B-PINN" in (tmp_path / "girder_pinns.md").read_text()
    before = [x["time_s"] for x in doc["records"]]
    r = subprocess.run(
        [sys.executable, str(script), *args], capture_output=True, text=True, cwd=REPO
    )
    assert r.returncode == 0
    assert [x["time_s"] for x in json.loads(path.read_text())["records"]] == before

    # a study of an older commit resumes: its replicates are kept, and the page names their commit
    doc = json.loads(path.read_text())
    assert all("git_commit" in x for x in doc["records"])
    for x in doc["records"]:
        x.update(git_commit="0123456789abcdef", git_dirty=False)
    path.write_text(json.dumps(doc))
    r = subprocess.run(
        [sys.executable, str(script), *args], capture_output=True, text=True, cwd=REPO
    )
    assert r.returncode == 0, r.stderr[-3000:]
    assert [x["time_s"] for x in json.loads(path.read_text())["records"]] == before
    assert "0123456789ab (1)" in (tmp_path / "girder_pinns.md").read_text()
