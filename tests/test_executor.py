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


def _strip(res):
    return [(r["hit"], r["rel_error_pct"], r["interval"]) for r in res["records"]]


def _study(executor):
    return coverage_study("modal", preset(), 10.0, replicates=4, seed=3, opts=SMALL, executor=executor, progress=False)


def _warm_parent_cache():
    """Compute the FE crossing in this process with two BLAS threads first: forked workers inherit the
    cache, Ray workers do not, so this is the situation in which a thread-dependent result would show
    (it did in CI before the FE solve was pinned to one thread)."""
    from threadpoolctl import threadpool_limits

    from bayespinn.physics.fem import solve_crossing

    cfg = preset()
    with threadpool_limits(2):
        solve_crossing(cfg.beam, cfg.vehicle)


def test_fe_solution_does_not_depend_on_blas_threads():
    from threadpoolctl import threadpool_limits

    from bayespinn.physics.fem import FEBeam

    cfg = preset()
    T = cfg.vehicle.duration(cfg.beam.length)
    out = []
    for n in (1, 2):
        with threadpool_limits(n):
            out.append(FEBeam(cfg.beam).solve(cfg.vehicle, T).U)
    assert (out[0] == out[1]).all()


def test_local_results_do_not_depend_on_workers():
    _warm_parent_cache()
    one = _study(Executor("local", workers=1))
    two = _study(Executor("local", workers=2))
    assert _strip(one) == _strip(two)


def test_bad_executor_is_input_error():
    from bayespinn.errors import InputError

    with pytest.raises(InputError):
        Executor("dask")


@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="Ray is not installed (pip install 'bayespinn[ray]')")
def test_ray_matches_local():
    import ray

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, ignore_reinit_error=True)
    try:
        _warm_parent_cache()
        local = _study(Executor("local", workers=2))
        remote = _study(Executor("ray"))
        assert _strip(local) == _strip(remote)
    finally:
        ray.shutdown()


def test_replicate_options_are_picklable():
    import pickle

    opts = dataclasses.replace(SMALL, executor=Executor())
    assert pickle.loads(pickle.dumps(opts)) == opts
