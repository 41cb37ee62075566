"""Ray backends: Embree (``embreex``, optional) answers the same shadow-ray queries as Warp.

The Embree tests skip when ``embreex`` is not installed (it is the optional ``embree`` extra,
not part of ``.[test]``); the choice and fallback of :func:`ray_backend` are tested either way.
"""

from __future__ import annotations

import numpy as np
import pytest

from warpshade._wp import wp
from warpshade.geometry._bvh import Visibility, trace_occlusion_f64
from warpshade.geometry._embree import (
    BACKEND_DISAGREEMENT_TOLERANCE,
    RAYS_ENV,
    EmbreeOcclusion,
    embree_available,
    ray_backend,
)
from warpshade.scene import Mesh, Scene
from warpshade.transfer import TransferTracer, sample_rays

needs_embree = pytest.mark.skipif(not embree_available(), reason="embreex not installed (pip install -e '.[embree]')")

#: The two backends trace the same float32 rays; their transfer sums agree to float32 rounding of
#: the accumulation (the same kernel sums the same answers: exactly equal unless a ray flips).
ATOL_TRANSFER = 1.0e-6


def _blocks_scene() -> Scene:
    """A ground grid with two boxes on it: open and occluded directions, edges and corners."""
    import trimesh

    ground = trimesh.creation.box(extents=(4.0, 4.0, 0.1))
    ground = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(ground.vertices, ground.faces, 0.5))
    tall = trimesh.creation.box(extents=(0.6, 0.6, 1.5))
    tall.apply_translation((0.5, 0.2, 0.8))
    ball = trimesh.creation.icosphere(2, radius=0.4)
    ball.apply_translation((-0.8, -0.5, 0.5))
    return Scene.from_meshes([Mesh("ground", ground.vertices, ground.faces), Mesh("tall", tall.vertices, tall.faces),
                              Mesh("ball", ball.vertices, ball.faces)])


def test_ray_backend_choice(monkeypatch):
    monkeypatch.delenv(RAYS_ENV, raising=False)
    assert ray_backend(None, "cpu") == "warp"
    assert ray_backend("warp", "cpu") == "warp"
    monkeypatch.setenv(RAYS_ENV, "warp")
    assert ray_backend(None, "cpu") == "warp"
    with pytest.raises(ValueError, match="rays must be one of"):
        ray_backend("optix", "cpu")
    monkeypatch.setenv(RAYS_ENV, "bogus")
    with pytest.raises(ValueError, match=RAYS_ENV):
        ray_backend(None, "cpu")


def test_missing_embreex_falls_back_with_one_line(monkeypatch, capsys):
    import warpshade.geometry._embree as embree

    monkeypatch.setattr(embree, "embree_available", lambda: False)
    monkeypatch.setattr(embree, "_said", set())
    assert ray_backend("embree", "cpu") == "warp"
    assert ray_backend("embree", "cpu") == "warp"
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "embreex is not installed" in err[0] and "Warp" in err[0]


@needs_embree
def test_embree_backend_resolves_on_cpu(monkeypatch):
    monkeypatch.setenv(RAYS_ENV, "embree")
    assert ray_backend(None, "cpu") == "embree"


@needs_embree
def test_embree_matches_warp_and_float64_on_explicit_rays():
    scene = _blocks_scene()
    frame = float(scene.frames[0])
    origins, directions = sample_rays(scene, frame, 64, device="cpu")
    origins, directions = origins.reshape(-1, 3), directions.reshape(-1, 3)
    warp_hits = Visibility.from_scene(scene, frame, device="cpu").occluded(origins, directions).numpy().astype(bool)
    embree = EmbreeOcclusion(scene.points_at(frame), scene.faces, workers=1)
    embree_hits = embree.occluded(origins, directions).astype(bool)
    exact = trace_occlusion_f64(scene.points_at(frame), scene.faces, origins, directions)
    assert 0.1 < embree_hits.mean() < 0.9  # both answers occur
    assert np.mean(embree_hits != warp_hits) <= BACKEND_DISAGREEMENT_TOLERANCE
    assert np.mean(embree_hits != exact) <= BACKEND_DISAGREEMENT_TOLERANCE
    # unnormalised directions and a finite max distance mean the same as for Warp
    scaled = directions * 3.0
    near = Visibility.from_scene(scene, frame, device="cpu").occluded(origins, scaled, max_distance=0.5).numpy()
    assert np.mean(embree.occluded(origins, scaled, max_distance=0.5) != near) <= BACKEND_DISAGREEMENT_TOLERANCE
    assert embree.occluded(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0,)


@needs_embree
def test_embree_worker_processes_give_the_same_answers(monkeypatch):
    import warpshade.geometry._embree as embree

    scene = _blocks_scene()
    frame = float(scene.frames[0])
    origins, directions = sample_rays(scene, frame, 32, device="cpu")
    origins, directions = origins.reshape(-1, 3), directions.reshape(-1, 3)
    monkeypatch.setattr(embree, "EMBREE_PARALLEL_MIN_RAYS", 1)  # split even this small batch
    local = EmbreeOcclusion(scene.points_at(frame), scene.faces, workers=1).occluded(origins, directions)
    split = EmbreeOcclusion(scene.points_at(frame), scene.faces, workers=2)
    np.testing.assert_array_equal(split.occluded(origins, directions), local)
    # moved points: the workers rebuild their scene
    moved = scene.points_at(frame) + np.array([0.0, 0.0, 10.0])
    split.update(moved)
    np.testing.assert_array_equal(split.occluded(origins, directions),
                                  EmbreeOcclusion(moved, scene.faces, workers=1).occluded(origins, directions))
    split.close()


def _flipped_receivers(scene, frame, samples: int) -> np.ndarray:
    """Receivers (rows of ``sample_rays``) with a ray that Warp and Embree answer differently."""
    origins, directions = sample_rays(scene, frame, samples, device="cpu")
    shape = origins.shape[:2]
    origins, directions = origins.reshape(-1, 3), directions.reshape(-1, 3)
    warp_hits = Visibility.from_scene(scene, frame, device="cpu").occluded(origins, directions).numpy()
    embree_hits = EmbreeOcclusion(scene.points_at(frame), scene.faces, workers=1).occluded(origins, directions)
    return np.nonzero((warp_hits != embree_hits).reshape(shape).any(axis=1))[0]


@needs_embree
@pytest.mark.parametrize("space", ["world", "local"])
def test_transfer_bake_is_the_same_with_either_backend(space):
    """Receivers whose rays both backends answer alike get the same sums; the few others (a ray
    grazing the box's edge on the ground) differ by those rays only."""
    scene = _blocks_scene()
    frame = float(scene.frames[0])
    samples = 64
    out = {}
    for rays in ("warp", "embree"):
        tracer = TransferTracer(scene, 3, samples, space=space, device="cpu", rays=rays, progress=rays == "embree")
        assert tracer.rays == rays
        tracer.trace(frame)
        out[rays] = tracer.result()
    flipped = _flipped_receivers(scene, frame, samples)
    assert flipped.size <= 0.01 * scene.vertex_count
    same = np.setdiff1d(np.arange(scene.vertex_count), flipped)
    for name in ("visibility", "transfer", "ambient_occlusion"):
        a, b = getattr(out["embree"], name), getattr(out["warp"], name)
        np.testing.assert_allclose(a[same], b[same], rtol=0, atol=ATOL_TRANSFER, err_msg=name)
    # the others (a corner where the box meets the ground) differ by their grazing rays only
    per_ray = 4.0 * np.pi / samples * 0.5 / np.sqrt(np.pi)  # one ray's share of the constant coefficient
    grazing = np.abs(out["embree"].visibility[flipped, 0] - out["warp"].visibility[flipped, 0]) / per_ray
    assert np.all(grazing <= samples / 8), grazing


@needs_embree
def test_transfer_tracer_on_a_bvh_kept_by_others_uses_its_points():
    """``launch`` (a BVH refit elsewhere, as a FrameState's) traces the BVH's current points."""
    scene = _blocks_scene()
    frame = float(scene.frames[0])
    state = scene.evaluate(frame, device="cpu")
    bvh = Visibility.over(state.points, scene.faces)
    warp = TransferTracer(scene, 2, 32, device="cpu", bvh=bvh, rays="warp")
    embree = TransferTracer(scene, 2, 32, device="cpu", bvh=bvh, rays="embree")
    for tracer in (warp, embree):
        tracer.launch(state.points, state.normals)
    wp.synchronize_device("cpu")
    same = np.setdiff1d(np.arange(scene.vertex_count), _flipped_receivers(scene, frame, 32))
    np.testing.assert_allclose(embree.transfer_sh.numpy()[same], warp.transfer_sh.numpy()[same], rtol=0, atol=ATOL_TRANSFER)
