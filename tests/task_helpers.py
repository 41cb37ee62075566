"""Module-level task functions for tests/test_tasks.py, importable by spawned and Dask workers.

Each task carries its own seed, so its result does not depend on the process that runs it.
"""

import os
import signal
import time
from pathlib import Path

import numpy as np
from grids import ground_grid


def seeded_sum(seed: int) -> float:
    """A number drawn from a per-task RNG (float64, bit-exact on every worker)."""
    rng = np.random.default_rng(seed)
    return float(rng.standard_normal(1000) @ rng.standard_normal(1000))


def slow_seeded(task):
    """``(seed, seconds, marker_dir)``: :func:`seeded_sum` after a sleep, writing
    ``start-<seed>-<pid>`` and ``done-<seed>`` markers into ``marker_dir`` so that a test can see
    which worker runs which task and kill one of them mid-task."""
    seed, seconds, marker_dir = task
    marker_dir = Path(marker_dir)
    (marker_dir / f"start-{seed}-{os.getpid()}").touch()
    time.sleep(seconds)
    value = seeded_sum(seed)
    (marker_dir / f"done-{seed}").touch()
    return value


def fail_on(task):
    """``(value, bad)``: raises ValueError when ``value == bad``, else returns ``value``."""
    value, bad = task
    if value == bad:
        raise ValueError(f"refusing {value}")
    return value


def kill_own_worker_on(task):
    """``(value, bad)``: the worker process SIGKILLs itself when ``value == bad``."""
    value, bad = task
    if value == bad:
        os.kill(os.getpid(), signal.SIGKILL)
    return value


def warp_transfer(seed: int):
    """Ray-traced transfer (a Warp CPU kernel) on a tiny scene built from arrays: a ground quad
    grid under a box; returns the transfer coefficients and ambient occlusion."""
    from warpshade.scene import Mesh, Scene
    from warpshade.transfer import compute

    ground, ground_faces = ground_grid(np.linspace(-1.0, 1.0, 5))
    corners = np.array([[x, y, z] for x in (-0.3, 0.3) for y in (-0.3, 0.3) for z in (0.2, 0.6)])
    box_faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                          [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    scene = Scene.from_meshes([Mesh("ground", ground, ground_faces), Mesh("box", corners, box_faces)])
    result = compute(scene, scene.frames[0], order=2, samples=64, device="cpu", seed=seed)
    return np.asarray(result.transfer), np.asarray(result.ambient_occlusion)
