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


def pytest_addoption(parser):
    parser.addoption("--update-goldens", action="store_true", default=False,
                     help="rewrite tests/golden/*.npz from this run's graph outputs (say why in the commit)")


@pytest.fixture
def update_goldens(request):
    """True when the run was asked to rewrite the golden outputs (``--update-goldens``)."""
    return request.config.getoption("--update-goldens")


class BakeReached(Exception):
    """Raised by the SG bakes under :func:`sg_bake_refused`: the run got past every check."""


@pytest.fixture
def sg_bake_refused(monkeypatch):
    """The SSDF bake and the environment's preparation of ``sg.shade`` raise :class:`BakeReached`:
    a test of a check that must come before any precompute asserts a refusal, or this exception
    when there is nothing to refuse."""
    import warpshade.methods.sg._stages as sg_stages

    def bake(*args, **kwargs):
        raise BakeReached

    monkeypatch.setattr(sg_stages, "bake_ssdf_model", bake)
    monkeypatch.setattr(sg_stages, "environment_lighting", bake)
    return BakeReached
