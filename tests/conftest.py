"""Shared test fixtures: every kernel test runs on the Warp CPU device (and CUDA when present)."""

import numpy as np
import pytest

from warpshade._wp import wp

DEVICES = ["cpu"] + (["cuda:0"] if wp.is_cuda_available() else [])


@pytest.fixture(params=DEVICES)
def device(request):
    """Each kernel test runs once per available Warp device."""
    return request.param


@pytest.fixture
def rng():
    return np.random.default_rng(1234)
