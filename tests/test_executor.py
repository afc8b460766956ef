"""Executors: results are a function of the seed only, whatever runs them."""

import dataclasses
import importlib.util

import pytest

from bayespinn.config import preset
from bayespinn.executor import Executor
from bayespinn.uq.coverage import coverage_study
from bayespinn.uq.methods import RunOptions
from bayespinn.uq.sampler import MCMCSettings

SMALL = RunOptions(profile="smoke", mcmc=MCMCSettings(n_walkers=8, n_groups=2, min_steps=250, tau_factor=5.0))


#: Agreement of two runs of the same replicate in two kinds of worker process, in posterior sds.
#: Bit-for-bit equality is not promised across process types: numpy's SIMD reductions can round the
#: last bit differently with the memory alignment of an array, and a few thousand MCMC steps amplify
#: that into a different (equally valid) chain. What must agree is the seeded *dataset* and the
#: posterior up to Monte Carlo error: these tiny chains have ESS ~80, so a mean moves by ~0.11 sd and a
#: 90 % endpoint by ~0.2 sd between two such chains; 0.5 sd is far outside that and far inside the gap
#: to a different dataset (replicates differ by ~1 sd).
SAME_TOL_SD = 0.5


def _same(a, b):
    """Two coverage studies agree replicate by replicate (see SAME_TOL_SD)."""
    assert len(a["records"]) == len(b["records"])
    for ra, rb in zip(a["records"], b["records"], strict=True):
        assert ra["EI_true"] == rb["EI_true"]
        sd = ra["sd_rel_pct"] / 100 * ra["EI_true"]
        tol = SAME_TOL_SD * sd
        assert abs(ra["rel_error_pct"] - rb["rel_error_pct"]) < SAME_TOL_SD * ra["sd_rel_pct"]
        for ea, eb in zip(ra["interval"], rb["interval"], strict=True):
            assert abs(ea - eb) < tol
        # a hit may only differ if the truth lies within the tolerance of an endpoint
        near = min(abs(e - ra["EI_true"]) for e in ra["interval"]) < tol
        assert ra["hit"] == rb["hit"] or near


def _study(executor):
    return coverage_study("modal", preset(), 10.0, replicates=4, seed=3, opts=SMALL, executor=executor, progress=False)


def test_local_results_do_not_depend_on_workers():
    one = _study(Executor("local", workers=1))
    two = _study(Executor("local", workers=2))
    _same(one, two)


def test_bad_executor_is_input_error():
    from bayespinn.errors import InputError

    with pytest.raises(InputError):
        Executor("dask")


def test_agreement_check_has_teeth():
    """Negative control: the same study with a different seed (other datasets) must not pass `_same`."""
    a = _study(Executor("local", workers=2))
    b = coverage_study("modal", preset(), 10.0, replicates=4, seed=4, opts=SMALL, executor=Executor("local", workers=2),
                       progress=False)
    with pytest.raises(AssertionError):
        _same(a, b)


@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="Ray is not installed (pip install 'bayespinn[ray]')")
def test_ray_matches_local():
    import ray

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, ignore_reinit_error=True)
    try:
        local = _study(Executor("local", workers=2))
        remote = _study(Executor("ray"))
        _same(local, remote)
    finally:
        ray.shutdown()


def test_replicate_options_are_picklable():
    import pickle

    opts = dataclasses.replace(SMALL, executor=Executor())
    assert pickle.loads(pickle.dumps(opts)) == opts
