"""warpshade: soft shadows and relighting for animated USD scenes, measured against ray tracing.

Commands: demo (run the bundled demo), run (a stage graph end to end), info (what a USD scene
holds), list-stages (ready-made graphs and stage types with their parameters), selfcheck (the
Warp SH kernels against float64).

A known problem (a bad file, flag, parameter or environment) ends in one or two lines,
"warpshade <command>: error: <what>, <where>", with exit code 2; an unexpected failure prints a
short message (add --debug for the traceback) and exits with 1. When the reader of standard output
goes away ("warpshade info FILE | head") the command ends quietly with 141, as a Unix tool that
SIGPIPE ends.
"""

from __future__ import annotations

import argparse
import os
import sys

__all__ = ["main"]


def _cmd_selfcheck(args) -> int:
    """Evaluate the SH basis on the Warp device and check it against the float64 mirror."""
    import numpy as np

    from .basis import quadrature, sh

    q = quadrature.gauss_legendre(2 * (args.order - 1))
    y_ref = sh.basis(q.directions, args.order)
    y_wp = sh.basis(q.directions, args.order, device=args.device)
    gram = (y_wp.astype(np.float64) * q.weights[:, None]).T @ y_wp
    ortho = float(np.abs(gram - np.eye(args.order**2)).max())
    agree = float(np.abs(y_wp - y_ref).max())
    print(f"warpshade SH self-check (order {args.order}, device {args.device}):")
    print(f"  kernel vs float64 mirror, max |diff|     = {agree:.3e}")
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

    from .io import load_scene, resolve_scene_path
    from .scene import DistantLight, Environment, SphereLight

    path = resolve_scene_path(args.scene)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = load_scene(path, ground_plane=args.ground_plane, sky=False)
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
        if m.implicit is not None:
            extra.append(f"tessellated {m.implicit[0]}")
        elif m.normals is not None:
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
    print(f"skipped {len(scene.skipped)} prim(s)")
    for prim, reason in scene.skipped:
        print(f"  {prim}: {reason}")
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


def _describe_param(name, param) -> str:
    bits = [f"{param.type.__name__}", f"default {param.default!r}"]
    if param.choices is not None:
        bits.append("one of " + ", ".join(repr(c) for c in param.choices))
    if param.minimum is not None or param.maximum is not None:
        lo = "" if param.minimum is None else (f"{param.minimum}" if param.type is int else f"{param.minimum:g}")
        hi = "" if param.maximum is None else (f"{param.maximum}" if param.type is int else f"{param.maximum:g}")
        bits.append(f"range [{lo}, {hi}]")
    return f"      {name:20s} {'; '.join(bits)}" + (f" -- {param.doc}" if param.doc else "")


def _cmd_list_stages(args) -> int:
    """List the ready-made stage graphs and every registered stage type with its parameters."""
    from .graph import GraphError, load, stage_types

    for d in _stage_dirs():
        print(f"stage graphs in {d}:")
        for f in sorted(d.glob("*.toml")):
            try:
                g = load(f)
                print(f"  {f.name:34s} {g.description or g.name}")
            except GraphError as exc:
                print(f"  {f.name:34s} [invalid: {exc}]")
    print("stage types (parameters: type; default; allowed values -- meaning):")
    for name, cls in sorted(stage_types().items()):
        print(f"  {name:26s} {cls.kind:10s} {cls.description}")
        if args.brief:
            continue
        for pname, param in sorted(cls.parameters.items()):
            print(_describe_param(pname, param))
    return 0


class CliError(Exception):
    """A problem with what the command was asked to do (reported in one line, exit code 2)."""


def _run_graph(graph_file, frames=None, device=None, out_dir=None, validate=False, previews=True, progress=True,
               usd_format="auto", scheduler=None, movie=False, validate_samples=None, scene_spec=None):
    """Run one stage graph end to end; returns (runtime, outputs dict).

    With ``movie``, a movie of every frame run is written too (MP4, or GIF without ffmpeg), and
    with ``validate`` one of the measured frames' method | reference | error strips.
    ``validate_samples`` replaces the graph's ``[validate] samples`` (ground-truth rays per vertex
    and per pixel). ``scene_spec`` (``--scene``) replaces the graph's ``scene``
    (:meth:`~warpshade.graph.GraphSpec.load_scene`: its ``frame_count`` applies only when nothing
    in that scene moves, said before any work).

    Everything is checked before any work: the graph file, the output directory (writable, not
    a file), the scene, ``--frames``, the ``[validate]`` frames measured (those the run steps),
    that the output can be measured at all (``--validate``), every file the run will write (none
    may replace a file warpshade did not write there: :func:`_plan_run`), the artifact cache and
    the lighting. Then the runtime (precompute, frames) is composed with the measuring layer
    (ground truth, pictures, the USD layer and the report). Nothing is written outside the
    output directory: every output is named by the graph's name, which cannot hold a path.
    """
    import time
    from pathlib import Path

    from .tasks import SCHEDULER_ENV, executor
    from ._fileio import check_writable_dir
    from .graph import GraphError, load

    if validate_samples is not None and not validate:
        raise CliError("--validate-samples without --validate: it sets the ground truth's rays, which only "
                       "--validate computes")
    if movie and not previews:
        raise CliError("--movie and --no-previews: a movie is made of the pictures --no-previews skips; "
                       "drop one of the two")
    movie_format = _movie_format() if movie else None
    spec = load(graph_file)
    out = Path(out_dir if out_dir is not None else Path("warpshade-out") / spec.name)
    check_writable_dir(out, "--out directory")
    t0 = time.perf_counter()
    scene = spec.load_scene(scene_spec)
    if scene_spec is not None:
        moving = spec.frame_count_skipped(scene)
        if moving is not None:
            print(f"warpshade run: --scene {scene_spec} is animated ({moving}): the graph's frame_count = "
                  f"{spec.scene_options['frame_count']} is for static scenes and is not applied; the run steps the "
                  f"scene's {len(scene.frames)} time codes {scene.frames[0]:g}..{scene.frames[-1]:g}", file=sys.stderr)
    try:
        run_frames = spec.run_frames(scene, frames)
    except GraphError as exc:
        if frames is not None:
            raise CliError(f"--frames {frames!r}: {str(exc).split(': ', 1)[-1]}") from None
        raise CliError(f"{exc}; choose the time codes to run with --frames") from None
    measured = left_out = []
    validation = None
    if validate:
        validation = spec.validation_plan(scene, run_frames)
        measured, left_out = validation.measured, validation.left_out
        if validation.note():  # said before any work, and again in the summary and the report
            print(f"warpshade run: {validation.note()}", file=sys.stderr)
    plan = _plan_run(spec, scene, out, run_frames, measured, validate, previews, usd_format, movie_format)
    _check_cache()
    # ground-truth frames go to the executor only when one is asked for (flag or environment)
    try:
        tasks = executor(scheduler) if scheduler is not None or os.environ.get(SCHEDULER_ENV) else None
    except ValueError as exc:
        raise CliError(f"--scheduler: {exc}") from None
    try:
        rt = spec.compile(scene, device=device, progress=progress, scheduler=scheduler)
        rt.run(run_frames)
        outputs = _finish_run(spec, rt, plan, measured, left_out, validate, previews, tasks, validate_samples)
        outputs["validation"] = validation
    finally:
        if tasks is not None:
            tasks.close()
    outputs["seconds"] = time.perf_counter() - t0
    return rt, outputs


def _movie_format() -> str:
    """``mp4`` or ``gif`` (:func:`warpshade.measure._pictures.movie_format`), or a CliError saying what to install."""
    from .measure._pictures import movie_format

    try:
        return movie_format()
    except ImportError as exc:
        raise CliError(f"--movie: {exc}") from None


def _plan_run(spec, scene, out, run_frames, measured, validate, previews, usd_format, movie_format=None):
    """The files of the run, planned and checked before any work
    (:func:`warpshade.measure._outputs.plan_outputs`); with ``validate``, the stages measured are
    asked whether their parameters allow a ground truth at all.

    Raises:
        FileExistsError: a planned file warpshade did not write there or one the run reads, naming it.
        StageError: a stage that cannot be measured, naming it and its parameter.
    """
    from .io._usd_write import usd_output_name
    from .measure._outputs import plan_outputs, run_inputs
    from .measure._pixels import pixel_stage_of
    from .measure._protocols import check_measurable

    stages, _ = spec.build()
    shader = pixel_stage_of(stages, spec.output)
    if validate:
        output_name = spec.output.split(".", 1)[0]
        check_measurable(next(s for s in stages if s.name == output_name))
        from .scene._materials_warp import check_reference_brdf

        for entry in spec.materials:
            try:
                check_reference_brdf(entry["brdf"])
            except ValueError as exc:
                source = getattr(entry["brdf"], "source", None)
                raise CliError(f"--validate: {entry['where']}{f' ({source})' if source else ''}: {exc}; "
                               "run without --validate") from None
        if shader is not None and measured:
            check_measurable(shader, per_pixel=True)
    plan = plan_outputs(out, spec.name, usd_output_name(spec.name, scene, len(run_frames), usd_format), run_frames,
                        measured, previews=previews, validate=validate, pixels=shader is not None,
                        movie=movie_format, protected=run_inputs(spec, scene))
    plan.check()
    return plan


def _check_cache() -> None:
    """The artifact cache must take new entries: say so before any work, naming the directory and
    how to choose another."""
    from ._fileio import check_writable_dir
    from .graph._cache import default_cache_dir

    cache = default_cache_dir()
    try:
        check_writable_dir(cache, "artifact cache")
    except OSError as exc:
        raise CliError(f"{_message(exc)}; set $WARPSHADE_CACHE to a writable directory") from None


def _finish_run(spec, rt, plan, measured, left_out, validate, previews, tasks, validate_samples=None) -> dict:
    """The measuring layer's part of a run: USD layer, previews, error, comparisons, report, each
    written where ``plan`` (:class:`~warpshade.measure._outputs.OutputPlan`) says and recorded in
    the output directory's manifest once written."""
    from pathlib import Path

    from .measure import measure_error, render_comparisons, render_previews, write_report, write_usd
    from .measure._pictures import render_comparison_movie, render_movie
    from .measure._pixels import measure_pixels, pixel_stage, write_pixel_images

    out = plan.directory
    outputs = {"left_out": left_out, "png": []}

    def wrote(paths) -> list:
        plan.record(paths)
        return list(paths)

    outputs["usd"] = wrote([write_usd(rt, plan.usd)])[0]
    if previews:
        outputs["png"] += wrote(render_previews(rt, out, frames=sorted(plan.previews)))
    samples = int(spec.validate_spec.get("samples", 1024) if validate_samples is None else validate_samples)
    measurement = measure_error(rt, measured, samples=samples, executor=tasks) if validate else None
    error = measurement.error if measurement is not None else None
    if error is not None and left_out:
        error["frames_left_out"] = left_out
    if validate and previews:
        outputs["png"] += wrote(render_comparisons(rt, measurement, out, frames=sorted(plan.comparisons)))
    if plan.movie is not None:
        outputs["movie"] = wrote([render_movie(rt, plan.movie)])
        if plan.comparison_movie is not None:
            outputs["movie"] += wrote([render_comparison_movie(rt, measurement, plan.comparison_movie,
                                                               frames=sorted(measurement.references))])
    if pixel_stage(rt) is not None:
        # stages that shade pixels: per-pixel PNG + linear EXR previews, and per-pixel error
        if previews:
            outputs["png"] += wrote(write_pixel_images(rt, out, frames=sorted(plan.pixel_images), width=480, height=360))
        if validate and measured:
            px_samples = int(spec.validate_spec.get("samples", 256) if validate_samples is None else validate_samples)
            pixels = measure_pixels(rt, out, sorted(plan.pixel_comparisons), width=160, height=120, samples=px_samples)
            if error is not None:
                error["pixels"] = pixels
            outputs["png"] += wrote([Path(v["image"]) for v in pixels["frames"].values()])
    outputs["report"] = wrote([write_report(rt, plan.report, error=error)])[0]
    outputs["error"] = error
    return outputs


def _print_run(rt, outputs) -> None:
    t = rt.timing_summary()
    pre = sum(v.get("precompute_s", 0.0) for v in t["stages"].values())
    print(f"{rt.spec.name}: {rt.scene.vertex_count:,} vertices, {len(rt.results)} frames on {rt.device}")
    print(f"  precompute {pre:.2f} s, median frame {1e3 * (t['median_frame_s'] or 0):.2f} ms "
          f"(host-side Python {1e3 * (t['median_host_s'] or 0):.3f} ms, "
          f"{'one recorded frame replayed' if t['captured'] else 'not recorded'})")
    for line in rt.stale_artifacts:
        print(f"  recomputed a cached artifact: {line}")
    err = outputs.get("error")
    if err:
        m = err["mean"]
        debiased = m.get("rel_rms_debiased")
        print(f"  error vs ray-traced ground truth ({err['samples']} spp): relative RMS "
              + (f"{debiased:.4f} with the reference's noise removed ({m['rel_rms']:.4f} with it), " if debiased is not None
                 else f"{m['rel_rms']:.4f}, ")
              + f"p99 {m['rel_p99']:.4f} (ground-truth noise {m.get('noise_rel_rms', float('nan')):.4f})")
        for f, v in (err.get("pixels") or {}).get("frames", {}).items():
            px = err["pixels"]
            print(f"  per pixel, frame {f:g} ({px['width']}x{px['height']}, {px['samples']} spp): relative RMS "
                  f"{v['rel_rms']:.4f} (ground-truth noise {v['noise']:.4f})")
    validation = outputs.get("validation")
    if validation is not None:
        if validation.outside_run:
            print(f"  [validate] frame(s) {validation.outside_run} are outside the frames run and were not measured")
        if validation.not_in_scene:
            print(f"  [validate] frame(s) {validation.not_in_scene} are not time codes of the scene "
                  f"({validation.scene_times}) and were not measured"
                  + (f"; measured the first frame run, {validation.measured[0]:g}" if validation.fallback else ""))
    elif outputs.get("left_out"):
        print(f"  [validate] frame(s) {outputs['left_out']} are outside the frames run and were not measured")
    print(f"  USD     {outputs['usd']}")
    for p in outputs.get("png", []):
        print(f"  {'EXR' if str(p).endswith('.exr') else 'PNG'}     {p}")
    for p in outputs.get("movie", []):
        print(f"  movie   {p}")
    print(f"  report  {outputs['report']}  ({outputs['seconds']:.1f} s in all)")


def _refuse_scene_as_graph(name: str) -> None:
    """A USD scene (a file, ``warp-example:NAME``, ``bundled:NAME``) given where a stage graph is
    expected: say what it is and how to run a graph on it."""
    from pathlib import Path

    from .graph._loader import usd_scene_kind
    from .io._scene_specs import SCENE_SPEC_PREFIXES, USD_SUFFIXES

    kind = None
    if name.startswith(SCENE_SPEC_PREFIXES):
        kind = "a scene spec"
    elif Path(name).is_file():
        kind = usd_scene_kind(name)
    elif Path(name).suffix.lower() in USD_SUFFIXES:
        kind = "a USD file name"
    if kind is not None:
        raise CliError(f"{name} is a USD scene ({kind}), not a stage graph: run a graph on it with --scene, e.g. "
                       f"warpshade run stages/bunny_prt.toml --scene {name} (warpshade list-stages lists the graphs)")


def _cmd_run(args) -> int:
    """Run a stage graph: precompute (cached), frame loop, USD + PNG + JSON outputs."""
    _refuse_scene_as_graph(args.graph)
    graph_file = _find_graph(args.graph)
    rt, outputs = _run_graph(graph_file, args.frames, args.device, args.out, args.validate, not args.no_previews,
                             usd_format=args.usd_format, scheduler=args.scheduler, movie=args.movie,
                             validate_samples=args.validate_samples, scene_spec=args.scene)
    _print_run(rt, outputs)
    return 0


def _cmd_shade(args) -> int:
    """Choose, size and validate a method for a scene; write the chosen graph; run it."""
    from pathlib import Path

    from .measure._auto import VALIDATE_SAMPLES, run_frames, shade_scene

    name = Path(str(args.scene).split(":", 1)[-1]).stem or "scene"
    out = args.out or f"warpshade-out/{name}_auto"
    samples = args.validate_samples or VALIDATE_SAMPLES
    report = shade_scene(args.scene, out, target_error=args.target_error, budget_ms=args.budget_ms, glossy=args.glossy,
                         device=args.device or "cpu", validate_samples=samples, quick=args.quick,
                         training=args.training, tune=not args.no_tune)
    if report["chosen"] is None:
        raise CliError(f"{args.scene}: {report['why']} (see {report['chart']} and the report next to it)")
    if not report["met"]:
        print(f"note    the request was not met: {report['why']}")
    if args.no_run:
        return 0
    graph = report["chosen"]["graph"]
    frames = run_frames(report["scene_frames"], report["held_out_frames"])
    print(f"run     warpshade run {graph} --frames {frames} --validate --out {out}")
    rt, outputs = _run_graph(Path(graph), frames, args.device, out, True, True, validate_samples=samples)
    _print_run(rt, outputs)
    return 0


DEMO_GRAPH = "demo.toml"


def _cmd_demo(args) -> int:
    """Run the default bundled scene end to end and say where the outputs are."""
    graph_file = _find_graph(DEMO_GRAPH)
    rt, outputs = _run_graph(graph_file, None, args.device, args.out or "warpshade-out/demo", validate=True)
    print(f"warpshade demo ({graph_file}):")
    _print_run(rt, outputs)
    return 0


def _order(text: str) -> int:
    from .basis.sh_warp import MAX_KERNEL_ORDER

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
    if not 1 <= value <= MAX_KERNEL_ORDER:
        raise argparse.ArgumentTypeError(f"must be in 1..{MAX_KERNEL_ORDER}, got {value}")
    return value


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def _frames(text: str) -> str:
    from .graph import GraphError
    from .graph._loader import check_frames_spec

    try:
        check_frames_spec(text, "value")
    except GraphError as exc:
        raise argparse.ArgumentTypeError(str(exc).split(": ", 1)[-1]) from None
    return text


def _cmd_budget(args) -> int:
    from .measure._budget import main as budget_main

    return budget_main(args.budget_args)


def build_parser() -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                        help="show the Python traceback of an error")
    device = argparse.ArgumentParser(add_help=False)
    device.add_argument("--device", default=None, help="Warp device: cpu, cuda:0, ... (default: Warp's default device)")
    parser = argparse.ArgumentParser(prog="warpshade", description=__doc__, parents=[common],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    p = sub.add_parser("selfcheck", parents=[common], help="check the Warp SH kernels against the float64 mirror",
                       description="Evaluate the SH basis with the Warp kernels and check it against the float64 mirror.")
    p.add_argument("--order", type=_order, default=6, help="SH order n (n*n coefficients), 1..12 (default 6)")
    p.add_argument("--device", default="cpu", help="Warp device (default: cpu)")
    p.set_defaults(func=_cmd_selfcheck)
    p = sub.add_parser(
        "info", parents=[common],
        help="print what a USD scene contains (meshes, skinning, lights, camera, frames, bounds)",
        description="SCENE is a USD file, warp-example:NAME (e.g. warp-example:bunny) or bundled:NAME.",
    )
    p.add_argument("scene", help="USD file or scene spec")
    p.add_argument("--ground-plane", action="store_true", help="add a ground plane under the scene first")
    p.set_defaults(func=_cmd_info)
    p = sub.add_parser("run", parents=[common, device], help="run a stage graph (TOML) end to end: USD + PNG + JSON report",
                       description="Run a stage graph on its scene (or on another one given with --scene): "
                                   "precompute (cached), every frame, then write the USD layer, PNG previews and a JSON "
                                   "report into --out.")
    p.add_argument("graph", help="path to a stage graph, or the name of one in stages/")
    p.add_argument("--scene", default=None, metavar="SCENE",
                   help="run the graph on this scene instead of its own: a USD file, warp-example:NAME or bundled:NAME "
                        "(the graph's scene options apply; frame_count only to a scene in which nothing moves)")
    p.add_argument("--frames", type=_frames, default=None,
                   help="time codes to run: A:B (A <= t < B; either end may be left out) or one time code "
                        "(default: the graph's [graph] frames, else every frame of the scene)")
    p.add_argument("--out", default=None, help="output directory (default: warpshade-out/<graph name>)")
    p.add_argument("--validate", action="store_true",
                   help="measure the error against ray-traced ground truth on the graph's [validate] frames that are run")
    p.add_argument("--validate-samples", type=_positive_int, default=None, metavar="N",
                   help="ground-truth rays per vertex (and per pixel) of --validate (default: the graph's "
                        "[validate] samples, else 1024); fewer for a quick, noisier check")
    p.add_argument("--no-previews", action="store_true", help="skip the PNG previews and comparison pictures")
    p.add_argument("--movie", action="store_true",
                   help="also write <graph>.mp4 (<graph>.gif without ffmpeg) of every frame run, and with --validate "
                        "<graph>_vs_reference.mp4: method | reference | error over the validated frames")
    p.add_argument("--usd-format", choices=("auto", "usda", "usdc"), default="auto",
                   help="USD layer format: text (usda), binary (usdc) or auto (binary above 32 MiB of colours)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="where independent precompute tasks (training frames, ground-truth frames) run: a Dask "
                        "scheduler address (tcp://host:8786), 'local[:N]' worker processes or 'serial' "
                        "(default: $WARPSHADE_SCHEDULER, else local worker processes)")
    p.set_defaults(func=_cmd_run)
    p = sub.add_parser("shade", parents=[common, device],
                       help="choose, size and validate a method for your own scene, write its graph and run it",
                       description="Inspect SCENE (a USD file, warp-example:NAME or bundled:NAME), measure every method "
                                   "that applies to it at a few sizes on training frames against ray-traced ground "
                                   "truth (the per-frame ray tracer among them, the baseline), choose (the cheapest "
                                   "meeting --target-error, the most accurate within --budget-ms), write the chosen "
                                   "graph (<name>_auto.toml), a report and a time-vs-error chart into --out, then run "
                                   "the graph validated on held-out frames the choice did not use.")
    p.add_argument("scene", help="USD file or scene spec")
    p.add_argument("--target-error", type=float, default=None, metavar="E",
                   help="relative RMS error against ray-traced ground truth to meet (default 0.1 when no budget is given)")
    p.add_argument("--budget-ms", type=float, default=None, metavar="X", help="time per frame the method may take (ms)")
    p.add_argument("--glossy", choices=("auto", "on", "off"), default="auto",
                   help="shade glossy (RPO) or diffuse; auto: glossy when a mesh's material roughness is below 0.4")
    p.add_argument("--out", default=None, help="output directory (default: warpshade-out/<scene name>_auto)")
    p.add_argument("--validate-samples", type=_positive_int, default=None, metavar="N",
                   help="ground-truth rays per vertex of the held-out validation (default 512)")
    p.add_argument("--training", default=None, metavar="CLIP",
                   help="a training clip of the same character (USD file or scene spec): adds the data-driven "
                        "methods, trained on it")
    p.add_argument("--no-tune", action="store_true",
                   help="the few-ray tracer with its default reuse settings (default: chosen on the training frames)")
    p.add_argument("--quick", action="store_true", help="one size per method, no tuning (a first look)")
    p.add_argument("--no-run", action="store_true", help="choose and write the graph, its report and chart; do not run it")
    p.set_defaults(func=_cmd_shade)
    p = sub.add_parser("budget", add_help=False,
                       help="measure a method's candidate settings on a scene and pick the cheapest meeting a target error "
                            "(warpshade budget --help)")
    p.add_argument("budget_args", nargs=argparse.REMAINDER, help="the flags of warpshade budget (see warpshade budget --help)")
    p.set_defaults(func=_cmd_budget)
    p = sub.add_parser("demo", parents=[common, device], help="run the default bundled scene end to end and print where its outputs are",
                       description="Run stages/demo.toml (Warp's bunny under a rotating sky, static PRT) with validation.")
    p.add_argument("--out", default=None, help="output directory (default: warpshade-out/demo)")
    p.set_defaults(func=_cmd_demo)
    p = sub.add_parser("list-stages", parents=[common], help="list ready-made stage graphs and stage types with their parameters",
                       description="List the stage graphs in ./stages and the source checkout's stages/, and every "
                                   "registered stage type with its parameters.")
    p.add_argument("--brief", action="store_true", help="stage types without their parameters")
    p.set_defaults(func=_cmd_list_stages)
    return parser


def _message(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:
        text = str(exc.strerror)
        if exc.filename and str(exc.filename) not in text:
            text = f"{text}: {exc.filename}"
    else:
        text = str(exc) or type(exc).__name__
    if isinstance(exc, MemoryError):
        text = f"ran out of memory ({text})"
    return text


#: Exit status when the reader of standard output goes away (``warpshade info FILE | head``):
#: 128 + SIGPIPE, what a shell reports for a tool that SIGPIPE ended.
EXIT_BROKEN_PIPE = 128 + 13


def _stdout_closed() -> int:
    """Standard output's reader went away: end quietly, like a Unix tool ended by SIGPIPE. What is
    still buffered for it goes to the null device, so the interpreter's last flush cannot fail
    (Python's documentation, "Note on SIGPIPE")."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, AttributeError, ValueError):  # no file descriptor (a captured stream)
        pass
    return EXIT_BROKEN_PIPE


def main(argv=None) -> int:
    import traceback

    from .methods.stage import StageError

    parser = build_parser()
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["budget"]:  # its own parser reads every flag after the word (--help included)
        return _cmd_budget(argparse.Namespace(budget_args=argv[1:]))
    args = parser.parse_args(argv)
    debug = getattr(args, "debug", False)
    try:
        code = int(args.func(args) or 0)
        sys.stdout.flush()  # a reader that went away (| head) shows here, not at interpreter exit
        return code
    except BrokenPipeError:
        return _stdout_closed()
    except KeyboardInterrupt:
        print(f"warpshade {args.command}: interrupted", file=sys.stderr)
        return 130
    except (CliError, StageError, ValueError, OSError, MemoryError) as exc:
        if debug:
            traceback.print_exc()
        text = _message(exc).strip()
        lines = text.splitlines()
        print(f"warpshade {args.command}: error: {lines[0] if lines else text}", file=sys.stderr)
        for line in lines[1:3]:
            print(f"  {line}", file=sys.stderr)
        return 2
    except Exception as exc:  # a bug: short, with the way to the traceback
        if debug:
            raise
        print(f"warpshade {args.command}: unexpected error: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}\n"
              f"  run it again with --debug to see the traceback", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
