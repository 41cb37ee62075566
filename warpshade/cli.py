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
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
