"""hybrid.visibility_transfer: local or world-frame SH visibility as world-frame diffuse transfer
(the control of hybrid.trace), against the float64 mirrors and the exact clamped cosine of an open
vertex; SHEXP's blocker spheres as control through stages_for("shexp")."""

import numpy as np
import pytest
import trimesh

from warpshade._wp import wp
from warpshade.basis import quadrature, sh
from warpshade.basis.sh_warp import sh_kernels
from warpshade.graph import GraphSpec, StageError, StageSpec
from warpshade.methods.hybrid import stages_for, visibility_transfer_f64, world_visibility_transfer_f64
from warpshade.methods.hybrid._kernels import visibility_transfer_kernel, world_visibility_transfer_kernel
from warpshade.scene import Environment, Mesh, Scene

from tolerances import assert_close

ORDER = 6
#: float32 product (Gaunt table sums of ~100 terms) and rotation against float64, coefficients <= ~3.
ATOL_TRANSFER = 5e-5
#: An open vertex (visibility 1 everywhere): the order-6 product of 1 and the clamped cosine is the
#: clamped cosine itself (exact), against a 40 000-point quadrature of max(0, n.w).
ATOL_OPEN = 1e-3


def _random_frames(rng, count):
    q, _ = np.linalg.qr(rng.standard_normal((count, 3, 3)))
    q *= np.sign(np.linalg.det(q))[:, None, None]
    return q


def _run(device, vis, frames):
    dev = wp.get_device(device)
    v = vis.shape[0]
    out = wp.zeros((v, ORDER * ORDER), dtype=wp.float32, device=dev)
    wp.launch(visibility_transfer_kernel(ORDER), dim=v, device=dev,
              inputs=[wp.array(vis.astype(np.float32), dtype=wp.float32, device=dev),
                      wp.array(frames.astype(np.float32), dtype=wp.mat33, device=dev),
                      wp.array(sh.clamped_cosine_sh(ORDER).astype(np.float32), dtype=wp.float32, device=dev),
                      sh_kernels(ORDER).tables(dev), 0, out])
    return out.numpy()


def test_visibility_transfer_matches_mirror(device, rng):
    v = 16
    vis = 0.3 * rng.standard_normal((v, ORDER * ORDER))
    frames = _random_frames(rng, v)
    assert_close(_run(device, vis, frames), visibility_transfer_f64(vis, frames, ORDER), atol=ATOL_TRANSFER,
                 what="world-frame transfer")


def test_open_vertex_gives_the_clamped_cosine_about_its_normal(device, rng):
    v = 5
    vis = np.zeros((v, ORDER * ORDER))
    vis[:, 0] = 2.0 * np.sqrt(np.pi)  # SH of the constant 1
    frames = _random_frames(rng, v)
    q = quadrature.fibonacci(40000)
    exact = np.maximum(0.0, frames[:, 2, :] @ q.directions.T) @ (sh.basis(q.directions, ORDER) * q.weights[:, None])
    assert_close(_run(device, vis, frames), exact, atol=ATOL_OPEN, what="clamped cosine of an open vertex")


# -- space = "world": world-frame visibility (SHEXP's), the cosine about the vertex normal --------

#: SHEXP's visibility order on the blockers (zero-padded to the transfer's order 6).
WORLD_VIS_ORDER = 4


def _run_world(device, vis, normals, order=ORDER, vis_order=WORLD_VIS_ORDER):
    dev = wp.get_device(device)
    v = vis.shape[0]
    out = wp.zeros((v, order * order), dtype=wp.float32, device=dev)
    wp.launch(world_visibility_transfer_kernel(order, vis_order), dim=v, device=dev,
              inputs=[wp.array(vis.astype(np.float32), dtype=wp.float32, device=dev),
                      wp.array(normals.astype(np.float32), dtype=wp.vec3, device=dev),
                      wp.array(sh.clamped_cosine_zh(order, "zh").astype(np.float32), dtype=wp.float32, device=dev),
                      sh_kernels(order).tables(dev), 0, out])
    return out.numpy()


def test_world_visibility_transfer_matches_mirror(device, rng):
    v = 16
    vis = 0.3 * rng.standard_normal((v, WORLD_VIS_ORDER ** 2))
    normals = rng.standard_normal((v, 3)) * rng.uniform(0.5, 2.0, (v, 1))  # not unit: the kernel normalises
    normals[3] = 0.0  # no normal: no control
    got = _run_world(device, vis, normals)
    assert np.all(got[3] == 0.0)
    assert_close(got, world_visibility_transfer_f64(vis, normals, ORDER), atol=ATOL_TRANSFER, what="world-frame transfer")


def test_world_visibility_transfer_equals_local_path_in_the_tangent_frame(device, rng):
    """The same visibility given in the world frame and in a tangent frame (rotated into it) gives
    the same transfer by both paths: the two kernels are independent implementations."""
    v = 8
    frames = _random_frames(rng, v)
    world = np.zeros((v, ORDER * ORDER))
    world[:, : WORLD_VIS_ORDER ** 2] = 0.3 * rng.standard_normal((v, WORLD_VIS_ORDER ** 2))
    local = sh.rotate(world, frames)  # R(F): world -> tangent frame (rows t, b, n)
    assert_close(_run_world(device, world[:, : WORLD_VIS_ORDER ** 2], frames[:, 2, :]), _run(device, local, frames),
                 atol=2 * ATOL_TRANSFER, what="world path against the tangent-frame path")


def test_world_open_vertex_gives_the_clamped_cosine(device, rng):
    v = 5
    vis = np.zeros((v, WORLD_VIS_ORDER ** 2))
    vis[:, 0] = 2.0 * np.sqrt(np.pi)
    normals = rng.standard_normal((v, 3))
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    q = quadrature.fibonacci(40000)
    exact = np.maximum(0.0, n @ q.directions.T) @ (sh.basis(q.directions, ORDER) * q.weights[:, None])
    assert_close(_run_world(device, vis, normals), exact, atol=ATOL_OPEN, what="clamped cosine of an open vertex")


def test_world_visibility_order_above_the_transfer_is_refused():
    with pytest.raises(ValueError, match="visibility order 7"):
        world_visibility_transfer_kernel(6, 7)


# -- SHEXP's blocker spheres as control (stages_for("shexp")) -------------------------------------

#: Per-frame variance of the one-frame estimate (diagnostic ``variance_rel``) with SHEXP's spheres as
#: control, relative to no control, on a sphere over a plane: the spheres bound the blocker closely,
#: so the residual the rays estimate is the few-percent error of SHEXP (measured 0.2-0.3).
VARIANCE_RATIO_SHEXP = 0.6
#: shexp.blockers settings of a quick fit (a few spheres bound a ball closely).
FAST_FIT = {"budget": 4, "grid_cells": 4000, "teleports": 0}


def _plane_sphere(frames=3):
    quad = np.array([[-1.5, -1.5, 0.0], [1.5, -1.5, 0.0], [1.5, 1.5, 0.0], [-1.5, 1.5, 0.0]])
    plane = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(quad, np.array([[0, 1, 2], [0, 2, 3]]), 0.2))
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.4)
    xf = np.repeat(np.eye(4)[None], frames, axis=0)
    xf[:, 3, 2] = 0.7
    xf[:, 3, 0] = np.linspace(-0.3, 0.3, frames)
    meshes = [Mesh("/plane", plane.vertices, plane.faces),
              Mesh("/ball", ball.vertices, ball.faces, animation="rigid", transforms=xf)]
    return Scene.from_meshes(meshes, frames=range(frames), lights=[Environment.sky(sun_radiance=(0.0, 0.0, 0.0))])


def _hybrid_graph(control, order=4, **trace):
    stages = stages_for(control, 16, order=order, trace={"alpha": 1.0, "filter_iterations": 0, **trace})
    # a small sphere fit (the ball is the only closed mesh; the open plane blocks as a disc)
    stages = [(n, t, {**p, **FAST_FIT}, i) if t == "shexp.blockers" else (n, t, p, i) for n, t, p, i in stages]
    return GraphSpec([StageSpec(n, t, p, i) for n, t, p, i in stages], "shade.radiance", name=f"hybrid-{control}")


def test_shexp_control_lowers_the_variance_and_stays_bounded(device):
    scene = _plane_sphere()
    variance = {}
    for control in ("none", "shexp"):
        rt = _hybrid_graph(control).compile(scene, device=device, cache_dir=None, progress=False)
        for f in scene.frames:
            out = rt.step(f).numpy()
            assert np.all(np.isfinite(out)), control
        trace = next(s for s in rt.frame_stages if s.name == "trace")
        variance[control] = trace.diagnostics()["variance_rel"]
    assert variance["shexp"] < VARIANCE_RATIO_SHEXP * variance["none"], variance


def test_visibility_order_above_the_order_is_refused_by_the_stage(device):
    spec = GraphSpec([StageSpec("tables", "shexp.tables", {"order": 4}),
                      StageSpec("blockers", "shexp.blockers", FAST_FIT),
                      StageSpec("spheres", "shexp.visibility", {"order": 4}),
                      StageSpec("model", "hybrid.visibility_transfer", {"order": 3, "space": "world", "visibility_order": 4},
                                {"visibility": "spheres.visibility"})], "model.transfer", name="bad-order")
    with pytest.raises((StageError, ValueError), match="visibility_order"):
        spec.compile(_plane_sphere(), device=device, cache_dir=None, progress=False)
