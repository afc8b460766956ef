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
