"""What the dish benchmarks share (``bench_sg_aniso``, ``bench_sg_aniso_table``, ``bench_sg_svbrdf``,
``bench_svbrdf_reference``): the quick profile's stage overrides, one per-pixel frame of a dish
graph with its ray-traced references, the pixels on the dish, the relative RMS errors, and the
best isotropic approximation, panels and JSON report of the two anisotropic ones.

Not a script: the scripts import it as a sibling module (``python benchmarks/<script>.py`` puts
``benchmarks/`` first on the import path).
"""

from __future__ import annotations

import dataclasses
import datetime
import sys
import time
from pathlib import Path

import numpy as np

from warpshade._fileio import write_json_atomic
from warpshade.measure import ground_truth_model
from warpshade.measure._pictures import ERROR_COLORMAP, ERROR_LIMIT, write_panels
from warpshade.measure._pixels import exposure_for, pixel_stage, render_frame
from warpshade.reference import reference_image
from warpshade.render import tonemap_f64
from warpshade.scene import Environment


def quick_overrides(spec, resolution: int = 16, lobes: int | None = None):
    """The quick profile's overrides on a loaded graph ``spec``, in place: every ``sg.ssdf`` stage at
    ``resolution``^2 without supersampling, and (unless ``lobes`` is None) every ``sg.shade`` stage
    with ``lobes`` NDF lobes. Returns ``spec``."""
    for st in spec.stages:
        if st.type == "sg.ssdf":
            st.params.update(resolution=resolution, supersample=1)
        if lobes is not None and st.type == "sg.shade":
            st.params.update(lobes=lobes)
    return spec


@dataclasses.dataclass
class DishRun:
    """One compiled run of a dish graph at its first frame, rendered per pixel.

    ``stage`` is the per-pixel ``sg.shade`` stage, ``image`` :func:`render_frame`'s result;
    ``model`` is the stage's per-pixel ground-truth model and ``references`` the ray-traced
    reference images by name (both empty unless :func:`render_and_reference` made them). Seconds:
    ``compile_s`` (graph compile), ``sg_s`` (the per-pixel frame), ``reference_s`` (by name)."""

    rt: object
    frame: float
    stage: object
    image: object
    compile_s: float
    sg_s: float
    model: dict = dataclasses.field(default_factory=dict)
    references: dict = dataclasses.field(default_factory=dict)
    reference_s: dict = dataclasses.field(default_factory=dict)


def render_first_frame(spec, device: str, width: int, height: int, progress: bool) -> DishRun:
    """Compile ``spec`` on ``device``, step its first frame and render it per pixel at
    ``width`` x ``height`` (:func:`warpshade.measure._pixels.render_frame`), timing the compile and
    the render."""
    t0 = time.perf_counter()
    rt = spec.compile(device=device, progress=progress)
    compile_s = time.perf_counter() - t0
    frame = float(rt.scene.frames[0])
    rt.step(frame)
    st = pixel_stage(rt)
    t0 = time.perf_counter()
    im = render_frame(rt, frame, width, height)
    sg_s = time.perf_counter() - t0
    return DishRun(rt, frame, st, im, compile_s, sg_s)


def render_and_reference(spec, device: str, width: int, height: int, samples: int, seed: int, progress: bool,
                         brdfs: dict | None = None) -> DishRun:
    """:func:`render_first_frame`, then the stage's per-pixel ground-truth model
    (:func:`warpshade.measure.ground_truth_model`) and one specular reference image
    (:func:`warpshade.reference.reference_image`: the frame's camera and lights, the model's eye
    and UV tangents, the rendered specular colours, ``samples`` rays per pixel, ``seed``) per entry
    of ``brdfs`` (name -> BRDF, in order; None stands for the model's own BRDF; default
    ``{"reference": None}``), each one timed."""
    run = render_first_frame(spec, device, width, height, progress)
    rt, frame, im = run.rt, run.frame, run.image
    run.model = ground_truth_model(run.stage, rt.state.materials, rt.state.eye.numpy()[0], per_pixel=True)
    for name, brdf in (brdfs or {"reference": None}).items():
        t0 = time.perf_counter()
        run.references[name] = reference_image(
            rt.scene, frame, run.model["brdf"] if brdf is None else brdf, camera=im.camera, width=width, height=height,
            samples=samples, eye=run.model["eye"], lighting=rt.lighting.lights_at(frame),
            specular=im.materials["specular"], include=("specular",), seed=seed, device=rt.device,
            tangents=run.model["tangents"])
        run.reference_s[name] = time.perf_counter() - t0
    return run


def dish_triangles(scene) -> tuple[int, int]:
    """``[start, stop)`` of the dish's triangles in the scene-wide triangle numbering (the mesh
    whose prim path ends in ``Dish``)."""
    dish = next((k for k, m in enumerate(scene.meshes) if m.path.endswith("Dish")), None)
    if dish is None:
        raise ValueError(f"no mesh whose prim path ends in 'Dish' among {[m.path for m in scene.meshes]}")
    start = sum(m.triangle_count for m in scene.meshes[:dish])
    return start, start + scene.meshes[dish].triangle_count


def dish_mask(scene, triangles) -> np.ndarray:
    """True where ``triangles`` (scene-wide triangle indices, any shape) is one of the dish's."""
    start, stop = dish_triangles(scene)
    return (triangles >= start) & (triangles < stop)


def pixel_masks(scene, reference, image, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """``(dish, covered)`` pixel masks of a rendered ``image`` and its ``reference``: ``covered``,
    every ray of the pixel hits the scene in both; ``dish``, covered and the reference's pixel ray
    hits one of the dish's triangles."""
    covered = reference.mask & (image.coverage >= 1.0)
    on_dish = dish_mask(scene, reference.hits.triangles.reshape(height, width))
    return covered & on_dish, covered


def rel_rms(est, ref, mask=None) -> float:
    """Relative RMS error ``sqrt(mean |est - ref|^2) / sqrt(mean |ref|^2)`` over every element
    (RGB included), over ``mask`` only where one is given."""
    est, ref = np.asarray(est), np.asarray(ref)
    if mask is not None:
        est, ref = est[mask], ref[mask]
    d = est - ref
    return float(np.sqrt(np.mean(d * d)) / np.sqrt(np.mean(ref * ref)))


def relative_noise(stderr, ref, mask) -> float:
    """A reference's standard error relative to its signal: ``sqrt(mean stderr^2) / sqrt(mean
    ref^2)`` over ``mask`` (a boolean mask or an index array)."""
    return float(np.sqrt(np.mean(stderr[mask] ** 2)) / np.sqrt(np.mean(ref[mask] ** 2)))


def sole_environment(rt, frame: float, graph: Path) -> Environment:
    """The frame's one light, an environment; SystemExit naming ``graph`` if the scene has any
    other light (the eq.-13 quadratures integrate one sky and nothing else)."""
    lights = rt.lighting.lights_at(frame)
    envs = [light for light in lights if isinstance(light, Environment)]
    if len(envs) != 1 or len(lights) != 1:
        raise SystemExit(f"{graph.name}: the quadrature takes one environment and no other light; the scene has {lights}")
    return envs[0]


def dated_stem(name: str, quick: bool) -> tuple[str, str]:
    """``(date, stem)`` of today's output files: ``<name>-<date>-cpu[-quick]``."""
    date = datetime.date.today().isoformat()
    return date, f"{name}-{date}-cpu" + ("-quick" if quick else "")


def write_aniso_panels(path: Path, sg, ref, iso, mask, sg_title: str, iso_title: str, samples: int, ratio: float) -> Path:
    """The anisotropic benchmarks' three panels into ``path``: ``sg | ref`` (titled ``sg_title``),
    ``iso | ref`` (the best isotropic approximation, ``iso_title``) and the signed error of ``sg``
    (relative to the mean of ``ref``'s RGB sum over ``mask``, grey off the mask) beside grey, with
    the size, the reference's ``samples`` per pixel and the anisotropic / best isotropic ``ratio``
    beneath. Images are linear RGB ``(height, width, 3)``, tonemapped at the exposure of ``ref``
    over ``mask``."""
    import matplotlib

    height, width = mask.shape
    exposure = exposure_for(ref[mask].reshape(-1, 3))
    y_scale = float(np.mean(ref[mask].sum(-1))) if mask.any() else 1.0
    err = np.where(mask, (sg - ref).sum(-1) / max(y_scale, 1e-30), 0.0)
    err_rgb = matplotlib.colormaps[ERROR_COLORMAP](np.clip(0.5 + 0.5 * err / ERROR_LIMIT, 0, 1))[..., :3]
    err_u8 = np.clip(np.where(mask[..., None], err_rgb, 0.5) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    sg_img, ref_img, iso_img = (tonemap_f64(x, exposure=exposure) for x in (sg, ref, iso))
    return write_panels(path, [np.concatenate([sg_img, ref_img], 1), np.concatenate([iso_img, ref_img], 1),
                               np.concatenate([err_u8, np.full_like(err_u8, 128)], 1)],
                        [sg_title, iso_title, "error (anisotropic SG)"], ERROR_LIMIT,
                        f"{width}x{height} pixels, reference {samples} spp; anisotropic / best isotropic = {ratio:.2f}")


def best_isotropic(result: dict, rows: list, images: list, label) -> tuple[dict, np.ndarray, float]:
    """The best isotropic approximation among ``rows`` (the first with the lowest ``rel_rms_dish``),
    its linear image (``images`` in the order of ``rows``) and the ratio of the anisotropic
    ``result``'s dish error to its; printed with ``label(row)`` naming the row."""
    k = min(range(len(rows)), key=lambda i: rows[i]["rel_rms_dish"])
    ratio = result["rel_rms_dish"] / rows[k]["rel_rms_dish"]
    print(f"best isotropic: {label(rows[k])}, dish rel RMS {rows[k]['rel_rms_dish']:.4f}; "
          f"anisotropic / best isotropic = {ratio:.3f}", flush=True)
    return rows[k], images[k], ratio


def write_aniso_outputs(out: Path, name: str, script: str, argv, args, graph: Path, root: Path, rt, sg, ref, mask, *,
                        titles: tuple[str, str], material: dict, result: dict, iso_key: str, iso: list, best: dict,
                        best_image, ratio: float, seconds: dict) -> tuple[Path, Path]:
    """The anisotropic benchmarks' outputs in ``out``: ``<name>-<date>-cpu[-quick].png``
    (:func:`write_aniso_panels` of ``sg``, ``ref`` and ``best_image`` over ``mask``, the panels
    titled ``titles`` -- anisotropic, best isotropic -- and their dish errors) and the ``.json``
    report (the run's settings from ``args``, ``material``, the anisotropic ``result``, the
    isotropic rows ``iso`` under ``iso_key``, the ``best`` one, the ``ratio`` of their dish errors,
    the goals -- dish error below 0.25, ratio at most 0.5 --, ``seconds`` and the command line of
    ``script`` with ``argv``). Returns the JSON's and the PNG's paths."""
    date, stem = dated_stem(name, args.quick)
    png = write_aniso_panels(out / f"{stem}.png", sg, ref, best_image, mask,
                             f"{titles[0]}\ndish rel RMS {result['rel_rms_dish']:.3f}",
                             f"{titles[1]}\ndish rel RMS {best['rel_rms_dish']:.3f}", args.samples, ratio)
    report = {"date": date, "device": str(rt.device), "quick": args.quick, "graph": str(graph.relative_to(root)),
              "width": args.width, "height": args.height, "reference_samples": args.samples,
              "material": material, "anisotropic": result, iso_key: iso, "best_isotropic": best,
              "ratio_anisotropic_to_best_isotropic": ratio,
              "goals": {"rel_rms_dish_below_0.25": result["rel_rms_dish"] < 0.25, "ratio_below_0.5": ratio <= 0.5},
              "seconds": seconds, "png": png.name,
              "command": f"python benchmarks/{Path(script).name} " + " ".join(argv if argv is not None else sys.argv[1:])}
    path = write_json_atomic(out / f"{stem}.json", report)
    print(f"wrote {path} and {png}")
    return path, png
