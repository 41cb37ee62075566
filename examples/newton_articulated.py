"""A Newton articulated body built from implicit shapes, simulated and shaded live by warpshade.

Newton's ant (``nv_ant.xml``: a sphere torso and eight capsule leg segments; ``--robot humanoid``
loads ``nv_humanoid.xml``, capsules and spheres) is read from the installed ``newton`` package
(``newton.examples.get_asset``), dropped onto a ground plane with random joint velocities and
driven by a sinusoidal gait of joint position targets, solved with ``SolverXPBD`` (it runs on
the CPU device as on CUDA). Each visible shape of the model -- a Newton sphere, capsule, box,
cylinder, cone or ellipsoid -- is tessellated once, in its body's frame, as warpshade tessellates
the matching implicit USD prim (:func:`warpshade.io.tessellate`), and the shapes
together are one mesh with the same topology at every frame. After each simulated frame a Warp
kernel places every vertex with its body's transform (``State.body_q``) and the points are fed to
a warpshade run compiled once: ``rt.step(0, points={"/World/Body": points})``. The graph is
``prt.trace`` (per-frame ray-traced SH transfer, order 3): the moving body shadows the ground and
itself under a procedural sky. Everything stays on the device between the two; the host sees
only the copies kept for the outputs.

Outputs in ``--out``:

* ``newton_articulated.usda`` -- the body's points (time-sampled) and the ground, each with
  per-vertex ``primvars:displayColor`` (linear RGB radiance) per frame;
* ``newton_articulated_<frame>.png`` -- previews of the first, middle and last frames;
* ``newton_articulated_<frame>_vs_reference.png`` -- method | ray-traced reference | error of
  the measured frames (``--measure``, default 3 of the previewed frames);
* ``newton_articulated.json`` -- the time per frame split into simulation and shading, the device,
  the counts, and the relative RMS error per measured frame against ray-traced ground truth
  (``--truth-samples`` rays per vertex, with the reference's own noise reported beside it).

They are planned like the outputs of ``warpshade run`` (:func:`warpshade.measure.plan_outputs`):
a file of one of those names that this example did not write there itself (the folder's manifest,
``.warpshade-outputs.json``, says which it did) is never replaced. The arguments and the output
folder are checked before the simulation starts: a problem is a usage error (exit status 2) that
names the flag.

It exits non-zero when a point or colour is not finite (the NaN check). Run it headless::

    python examples/newton_articulated.py --frames 90 --out out/newton_articulated --device cpu

Needs Newton (``pip install -e ".[sim]"``). The first run on a device compiles Newton's kernels
(a minute or two on a CPU; Warp caches them for later runs).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
import warp as wp

#: The prim path of the simulated body (every shape of it, one mesh) and of the ground.
BODY = "/World/Body"
GROUND = "/World/Ground"
FPS = 30
SUBSTEPS = 10  # dt = 1/300 s: XPBD holds the ant's and the humanoid's joints and contacts at this step
#: Side of the square ground (m) and its cells along each side (10 cm cells resolve the shadows).
GROUND_SIZE = 5.0
GROUND_CELLS = 50
#: Joint drive of the gait: stiffness (N m / rad) and damping of the position targets, the
#: targets' amplitude (rad) and frequency (Hz); consecutive joints are a quarter period apart.
DRIVE_KE, DRIVE_KD = 400.0, 2.0
GAIT_AMPLITUDE, GAIT_HZ = 0.6, 1.0
#: Random initial joint velocities, uniform in +-this (rad/s), seeded by ``--seed``.
KICK = 2.0
BODY_COLOR = (0.8, 0.55, 0.2)
TORSO_COLOR = (0.25, 0.4, 0.75)
GROUND_COLOR = (0.6, 0.6, 0.55)
#: The pictures' exposure maps the 99th percentile of the luminance to this (below 0.9: the sunlit
#: ground, most of the picture, stays off white, so the soft shadows on it show).
PICTURE_P99 = 0.75
#: Rec. 709 luminance weights of linear RGB.
LUMA = np.array([0.2126, 0.7152, 0.0722])


class Robot(NamedTuple):
    """One of Newton's articulated assets: its MJCF file and where its root starts."""

    asset: str
    #: The root's start height above the ground (m): it drops onto the ground.
    height: float
    #: The camera (position, target), Z up, metres.
    eye: tuple
    target: tuple


ROBOTS = {
    "ant": Robot("nv_ant.xml", 1.0, (2.6, -2.2, 1.9), (0.0, 0.0, 0.25)),
    "humanoid": Robot("nv_humanoid.xml", 1.4, (3.2, -2.8, 2.2), (0.0, 0.0, 0.5)),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=90, help="frames to simulate and shade (default 90)")
    parser.add_argument("--out", type=Path, default=Path("out/newton_articulated"), help="output folder")
    parser.add_argument("--device", default=None, help="Warp device, e.g. cpu or cuda:0 (default: Warp's default)")
    parser.add_argument("--robot", choices=sorted(ROBOTS), default="ant", help="Newton asset to simulate (default ant)")
    parser.add_argument("--segments", type=int, default=32,
                        help="segments around each circle of a tessellated shape, >= 3 (default 32)")
    parser.add_argument("--samples", type=int, default=64, help="visibility rays per vertex and frame, >= 16 (default 64)")
    parser.add_argument("--measure", type=int, default=3,
                        help="frames measured against ray-traced ground truth, of the first, middle and last "
                             "(0 to 3, default 3)")
    parser.add_argument("--truth-samples", type=int, default=1024,
                        help="ground-truth rays per vertex of a measured frame, >= 16 (default 1024)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random initial joint velocities (default 0)")
    return parser


def shape_mesh(geo_type: int, scale, segments: int):
    """The tessellation of one Newton shape in its own frame, as the matching implicit USD prim.

    Args:
        geo_type: the shape's ``newton.GeoType``.
        scale: ``Model.shape_scale`` of the shape: a sphere's radius; a capsule's, cylinder's or
            cone's radius and half height (spine along local Z); a box's or ellipsoid's half
            extents (m).
        segments: segments around each circle.

    Returns:
        ``(points (V, 3) float64, faces (F, 3) int64)``, or None for a shape type that is not
        tessellated here (a plane, a mesh, a height field).
    """
    import newton

    from warpshade.io import tessellate

    s = [float(v) for v in scale]
    stretch = np.ones(3)
    if geo_type == newton.GeoType.SPHERE:
        kind, params = "Sphere", {"radius": s[0]}
    elif geo_type == newton.GeoType.CAPSULE:
        kind, params = "Capsule", {"radius": s[0], "height": 2.0 * s[1], "axis": "Z"}
    elif geo_type == newton.GeoType.CYLINDER:
        kind, params = "Cylinder", {"radius": s[0], "height": 2.0 * s[1], "axis": "Z"}
    elif geo_type == newton.GeoType.CONE:
        kind, params = "Cone", {"radius": s[0], "height": 2.0 * s[1], "axis": "Z"}
    elif geo_type == newton.GeoType.BOX:
        kind, params, stretch = "Cube", {"size": 2.0}, np.asarray(s)
    elif geo_type == newton.GeoType.ELLIPSOID:
        kind, params, stretch = "Sphere", {"radius": 1.0}, np.asarray(s)
    else:
        return None
    points, _, faces, _ = tessellate(kind, params, segments=segments, where=f"shape {newton.GeoType(geo_type).name}")
    return points * stretch, faces


@wp.kernel(enable_backward=False)
def place_vertices(body_points: wp.array(dtype=wp.vec3), vertex_body: wp.array(dtype=wp.int32),
                   body_q: wp.array(dtype=wp.transform), points: wp.array(dtype=wp.vec3)):
    """``points[i]``: vertex ``i`` of the body's shapes, given in its body's frame, placed by that
    body's transform (world frame, metres)."""
    i = wp.tid()
    points[i] = wp.transform_point(body_q[vertex_body[i]], body_points[i])


class ArticulatedSim:
    """Newton's side: the robot on a ground plane, stepped by XPBD with a gait of joint targets.

    Attributes:
        model: the finalized ``newton.Model``.
        body_points: every visible shape's vertices in its body's frame, shape (V, 3), float32
            (a wp.array(vec3) on the device); ``vertex_body`` (V,) int32 the body of each.
        faces: the shapes' triangles, shape (F, 3), int32, indices into ``body_points``.
        albedo: per-vertex diffuse albedo (V, 3), float32 (the root body's shapes in one colour).
        shapes: what was tessellated, one line per shape type (``"8 CAPSULE"``).
    """

    def __init__(self, robot: Robot, segments: int, seed: int, device):
        import newton
        import newton.examples

        builder = newton.ModelBuilder()  # Z up, gravity -9.81 m/s^2
        builder.add_mjcf(newton.examples.get_asset(robot.asset), ignore_names=["floor", "ground"])
        builder.joint_q[2] = robot.height  # the free root joint's z
        for dof in range(6, builder.joint_dof_count):  # the free root's six dofs are not driven
            builder.joint_target_ke[dof] = DRIVE_KE
            builder.joint_target_kd[dof] = DRIVE_KD
        builder.add_ground_plane()
        self.model = builder.finalize(device=device)
        qd = self.model.joint_qd.numpy()
        qd[6:] = np.random.default_rng(seed).uniform(-KICK, KICK, size=qd.size - 6)
        self.model.joint_qd.assign(qd)
        self.solver = newton.solvers.SolverXPBD(self.model, iterations=10)
        self.state_0, self.state_1 = self.model.state(), self.model.state()
        newton.eval_fk(self.model, self.model.joint_q, self.model.joint_qd, self.state_0)
        self.control = self.model.control()
        self.pipeline = newton.CollisionPipeline(self.model)
        self.contacts = self.pipeline.contacts()
        self.dt = 1.0 / (FPS * SUBSTEPS)
        self._rest_q = self.model.joint_q.numpy().copy()
        self._targets = self._rest_q.copy()
        self._time = 0.0
        self._tessellate(segments, device)

    def _tessellate(self, segments: int, device) -> None:
        import newton
        from scipy.spatial.transform import Rotation

        types = self.model.shape_type.numpy()
        bodies = self.model.shape_body.numpy()
        scales = self.model.shape_scale.numpy()
        xforms = self.model.shape_transform.numpy()
        flags = self.model.shape_flags.numpy()
        root = int(bodies[bodies >= 0].min())
        points, faces, vertex_body, albedo, counts, skipped = [], [], [], [], {}, {}
        offset = 0
        for shape, (geo, body) in enumerate(zip(types, bodies)):
            name = newton.GeoType(int(geo)).name
            if body < 0 or not flags[shape] & newton.ShapeFlags.VISIBLE:
                continue  # the ground plane (drawn as its own mesh) and collision-only shapes
            mesh = shape_mesh(int(geo), scales[shape], segments)
            if mesh is None:
                skipped[name] = skipped.get(name, 0) + 1
                continue
            p, f = mesh
            x = xforms[shape]  # shape to body: position, quaternion (x, y, z, w)
            rot = Rotation.from_quat(x[3:7]).as_matrix()
            points.append(p @ rot.T + x[:3])
            faces.append(f + offset)
            vertex_body.append(np.full(len(p), body, np.int32))
            albedo.append(np.tile(TORSO_COLOR if body == root else BODY_COLOR, (len(p), 1)))
            counts[name] = counts.get(name, 0) + 1
            offset += len(p)
        if skipped:
            print("not tessellated: " + ", ".join(f"{n} {t}" for t, n in sorted(skipped.items())), file=sys.stderr)
        if not points:
            raise ValueError("the model has no visible sphere, capsule, box, cylinder, cone or ellipsoid shape")
        self.shapes = [f"{n} {t}" for t, n in sorted(counts.items())]
        self.faces = np.concatenate(faces).astype(np.int32)
        self.albedo = np.concatenate(albedo).astype(np.float32)
        self.body_points = wp.array(np.concatenate(points).astype(np.float32), dtype=wp.vec3, device=device)
        self.vertex_body = wp.array(np.concatenate(vertex_body), dtype=wp.int32, device=device)
        self.points = wp.empty_like(self.body_points)

    def step(self) -> None:
        """Advance one frame (``SUBSTEPS`` solver steps), the gait's targets set once per frame."""
        # joint_q starts with the free root's 7 coordinates (position, quaternion); one per hinge after it
        phase = 2.0 * np.pi * GAIT_HZ * self._time + 0.5 * np.pi * np.arange(self._targets.size - 7)
        self._targets[7:] = self._rest_q[7:] + GAIT_AMPLITUDE * np.sin(phase)
        self.control.joint_target_q.assign(self._targets.astype(np.float32))
        for _ in range(SUBSTEPS):
            self.state_0.clear_forces()
            self.pipeline.collide(self.state_0, self.contacts)
            self.solver.step(self.state_0, self.state_1, self.control, self.contacts, self.dt)
            self.state_0, self.state_1 = self.state_1, self.state_0
        self._time += 1.0 / FPS

    def pose(self):
        """Every vertex placed by its body's current transform: wp.array(vec3) (V,), metres, world frame."""
        wp.launch(place_vertices, dim=self.points.shape[0],
                  inputs=[self.body_points, self.vertex_body, self.state_0.body_q], outputs=[self.points],
                  device=self.points.device)
        return self.points


def ground_mesh():
    """The ground: a ``GROUND_SIZE`` square at z = 0 of ``GROUND_CELLS`` x ``GROUND_CELLS`` cells,
    as ``(points (V, 3), faces (F, 3))``."""
    n = GROUND_CELLS + 1
    g = np.linspace(-0.5 * GROUND_SIZE, 0.5 * GROUND_SIZE, n)
    gx, gy = np.meshgrid(g, g, indexing="xy")
    points = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    quads = np.array([[j * n + i, j * n + i + 1, (j + 1) * n + i + 1, (j + 1) * n + i]
                      for j in range(GROUND_CELLS) for i in range(GROUND_CELLS)])
    return points, np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])


def shading_scene(robot: Robot, rest_points: np.ndarray, faces: np.ndarray, albedo: np.ndarray,
                  point_samples: np.ndarray | None = None):
    """The warpshade scene: the body (deforming: its shapes move rigidly, each with its body), the
    ground (static), a sky.

    Args:
        robot: the asset (its camera).
        rest_points: the body's points at the start, shape (V, 3), metres, world frame.
        faces: the body's triangles, shape (F, 3), int32.
        albedo: per-vertex albedo of the body, shape (V, 3).
        point_samples: the body's points per frame, shape (T, V, 3); default: one frame at the
            start (a live run feeds the points instead).
    """
    from warpshade.scene import Camera, Environment, Mesh, Scene

    samples = rest_points[None] if point_samples is None else point_samples
    ground_points, ground_faces = ground_mesh()
    meshes = [
        Mesh(BODY, rest_points, faces, animation="deforming", point_samples=samples, albedo=albedo),
        Mesh(GROUND, ground_points, ground_faces, albedo=GROUND_COLOR),
    ]
    camera = Camera(position=np.array(robot.eye), target=np.array(robot.target), up=np.array([0.0, 0.0, 1.0]))
    return Scene.from_meshes(meshes, frames=np.arange(samples.shape[0], dtype=np.float64), fps=FPS,
                             lights=[Environment.sky()], camera=camera, up_axis="Z")


def measured_frames(frame_count: int, count: int) -> list:
    """The frames measured against ground truth: ``count`` of the first, middle and last (the
    previewed frames), the last ones first (the body has moved most by then)."""
    from warpshade.measure import preview_frames

    shown = preview_frames(range(frame_count))
    return sorted(shown[::-1][:count])


def check_arguments(parser: argparse.ArgumentParser, args):
    """Everything about the arguments that can go wrong, found before any simulation: the counts,
    the device, the shading graph's parameters (``--samples``) and the files ``--out`` would get.
    A problem ends the program as a usage error (exit status 2) naming the flag.

    Returns:
        ``(device, graph, plan)``: the Warp device, the shading graph and the checked output plan
        (:func:`warpshade.measure.plan_outputs`).
    """
    if args.frames < 1:
        parser.error(f"argument --frames: must be >= 1, got {args.frames}")
    if args.segments < 3:
        parser.error(f"argument --segments: must be >= 3, got {args.segments}")
    if not 0 <= args.measure <= 3:
        parser.error(f"argument --measure: must be 0 to 3 (of the first, middle and last frames), got {args.measure}")
    if args.truth_samples < 16:
        parser.error(f"argument --truth-samples: must be >= 16, got {args.truth_samples}")
    from warpshade.graph import GraphError, GraphSpec, StageError, StageSpec
    from warpshade.measure import check_output_directory, plan_outputs

    try:
        device = wp.get_device(args.device)
    except (ValueError, RuntimeError) as exc:
        parser.error(f"argument --device: {exc} (this machine has {', '.join(str(d) for d in wp.get_devices())})")
    graph = GraphSpec([StageSpec("shade", "prt.trace", {"order": 3, "samples": args.samples})], "shade.radiance",
                      name="newton_articulated")
    try:
        graph.check()
    except (GraphError, StageError) as exc:
        parser.error(f"argument --samples: {exc}")
    try:
        check_output_directory(args.out)
    except OSError as exc:
        parser.error(f"argument --out: {exc}")
    # the outputs, planned like those of `warpshade run`: never over a file this example did not write there
    measured = measured_frames(args.frames, args.measure)
    plan = plan_outputs(args.out, "newton_articulated", "newton_articulated.usda", range(args.frames), measured,
                        validate=bool(measured))
    try:
        plan.check()
    except (OSError, ValueError) as exc:
        parser.error(f"argument --out: {exc.strerror if isinstance(exc, OSError) and exc.strerror else exc}")
    return device, graph, plan


def measure(scene, lighting, colors: np.ndarray, frames: list, samples: int, device) -> list:
    """The run's radiance against ray-traced ground truth on ``frames`` (no disk cache).

    Returns:
        per frame: ``{"frame", "rel_rms", "rel_rms_debiased", "noise_rel_rms", "rel_p99"}`` and the
        reference radiance ``(V, 3)`` under ``"reference"``.
    """
    from warpshade.measure import error_metrics, ground_truth

    truth = ground_truth(scene, lighting, frames, samples, device, cache_dir=None, progress=True)
    out = []
    for f in frames:
        gt = truth[float(f)]
        m = error_metrics(colors[int(f)], gt["radiance"], gt["stderr"])
        out.append({"frame": int(f), **{k: m[k] for k in ("rel_rms", "rel_rms_debiased", "noise_rel_rms", "rel_p99")},
                    "reference": np.asarray(gt["radiance"])})
    return out


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    device, graph, plan = check_arguments(parser, args)
    robot = ROBOTS[args.robot]
    from warpshade.io import write_vertex_colors
    from warpshade.measure import comparison_figure
    from warpshade.render import render
    from warpshade.tasks import progress_bar

    with wp.ScopedDevice(device):
        sim = ArticulatedSim(robot, args.segments, args.seed, device)
        rest = sim.pose().numpy().astype(np.float64)
        rt = graph.compile(shading_scene(robot, rest, sim.faces, sim.albedo), device=device, cache_dir=None,
                           progress=False)

        points, colors, sim_s, shade_s = [], [], [], []
        for _ in progress_bar(range(args.frames), desc="simulate and shade", unit="frame"):
            t0 = time.perf_counter()
            sim.step()
            wp.synchronize_device(device)
            t1 = time.perf_counter()
            radiance = rt.step(0, points={BODY: sim.pose()})  # the posed shapes, device to device
            wp.synchronize_device(device)
            t2 = time.perf_counter()
            sim_s.append(t1 - t0)
            shade_s.append(t2 - t1)
            points.append(sim.points.numpy().astype(np.float64))
            colors.append(radiance.numpy().copy())

    print(f"{args.frames} frames of the {args.robot} ({', '.join(sim.shapes)}; {sim.model.body_count} bodies), "
          f"{rt.scene.vertex_count} shaded vertices on {device}")
    print(f"first frame (compiles and records): simulation {sim_s[0]:.2f} s, shading {shade_s[0]:.2f} s")
    timed = slice(1, None) if args.frames > 1 else slice(0, None)
    sim_ms, shade_ms = 1e3 * float(np.mean(sim_s[timed])), 1e3 * float(np.mean(shade_s[timed]))
    if args.frames > 1:
        print(f"per frame after it: simulation {sim_ms:.1f} ms, shading {shade_ms:.1f} ms")

    points, colors = np.stack(points), np.stack(colors)
    bad = [name for name, a in (("body points", points), ("colours", colors)) if not np.all(np.isfinite(a))]
    if bad:
        print(f"newton_articulated: NaN or infinite {' and '.join(bad)}", file=sys.stderr)
        return 1

    scene = shading_scene(robot, rest, sim.faces, sim.albedo, point_samples=points)
    usd = write_vertex_colors(plan.usd, scene, scene.frames, colors)
    plan.record([usd])
    p99 = float(np.percentile(colors @ LUMA, 99))
    exposure = float(np.log2(PICTURE_P99 / p99)) if p99 > 0 else 0.0  # one exposure for every picture
    sky = scene.lights[0]
    for f, path in sorted(plan.previews.items()):
        render(scene, f, colors=colors[int(f)], width=480, height=360, environment=sky,
               exposure=exposure, supersample=2, path=path, device=device)
        plan.record([path])

    errors = measure(scene, rt.lighting, colors, sorted(plan.comparisons), args.truth_samples, device)
    for e in errors:
        path = plan.comparisons[float(e["frame"])]
        comparison_figure(scene, e["frame"], colors[e["frame"]], e.pop("reference"), path, label="prt.trace",
                          environment=sky, exposure=exposure, device=device)
        plan.record([path])
        print(f"frame {e['frame']}: relative RMS error {e['rel_rms']:.3f} against ray tracing "
              f"({e['rel_rms_debiased']:.3f} without the reference's noise of {e['noise_rel_rms']:.3f})")
    report = {
        "robot": args.robot, "asset": robot.asset, "shapes": sim.shapes, "body_count": int(sim.model.body_count),
        "frames": args.frames, "device": str(device), "solver": "SolverXPBD", "substeps": SUBSTEPS,
        "graph": "prt.trace", "order": 3, "samples": args.samples, "segments": args.segments,
        "vertex_count": int(rt.scene.vertex_count), "body_vertex_count": int(rest.shape[0]),
        "ms_per_frame": {"simulation": sim_ms, "shading": shade_ms, "total": sim_ms + shade_ms,
                         "frames_timed": len(sim_s[timed]), "first_frame_s": sim_s[0] + shade_s[0]},
        "error": {"per_frame": errors, "truth_samples": args.truth_samples, "reference": "diffuse, ray traced",
                  "mean_rel_rms": float(np.mean([e["rel_rms"] for e in errors])) if errors else None,
                  "mean_rel_rms_debiased": float(np.mean([e["rel_rms_debiased"] for e in errors])) if errors else None},
    }
    plan.report.write_text(json.dumps(report, indent=2) + "\n")
    plan.record([plan.report])
    written = [usd, *plan.previews.values(), *plan.comparisons.values(), plan.report]
    print(f"wrote {', '.join(Path(p).name for p in written)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
