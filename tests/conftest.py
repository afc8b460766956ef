import os

import numpy as np
import pytest

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
