"""A sampler whose walkers cannot move (every proposal leaves a support far narrower than the cloud's
steps): emcee has no autocorrelation time for such chains. The run must go on to max_steps, keep draws,
and the chain diagnostics must say it has not converged, rather than the sampler failing."""

from __future__ import annotations

import numpy as np

from bayespinn.uq.posterior import mcmc_diagnostics
from bayespinn.uq.sampler import RHAT_MAX, MCMCSettings, sample


def test_walkers_that_cannot_move_end_the_run_unconverged():
    centre = np.array([0.3, -1.0])

    def log_prob(theta):
        th = np.atleast_2d(theta)
        return np.where(np.all(np.abs(th - centre) < 1e-9, axis=1), 0.0, -np.inf)

    s = MCMCSettings(n_walkers=8, n_groups=2, tau_factor=5.0, min_steps=40, max_steps=120, chunk=40)
    ch = sample(log_prob, centre, np.ones(2), s, seed=3)
    assert ch.steps == 120 and ch.draws.shape[2] == 2 and ch.draws.shape[1] > 0
    d = mcmc_diagnostics(ch.draws[:, :, 0])
    assert not (d["rhat"] <= RHAT_MAX and d["ess_bulk"] >= 100)


def test_a_density_the_walkers_can_explore_still_converges():
    """The control: a standard normal in two dimensions meets the same diagnostics."""

    def log_prob(theta):
        th = np.atleast_2d(theta)
        return -0.5 * np.sum(th**2, axis=1)

    s = MCMCSettings(n_walkers=16, n_groups=2, tau_factor=30.0, min_steps=300, max_steps=6000)
    ch = sample(log_prob, np.zeros(2), np.ones(2), s, seed=3)
    d = mcmc_diagnostics(ch.draws[:, :, 0])
    assert d["rhat"] <= RHAT_MAX and d["ess_bulk"] >= 100


def test_walkers_beyond_a_support_edge_at_the_centre_start_inside():
    """The maximum on the support's edge (a half-normal at 0, as a hyperparameter's maximum on its
    table's edge): walkers drawn beyond it never get in by halving towards the centre. They must start
    inside, or emcee compares -inf with -inf and keeps draws outside the support."""
    from bayespinn.uq.sampler import _inside

    def log_prob(theta):
        th = np.atleast_2d(theta)
        return np.where(th[:, 0] >= 0.0, -0.5 * th[:, 0] ** 2, -np.inf)

    p0 = np.random.default_rng(0).standard_normal((16, 1))
    assert (p0 < 0).any()  # the setting: some walkers beyond the edge
    start = _inside(log_prob, np.zeros(1), p0)
    assert np.isfinite(log_prob(start)).all()
    assert np.unique(start).size > 1  # a cloud, not every walker at the centre
    s = MCMCSettings(n_walkers=16, n_groups=1, min_steps=200, max_steps=400)
    ch = sample(log_prob, np.zeros(1), np.ones(1), s, seed=1)
    assert (ch.draws >= 0.0).all()
