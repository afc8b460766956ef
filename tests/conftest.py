import os


def _give_each_xdist_worker_its_own_cores() -> None:
    """Under pytest-xdist (the default run: `-n auto`, one worker per core), pin each worker to its own
    share of this process's cores and tell BLAS/OpenMP so, before numpy or torch start their thread pools.

    Every process a test starts (a CLI subprocess, a two-worker pool, Ray) inherits the share, so the
    suite never runs more busy threads than the machine has cores, and a test that compares one worker
    with two still runs both (on the share's cores)."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    if not worker.startswith("gw") or not hasattr(os, "sched_setaffinity"):
        return
    cores = sorted(os.sched_getaffinity(0))
    n = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if n < 1 or n > len(cores):
        return  # more workers than cores: nothing to share out
    per = len(cores) // n
    i = int(worker[2:]) % n
    os.sched_setaffinity(0, cores[i * per : (i + 1) * per])
    # bayespinn.executor._THREAD_VARS, spelt out: importing bayespinn here would load numpy too early
    for v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ[v] = str(per)


_give_each_xdist_worker_its_own_cores()

import numpy as np  # noqa: E402 - after the thread settings above
import pytest  # noqa: E402

from bayespinn.uq.arviz_import import import_arviz  # noqa: E402

# every test process imports ArviZ here, once, through the guard against its stamp-file race (two
# workers importing it in the same second); test modules' own `import arviz` then finds it loaded
import_arviz()

os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(autouse=True)
def _no_global_randomness():
    """Library code must not depend on global RNG state: scramble it before every test."""
    np.random.seed(12345)
    yield


@pytest.fixture(scope="session")
def exeter():
    from bayespinn.config import preset

    return preset("deflection")


@pytest.fixture(scope="session")
def exeter_strain():
    from bayespinn.config import preset

    return preset("strain")


@pytest.fixture(autouse=True, scope="session")
def _one_torch_thread():
    """Tests train tiny networks: one intra-op thread is faster and never oversubscribes the cores."""
    import torch

    torch.set_num_threads(1)
    yield


@pytest.fixture(scope="session")
def smoke_fit():
    """A smoke-profile PINN fit of the Exeter deflection case at 20 dB: (config, data, problem, fit)."""
    from bayespinn.config import preset
    from bayespinn.data.synthetic import simulate
    from bayespinn.pinn import Problem, TrainSettings, fit

    cfg = preset()
    data = simulate(cfg, 20.0, 1)
    problem = Problem.from_config(cfg, data)
    # Adam (not varpro): varpro fits the supports so well that the dense observation-space checks of the
    # last-layer marginal become too ill-conditioned to be a reference
    res = fit(problem, TrainSettings.for_profile("smoke", optimizer="adam"), seed=0, quiet=True)
    return cfg, data, problem, res


@pytest.fixture(scope="module")
def study(request):
    """The `studies/` script named by the test module's `STUDY_SCRIPT`, imported with `studies/` on the
    path while the module's tests run (the scripts import each other by name)."""
    import importlib
    import sys
    from pathlib import Path

    studies = str(Path(__file__).resolve().parents[1] / "studies")
    sys.path.insert(0, studies)
    try:
        yield importlib.import_module(request.module.STUDY_SCRIPT)
    finally:
        sys.path.remove(studies)
