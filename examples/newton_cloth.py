"""A Newton cloth simulation shaded live by warpshade, frame by frame.

A square cloth (Newton's ``ModelBuilder.add_cloth_grid``, solved with ``SolverXPBD``) falls
onto a sphere resting on the ground and drapes over it. After each simulated frame the cloth's
particle positions (``State.particle_q``, a ``wp.array`` of vec3 on the run's device) are fed to
a warpshade run compiled once for a scene with the same topology:
``rt.step(0, points={"/World/Cloth": particle_q})``. The graph is ``prt.trace`` (per-frame
ray-traced SH transfer, order 3): the cloth shadows the ground and the sphere shadows the cloth
under a procedural sky. Everything stays on the device between the two; the host sees only the
copies kept for the outputs.

Outputs in ``--out``:

* ``newton_cloth.usda`` -- the simulated cloth points (time-sampled), the sphere and the ground,
  each with per-vertex ``primvars:displayColor`` (linear RGB radiance) per frame;
* ``newton_cloth_<frame>.png`` -- previews of the first, middle and last frames.

They are planned like the outputs of ``warpshade run`` (:func:`warpshade.measure.plan_outputs`):
a file of one of those names that this example did not write there itself (the folder's manifest,
``.warpshade-outputs.json``, says which it did) is never replaced. The arguments and the output
folder are checked before the simulation starts: a problem is a usage error (exit status 2) that
names the flag.

It prints the time per frame split into simulation and shading, and exits non-zero when a
point or colour is not finite (the NaN check). Run it headless::

    python examples/newton_cloth.py --frames 60 --out out/newton_cloth --device cpu

Needs Newton (``pip install -e ".[sim]"``). The first run on a device compiles Newton's kernels
(about 90 s on a CPU; Warp caches them for later runs).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

#: The prim path of the simulated cloth in the warpshade scene and the written layer.
CLOTH = "/World/Cloth"
SPHERE_CENTER = (0.0, 0.0, 0.5)
SPHERE_RADIUS = 0.5
#: Side of the square cloth (m); it starts flat, this high above the ground (m).
CLOTH_SIZE = 1.6
CLOTH_HEIGHT = 1.3
FPS = 30
SUBSTEPS = 20  # dt = 1/600 s: XPBD with these springs is stable here (10 substeps blow up)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=60, help="frames to simulate and shade (default 60)")
    parser.add_argument("--out", type=Path, default=Path("out/newton_cloth"), help="output folder")
    parser.add_argument("--device", default=None, help="Warp device, e.g. cpu or cuda:0 (default: Warp's default)")
    parser.add_argument("--cells", type=int, default=32, help="cloth grid cells along each side (default 32)")
    parser.add_argument("--samples", type=int, default=64, help="visibility rays per vertex and frame, >= 16 (default 64)")
    return parser


class ClothSim:
    """Newton's side: the cloth grid over a static sphere and ground plane, stepped by XPBD.

    Attributes:
        model: the finalized ``newton.Model`` (particles of the cloth only).
        faces: the cloth's triangles, shape (F, 3), int32, indices into ``particle_q``.
    """

    def __init__(self, cells: int, device):
        import newton
        import warp as wp

        self._wp = wp
        builder = newton.ModelBuilder()  # Z up, gravity -9.81 m/s^2
        builder.add_ground_plane()
        builder.add_shape_sphere(-1, xform=wp.transform(wp.vec3(*SPHERE_CENTER), wp.quat_identity()), radius=SPHERE_RADIUS)
        cell = CLOTH_SIZE / cells
        builder.add_cloth_grid(
            pos=wp.vec3(-0.5 * CLOTH_SIZE, -0.5 * CLOTH_SIZE, CLOTH_HEIGHT), rot=wp.quat_identity(), vel=wp.vec3(0.0, 0.0, 0.0),
            dim_x=cells, dim_y=cells, cell_x=cell, cell_y=cell, mass=0.05,
            add_springs=True, spring_ke=1.0e3, spring_kd=1.0, edge_ke=1.0e1, particle_radius=0.4 * cell,
        )
        self.model = builder.finalize(device=device)
        self.model.soft_contact_ke = 1.0e2
        self.model.soft_contact_kd = 1.0
        self.model.soft_contact_mu = 0.8
        self.faces = self.model.tri_indices.numpy().astype(np.int32)
        self.solver = newton.solvers.SolverXPBD(self.model, iterations=10)
        self.state_0, self.state_1 = self.model.state(), self.model.state()
        self.control = self.model.control()
        self.pipeline = newton.CollisionPipeline(self.model)
        self.contacts = self.pipeline.contacts()
        self.dt = 1.0 / (FPS * SUBSTEPS)

    @property
    def particle_q(self):
        """The cloth's current points, wp.array(vec3) (particle_count,), metres, world frame."""
        return self.state_0.particle_q

    def step(self) -> None:
        """Advance one frame (``SUBSTEPS`` solver steps)."""
        for _ in range(SUBSTEPS):
            self.state_0.clear_forces()
            self.pipeline.collide(self.state_0, self.contacts)
            self.solver.step(self.state_0, self.state_1, self.control, self.contacts, self.dt)
            self.state_0, self.state_1 = self.state_1, self.state_0


def shading_scene(rest_points: np.ndarray, faces: np.ndarray, point_samples: np.ndarray | None = None):
    """The warpshade scene: the cloth (deforming), the sphere and the ground (static), a sky.

    Args:
        rest_points: the cloth's initial points, shape (V, 3), metres, world frame.
        faces: the cloth's triangles, shape (F, 3), int32.
        point_samples: the cloth's points per frame, shape (T, V, 3); default: one frame at rest
            (a live run feeds the points instead).
    """
    import trimesh

    from warpshade.scene import Camera, Environment, Mesh, Scene

    samples = rest_points[None] if point_samples is None else point_samples
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=SPHERE_RADIUS)
    g = np.linspace(-2.0, 2.0, 41)
    gx, gy = np.meshgrid(g, g, indexing="xy")
    ground_points = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    quads = np.array([[j * 41 + i, j * 41 + i + 1, (j + 1) * 41 + i + 1, (j + 1) * 41 + i] for j in range(40) for i in range(40)])
    meshes = [
        Mesh(CLOTH, rest_points, faces, animation="deforming", point_samples=samples, albedo=(0.75, 0.2, 0.15)),
        Mesh("/World/Sphere", sphere.vertices + np.asarray(SPHERE_CENTER), sphere.faces, albedo=(0.7, 0.7, 0.7)),
        Mesh("/World/Ground", ground_points, np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]]), albedo=(0.6, 0.6, 0.55)),
    ]
    camera = Camera(position=np.array([2.8, -2.4, 2.2]), target=np.array([0.0, 0.0, 0.45]), up=np.array([0.0, 0.0, 1.0]))
    return Scene.from_meshes(meshes, frames=np.arange(samples.shape[0], dtype=np.float64), fps=FPS,
                             lights=[Environment.sky()], camera=camera, up_axis="Z")


def check_arguments(parser: argparse.ArgumentParser, args):
    """Everything about the arguments that can go wrong, found before any simulation: the counts,
    the device, the shading graph's parameters (``--samples``) and the files ``--out`` would get.
    A problem ends the program as a usage error (exit status 2) naming the flag.

    Returns:
        ``(device, graph, plan)``: the Warp device, the shading graph and the checked output plan
        (:func:`warpshade.measure.plan_outputs`).
    """
    for flag, value in (("--frames", args.frames), ("--cells", args.cells)):
        if value < 1:
            parser.error(f"argument {flag}: must be >= 1, got {value}")
    import warp as wp

    from warpshade.graph import GraphError, GraphSpec, StageError, StageSpec
    from warpshade.measure import check_output_directory, plan_outputs

    try:
        device = wp.get_device(args.device)
    except (ValueError, RuntimeError) as exc:
        parser.error(f"argument --device: {exc} (this machine has {', '.join(str(d) for d in wp.get_devices())})")
    graph = GraphSpec([StageSpec("shade", "prt.trace", {"order": 3, "samples": args.samples})], "shade.radiance",
                      name="newton_cloth")
    try:
        graph.check()
    except (GraphError, StageError) as exc:
        parser.error(f"argument --samples: {exc}")
    try:
        check_output_directory(args.out)
    except OSError as exc:
        parser.error(f"argument --out: {exc}")
    # the outputs, planned like those of `warpshade run`: never over a file this example did not write there
    plan = plan_outputs(args.out, "newton_cloth", "newton_cloth.usda", range(args.frames), report=False)
    try:
        plan.check()
    except (OSError, ValueError) as exc:
        parser.error(f"argument --out: {exc.strerror if isinstance(exc, OSError) and exc.strerror else exc}")
    return device, graph, plan


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    device, graph, plan = check_arguments(parser, args)
    import warp as wp

    from warpshade.io import write_vertex_colors
    from warpshade.render import render

    with wp.ScopedDevice(device):
        sim = ClothSim(args.cells, device)
        rest = sim.particle_q.numpy().astype(np.float64)
        rt = graph.compile(shading_scene(rest, sim.faces), device=device, cache_dir=None, progress=False)

        points, colors, sim_s, shade_s = [], [], [], []
        for _ in range(args.frames):
            t0 = time.perf_counter()
            sim.step()
            wp.synchronize_device(device)
            t1 = time.perf_counter()
            radiance = rt.step(0, points={CLOTH: sim.particle_q})  # the particles, device to device
            wp.synchronize_device(device)
            t2 = time.perf_counter()
            sim_s.append(t1 - t0)
            shade_s.append(t2 - t1)
            points.append(sim.particle_q.numpy().astype(np.float64))
            colors.append(radiance.numpy().copy())

    print(f"{args.frames} frames, {len(rest)} cloth particles, {rt.scene.vertex_count} shaded vertices on {device}")
    print(f"first frame (compiles and records): simulation {sim_s[0]:.2f} s, shading {shade_s[0]:.2f} s")
    if args.frames > 1:
        print(f"per frame after it: simulation {1e3 * np.mean(sim_s[1:]):.1f} ms, shading {1e3 * np.mean(shade_s[1:]):.1f} ms")

    points, colors = np.stack(points), np.stack(colors)
    bad = [name for name, a in (("cloth points", points), ("colours", colors)) if not np.all(np.isfinite(a))]
    if bad:
        print(f"newton_cloth: NaN or infinite {' and '.join(bad)}", file=sys.stderr)
        return 1

    scene = shading_scene(rest, sim.faces, point_samples=points)
    usd = write_vertex_colors(plan.usd, scene, scene.frames, colors)
    plan.record([usd])
    p99 = float(np.percentile(colors @ np.array([0.2126, 0.7152, 0.0722]), 99))
    exposure = float(np.log2(0.9 / p99)) if p99 > 0 else 0.0  # one exposure for every preview
    for f, path in sorted(plan.previews.items()):
        render(scene, f, colors=colors[int(f)], width=480, height=360, environment=scene.lights[0],
               exposure=exposure, supersample=2, path=path, device=device)
        plan.record([path])
    print(f"wrote {usd} and {', '.join(p.name for _, p in sorted(plan.previews.items()))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
