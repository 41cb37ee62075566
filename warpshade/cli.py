"""The ``warpshade`` command line."""

from __future__ import annotations

import argparse
import sys

__all__ = ["main"]


def _cmd_selfcheck(args) -> int:
    """Evaluate the SH basis on the Warp device and check it against the float64 reference."""
    import numpy as np

    from .basis import quadrature, sh

    q = quadrature.gauss_legendre(2 * (args.order - 1))
    y_ref = sh.basis(q.directions, args.order)
    y_wp = sh.basis(q.directions, args.order, device=args.device)
    gram = (y_wp.astype(np.float64) * q.weights[:, None]).T @ y_wp
    ortho = float(np.abs(gram - np.eye(args.order**2)).max())
    agree = float(np.abs(y_wp - y_ref).max())
    print(f"warpshade SH self-check (order {args.order}, device {args.device}):")
    print(f"  kernel vs float64 reference, max |diff|     = {agree:.3e}")
    print(f"  orthonormality by exact quadrature, max err = {ortho:.3e}")
    ok = agree < 1e-5 and ortho < 1e-5
    print("  OK" if ok else "  FAILED")
    return 0 if ok else 1


def _fmt_vec(v) -> str:
    return "(" + ", ".join(f"{float(x):.3g}" for x in v) + ")"


def _cmd_info(args) -> int:
    """Print what a USD scene contains: meshes, skinning, lights, camera, frames, bounds."""
    import warnings

    import numpy as np

    from .io.usd import load_scene, resolve_scene_path
    from .scene import DistantLight, Environment, SphereLight

    try:
        path = resolve_scene_path(args.scene)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            scene = load_scene(path, ground_plane=args.ground_plane, sky=False)
    except (FileNotFoundError, ValueError) as exc:
        print(f"warpshade info: error: {exc}", file=sys.stderr)
        return 2
    frames = scene.frames
    print(f"scene   {args.scene}" + (f"  ({path})" if path != args.scene else ""))
    print(f"up axis {scene.up_axis}    frames {len(frames)} (time codes {frames[0]:g}..{frames[-1]:g}) at {scene.fps:g} fps")
    lo, hi = scene.bounds()
    print(f"bounds  (frame {frames[0]:g}) min {_fmt_vec(lo)} max {_fmt_vec(hi)}")
    if len(frames) > 1:
        lo, hi = scene.bounds_over_frames()
        print(f"        (all frames) min {_fmt_vec(lo)} max {_fmt_vec(hi)}")
    print(f"meshes  {len(scene.meshes)}: {scene.vertex_count:,} vertices, {scene.triangle_count:,} triangles")
    width = max(len(m.path) for m in scene.meshes)
    for m in scene.meshes:
        extra = []
        if m.animation == "skinned":
            extra.append(f"skeleton {scene.skeletons[m.skin.skeleton].path}, {m.skin.joint_indices.shape[1]} influences")
        if m.animation == "rigid":
            extra.append(f"{m.transforms.shape[0]} transforms")
        if m.normals is not None:
            extra.append("authored normals")
        if m.uvs is not None:
            extra.append("uvs")
        if m.dropped_face_count:
            extra.append(f"{m.dropped_face_count} zero-area triangles dropped")
        albedo = np.asarray(m.albedo).mean(axis=0)
        print(
            f"  {m.path:<{width}}  {m.vertex_count:>7,} v {m.triangle_count:>7,} tri  {m.animation:<9}"
            f" albedo {_fmt_vec(albedo)}" + (f"  [{'; '.join(extra)}]" if extra else "")
        )
    print(f"skinning {len(scene.skeletons)} skeleton(s)")
    for skel in scene.skeletons:
        animated = skel.local_transforms.shape[0]
        angles = np.stack([np.linalg.norm(skel.joint_angles(t), axis=1) for t in range(animated)])
        print(
            f"  {skel.path}  {skel.joint_count} joints, {animated} animated frame(s), "
            f"max joint angle {np.degrees(angles.max()):.1f} deg"
        )
    print(f"lights  {len(scene.lights)}")
    for light in scene.lights:
        if isinstance(light, Environment):
            mean = light.image.reshape(-1, 3).mean(axis=0)
            src = light.path or "constant colour"
            print(f"  DomeLight     {src}  {light.width}x{light.height}  mean radiance {_fmt_vec(mean)}  peak {light.image.max():.3g}")
        elif isinstance(light, DistantLight):
            print(f"  DistantLight  {light.path}  towards {_fmt_vec(light.direction)}  irradiance {_fmt_vec(light.irradiance)}  angle {light.angle_deg:g} deg")
        elif isinstance(light, SphereLight):
            print(f"  SphereLight   {light.path}  at {_fmt_vec(light.position)}  radius {light.radius:.3g}  radiance {_fmt_vec(light.radiance)}")
        track = getattr(light, "track", None)
        if track is not None:
            turn = np.degrees(max(np.arccos(np.clip((np.trace(track.rotation(t)) - 1) / 2, -1, 1)) for t in track.times))
            move = max(np.linalg.norm(track.position(t) - track.position(track.times[0])) for t in track.times)
            print(f"                animated over {len(track.times)} frames: turns up to {turn:.1f} deg, moves up to {move:.3g}")
    cam = scene.camera
    if cam is None:
        print("camera  none (a camera framing the scene is used)")
    else:
        print(f"camera  {cam.path}  at {_fmt_vec(cam.position)} looking at {_fmt_vec(cam.target)}  vertical fov {cam.vertical_fov:.1f} deg")
    for prim, reason in scene.skipped:
        print(f"skipped {prim}: {reason}")
    for w in caught:
        print(f"warning {w.message}")
    return 0


def _stage_dirs() -> list:
    """Where ready-made stage graphs are looked for: ./stages, then the source checkout's."""
    from pathlib import Path

    dirs = [Path.cwd() / "stages", Path(__file__).resolve().parent.parent / "stages"]
    out = []
    for d in dirs:
        if d.is_dir() and d.resolve() not in [o.resolve() for o in out]:
            out.append(d)
    return out


def _find_graph(name: str):
    from pathlib import Path

    p = Path(name)
    if p.exists():
        return p
    for d in _stage_dirs():
        for cand in (d / name, d / f"{name}.toml"):
            if cand.exists():
                return cand
    raise FileNotFoundError(f"stage graph {name!r} not found (looked in: {', '.join(map(str, _stage_dirs())) or 'no stages/ folder'})")


def _cmd_list_stages(args) -> int:
    """List the ready-made stage graphs and every registered stage type."""
    from .graph import GraphError, load, stage_types

    for d in _stage_dirs():
        print(f"stage graphs in {d}:")
        for f in sorted(d.glob("*.toml")):
            try:
                g = load(f)
                print(f"  {f.name:34s} {g.description or g.name}")
            except GraphError as exc:
                print(f"  {f.name:34s} [invalid: {exc}]")
    print("stage types:")
    for name, cls in sorted(stage_types().items()):
        print(f"  {name:26s} {cls.kind:10s} {cls.description}")
    return 0


def _run_graph(graph_file, frames=None, device=None, out_dir=None, validate=False, previews=True, progress=True):
    """Run one stage graph end to end; returns (runtime, outputs dict).

    Composes the runtime (precompute, frames) with the measuring layer (ground truth, pictures,
    the USD layer and the report).
    """
    import time
    from pathlib import Path

    from .graph import load
    from .measure import measure_error, render_comparisons, render_previews, write_report, write_usd

    spec = load(graph_file)
    out = Path(out_dir if out_dir is not None else Path("warpshade-out") / spec.name)
    t0 = time.perf_counter()
    rt = spec.compile(device=device, progress=progress)
    rt.run(frames)
    outputs = {"usd": write_usd(rt, out / f"{spec.name}.usda")}
    if previews:
        outputs["png"] = render_previews(rt, out)
    measurement = measure_error(rt) if validate else None
    error = measurement.error if measurement is not None else None
    if validate and previews:
        outputs["png"] = [*outputs.get("png", []), *render_comparisons(rt, measurement, out)]
    outputs["report"] = write_report(rt, out / f"{spec.name}.json", error=error)
    outputs["seconds"] = time.perf_counter() - t0
    outputs["error"] = error
    return rt, outputs


def _print_run(rt, outputs) -> None:
    t = rt.timing_summary()
    pre = sum(v.get("precompute_s", 0.0) for v in t["stages"].values())
    print(f"{rt.spec.name}: {rt.scene.vertex_count:,} vertices, {len(rt.results)} frames on {rt.device}")
    print(f"  precompute {pre:.2f} s, median frame {1e3 * (t['median_frame_s'] or 0):.2f} ms "
          f"(host-side Python {1e3 * (t['median_host_s'] or 0):.3f} ms, "
          f"{'one recorded frame replayed' if t['captured'] else 'not recorded'})")
    err = outputs.get("error")
    if err:
        m = err["mean"]
        print(f"  error vs ray-traced ground truth ({err['samples']} spp): relative RMS {m['rel_rms']:.4f}, "
              f"p99 {m['rel_p99']:.4f} (ground-truth noise {m.get('noise_rel_rms', float('nan')):.4f})")
    print(f"  USD     {outputs['usd']}")
    for p in outputs.get("png", []):
        print(f"  PNG     {p}")
    print(f"  report  {outputs['report']}  ({outputs['seconds']:.1f} s in all)")


def _cmd_run(args) -> int:
    """Run a stage graph: precompute (cached), frame loop, USD + PNG + JSON outputs."""
    from .graph import GraphError

    try:
        graph_file = _find_graph(args.graph)
        rt, outputs = _run_graph(graph_file, args.frames, args.device, args.out, args.validate, not args.no_previews)
    except (GraphError, FileNotFoundError, ValueError) as exc:
        print(f"warpshade run: error: {exc}", file=sys.stderr)
        return 2
    _print_run(rt, outputs)
    return 0


DEMO_GRAPH = "demo.toml"


def _cmd_demo(args) -> int:
    """Run the default bundled scene end to end and say where the outputs are."""
    from .graph import GraphError

    try:
        graph_file = _find_graph(DEMO_GRAPH)
        rt, outputs = _run_graph(graph_file, None, args.device, args.out or "warpshade-out/demo", validate=True)
    except (GraphError, FileNotFoundError, ValueError) as exc:
        print(f"warpshade demo: error: {exc}", file=sys.stderr)
        return 2
    print(f"warpshade demo ({graph_file}):")
    _print_run(rt, outputs)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="warpshade", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("selfcheck", help="check the Warp SH kernels against the float64 reference")
    p.add_argument("--order", type=int, default=6)
    p.add_argument("--device", default="cpu")
    p.set_defaults(func=_cmd_selfcheck)
    p = sub.add_parser(
        "info",
        help="print what a USD scene contains (meshes, skinning, lights, camera, frames, bounds)",
        description="SCENE is a USD file, warp-example:NAME (e.g. warp-example:bunny) or bundled:NAME.",
    )
    p.add_argument("scene", help="USD file or scene spec")
    p.add_argument("--ground-plane", action="store_true", help="add a ground plane under the scene first")
    p.set_defaults(func=_cmd_info)
    p = sub.add_parser("run", help="run a stage graph (TOML) end to end: USD + PNG + JSON report")
    p.add_argument("graph", help="path to a stage graph, or the name of one in stages/")
    p.add_argument("--frames", default=None, help="time codes A:B (A <= t < B); default: the graph's range")
    p.add_argument("--device", default=None, help="Warp device: cpu, cuda:0 (default: Warp's default)")
    p.add_argument("--out", default=None, help="output directory (default: warpshade-out/<graph name>)")
    p.add_argument("--validate", action="store_true", help="measure error against ray-traced ground truth")
    p.add_argument("--no-previews", action="store_true", help="skip the PNG previews")
    p.set_defaults(func=_cmd_run)
    p = sub.add_parser("demo", help="run the default bundled scene end to end and print where its outputs are")
    p.add_argument("--device", default=None)
    p.add_argument("--out", default=None, help="output directory (default: warpshade-out/demo)")
    p.set_defaults(func=_cmd_demo)
    p = sub.add_parser("list-stages", help="list ready-made stage graphs and registered stage types")
    p.set_defaults(func=_cmd_list_stages)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
