"""The fast profile's training length: short, because the last layer decides EI's posterior, but with
fresh points several times and a randomise-then-optimise phase of its own."""

from bayespinn.pinn import TrainSettings
from bayespinn.uq.ensemble import RTO_FRACTION, phase2_settings


def test_fast_profile_trains_briefly_on_four_point_sets():
    fast = TrainSettings.for_profile("fast")
    assert (fast.epochs, fast.resample_every) == (100, 25)
    assert fast.epochs // fast.resample_every == 4  # four collocation sets over the Adam steps
    assert fast.lbfgs_iters == 0 and fast.log_every <= fast.epochs
    # the last layer's pseudo-observations keep their count (the PDE pseudo-sd is stated for them)
    assert (fast.n_pde, fast.n_bc, fast.n_ic) == (2000, 400, 400)


def test_rto_phase_follows_the_profile():
    fast = TrainSettings.for_profile("fast")
    s2 = phase2_settings(fast)
    assert s2.epochs == int(RTO_FRACTION * fast.epochs) == 25
    assert s2.lr == fast.lr * 0.3 and s2.resample_every == fast.resample_every


def test_smoke_profile_is_unchanged():
    s = TrainSettings.for_profile("smoke")
    assert (s.epochs, s.resample_every, s.lbfgs_iters, s.width, s.depth) == (60, 20, 20, 16, 2)
