"""Spherical Gaussians + SSDF visibility on the sunlit scene: speed vs accuracy against the SH
methods and the brute-force baseline, per vertex and per pixel.

Setup (every row): scene ``bundled:sunlit`` (a glossy torus knot on a ground plane), lighting the
scene's environment alone, not turning (its "sharp sky": a 1.2 degree sun about 30,000 times the
sky; the moving sphere light is left out except in part 5), one material for every mesh: the
Beckmann microfacet BRDF with roughness 0.2, f0 0.04 and specular colour 0.9, seen from the scene
camera. Error: relative RMS over vertices of the specular radiance against the glossy ray-traced
reference of the same BRDF, eye and colour (:func:`warpshade.measure.ground_truth`, 1024 spp,
seed :data:`warpshade.measure._truth.GT_SEED`, cached on disk) on frames 0 and 24; each error is
reported raw (``rel_rms``) and with the reference's own Monte Carlo variance removed
(``rel_rms_debiased``), and the reference noise is reported next to it.

Part 1 -- rows through the graph runtime (:func:`warpshade.measure.run_setting`):

* SG (``sg.ssdf`` -> ``sg.environment`` -> ``ldprt.tangents`` -> ``sg.shade``): SSDF resolution
  16, 32, 64 (x4 supersampled traces; 128 from 512 with ``--ssdf128``) with 8 environment lobes
  and the sun taken out of the sky (shaded as a narrow light with the BRDF at its direction); at
  32: the sun left in the sky, and the paper's method (sun in the sky, every light through the SG
  product of eq. 43, ``horizon = false``);
* glossy LDPRT with the same BRDF: n4 b3 N3 (the graph ``stages/sunlit_ldprt_glossy.toml``) and
  n6 b12 N4;
* RPO (``rpo.shade``, Beckmann 0.2): traced n4 k8 (256 rays per vertex and frame) and static n4 k8;
* the brute-force baseline: the glossy reference itself per frame at 16, 64 and 256 spp (another
  seed than the truth's).

Time per frame is the median over replayed frames, every row's frames stepped in turn (rows
interleaved, so a load change on the shared machine hits all rows alike); the precompute time of
an artifact is the time it took when it was computed (kept next to the artifact cache, since the
SG environment table is only built once per cache directory).

Part 2 -- per pixel (the SG method, SSDF 32): time per 640 x 480 frame (:func:`render_frame`: step,
G-buffer, materials, shade) and relighting only (the shading kernel over a reused G-buffer), medians
of >= 5 frames; per-vertex radiance interpolated per pixel against per-pixel shading at 160 x 120,
both against :func:`warpshade.reference._pixels.reference_image` (the paper's Fig. 8); the textured
variant (roughness and colours from the UsdPreviewSurface textures per pixel,
:func:`warpshade.measure._pixels.measure_pixels`) and one frame with the moving lamp and both BRDF
terms (``stages/sunlit_sg_lights.toml``) written as PNG and EXR.

Writes ``sg-<date>-cpu[-quick].json``, ``-pareto.png``, ``-pixels.png`` (Fig. 8 strip; with
``--ssdf128`` also ``-pixels-ssdf128.png``), ``-textured.png`` and ``-lights_px_<frame>.png/.exr``
into ``benchmarks/results``; ``--replot JSON`` redraws the chart of an earlier run.

Usage::

    WARPSHADE_CACHE=/tmp/ws-cache-bench python benchmarks/bench_sg.py [--quick] [--ssdf128] [--gt-samples 1024] [--out DIR]
    python benchmarks/bench_sg.py --replot benchmarks/results/sg-<date>-cpu.json
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

#: Smoke profile (tests/test_benchmarks.py): slow, kept out of the default suite (``-m "not slow"``):
#: 52 s: SSDF bakes and the sky's prefiltered table.
PROFILE = {"slow": True}

ROOT = Path(__file__).resolve().parent.parent

RESULTS = ROOT / "benchmarks" / "results"
#: The material of every row: Beckmann microfacets (the BRDF of stages/sunlit_sg.toml).
ROUGHNESS = 0.2
F0 = 0.04
SPECULAR = (0.9, 0.9, 0.9)
SG_SHADE = {"brdf": "beckmann", "roughness": ROUGHNESS, "f0": F0, "specular": list(SPECULAR)}
#: Frames of the error (the [validate] frames of the sunlit graphs).
ERROR_FRAMES = (0.0, 24.0)
#: Seeds of the brute-force baseline rows (independent of the truth's seed).
BASELINE_SEED = 9001
#: Seed of the per-pixel references.
PIXEL_SEED = 77
#: Where precompute seconds of computed artifacts are remembered (inside the artifact cache).
PRECOMPUTE_LOG = "bench-sg-precompute.json"
#: SSDF resolution and row label of the SG row of the ``--quick`` smoke profile (part 2 runs it).
QUICK_SSDF = 8
QUICK_SG = f"ssdf {QUICK_SSDF} x4 e8"


# ---- set-up -----------------------------------------------------------------------------------


def coarse_environment(env, rows: int = 32):
    """``env`` box-filtered down to about ``rows`` texel rows (the ``--quick`` profile: the
    prefiltered table of a full-size sky takes tens of seconds to build on the CPU)."""
    img = np.asarray(env.image, np.float32)
    f = max(1, img.shape[0] // rows)
    h, w = img.shape[0] // f * f, img.shape[1] // f * f
    return dataclasses.replace(env, image=img[:h, :w].reshape(h // f, f, w // f, f, 3).mean(axis=(1, 3)))


def load(quick: bool = False):
    """The sunlit scene and its environment-only lighting, not turning (``quick``: the scene's
    environment coarsened by :func:`coarse_environment`)."""
    from warpshade.io import load_scene
    from warpshade.scene import Environment, LightingSource, SphereLight

    scene = load_scene("bundled:sunlit")
    if quick:
        scene.lights = [coarse_environment(light) if isinstance(light, Environment) else light for light in scene.lights]
    lighting = LightingSource.fixed([light for light in scene.lights if not isinstance(light, SphereLight)], scene.up_axis)
    return scene, lighting


def sg_stages(resolution: int, supersample: int = 4, lobes: int = 8, sun: str = "separate", **shade) -> tuple:
    """SG graph stages (``warpshade.methods.sg._rows.sg_stages`` with this benchmark's BRDF, plus
    any ``sg.shade`` parameter, e.g. ``horizon``)."""
    from warpshade.methods.sg._rows import sg_stages as base

    stages = list(base(resolution, supersample, 0.02, lobes, brdf={**SG_SHADE, **shade}, sun=sun))
    return tuple(stages)


def ldprt_stages(order: int, rank: int, lobes: int, samples: int = 256) -> tuple:
    """Glossy LDPRT stages with the benchmark's BRDF (``stages/sunlit_ldprt_glossy.toml`` at n4 b3 N3)."""
    return (("fit", "ldprt.glossy_fit", {"order": order, "lobes": lobes, "rank": rank, "brdf": "beckmann",
                                         "roughness": ROUGHNESS, "f0": F0, "samples": samples}, {}),
            ("tangents", "ldprt.tangents", {}, {}),
            ("shade", "ldprt.glossy_shade", {"order": order, "lobes": lobes, "rank": rank, "specular": list(SPECULAR)}, {}))


def rpo_stages(visibility: str, samples: int) -> tuple:
    """RPO n4 k8 stages with the benchmark's BRDF over traced or rest-pose visibility."""
    from warpshade.methods.rpo._rows import rpo_stages as base

    out = []
    for name, kind, params, inputs in base(visibility, samples=samples):
        if kind == "rpo.shade":
            params = {**params, "brdf": "beckmann", "roughness": ROUGHNESS, "f0": F0, "specular": list(SPECULAR)}
        out.append((name, kind, params, inputs))
    return tuple(out)


def settings(quick: bool, ssdf128: bool) -> list:
    """``(method, setting, stages)`` rows of part 1."""
    if quick:
        # one environment table only (each lobe count builds its own, minutes on the CPU)
        return [("sg", QUICK_SG, sg_stages(QUICK_SSDF)),
                ("ldprt-glossy", "n4 b3 N3 s16", ldprt_stages(4, 3, 3, samples=16)),
                ("rpo", "traced n4 k8 s16", rpo_stages("traced", 16))]
    rows = [("sg", f"ssdf {r} x4 e8", sg_stages(r)) for r in (16, 32, 64)]
    if ssdf128:
        rows.append(("sg", "ssdf 128 x4 e8", sg_stages(128)))
    rows += [("sg", "ssdf 32 x4 e8 sun in sky", sg_stages(32, sun="keep")),
             ("sg", "ssdf 32 x4 e8 paper", sg_stages(32, sun="keep", horizon=False, narrow_lights="sg")),
             ("ldprt-glossy", "n4 b3 N3", ldprt_stages(4, 3, 3)),
             ("ldprt-glossy", "n6 b12 N4", ldprt_stages(6, 12, 4)),
             ("rpo", "traced n4 k8 s256", rpo_stages("traced", 256)),
             ("rpo", "static n4 k8 s1024", rpo_stages("static", 1024))]
    return rows


class PrecomputeLog:
    """Seconds each artifact took when it was computed, kept in the artifact cache directory."""

    def __init__(self):
        from warpshade.graph import default_cache_dir

        self.path = Path(default_cache_dir()) / PRECOMPUTE_LOG
        try:
            self.seconds = json.loads(self.path.read_text())
        except (OSError, ValueError):
            self.seconds = {}

    def charge(self, runtime) -> tuple:
        """(precompute seconds of the run's artifacts or None when one of them was loaded from the
        cache without a recorded time -- computed by another process --, which came from the cache)."""
        from warpshade._fileio import write_json_atomic

        total, cached = 0.0, []
        for name, timing in runtime.timings.items():
            key = runtime.artifact_keys.get(name)
            if key is None:
                continue
            if timing.cache == "miss":
                self.seconds[key] = float(timing.precompute_s)
            else:
                cached.append(name if key in self.seconds else f"{name} (computed elsewhere: time not measured)")
            if self.seconds.get(key) is None or total is None:
                total = None
            else:
                total += self.seconds[key]
        self.path.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(self.path, self.seconds)
        return total, cached


def _errors(radiance: dict, truth: dict, meshes=None) -> dict:
    """Metrics per frame and combined; per frame also the ratio of mean radiance to the truth's
    and the relative RMS per mesh (``meshes``: [(name, vertex slice)])."""
    from warpshade.measure import error_metrics, setting_error

    err = setting_error(radiance, truth)
    per = {}
    for p in err["per_frame"]:
        f = p["frame"]
        est, ref = np.asarray(radiance[f], np.float64), np.asarray(truth[f]["radiance"], np.float64)
        entry = {"rel_rms": p["rel_rms"], "rel_rms_debiased": p.get("rel_rms_debiased"), "rel_p99": p["rel_p99"],
                 "noise_rel_rms": p.get("noise_rel_rms"), "mean_ratio": float(est.mean() / max(ref.mean(), 1e-30))}
        for name, sl in meshes or ():
            entry[f"rel_rms_{name}"] = error_metrics(est[sl], ref[sl], truth[f]["stderr"][sl])["rel_rms"]
        per[f"{f:g}"] = entry
    return {"mean": {k: v for k, v in err.items() if k != "per_frame" and isinstance(v, (int, float))}, "per_frame": per}


def _meshes(scene) -> list:
    """(name, vertex slice) of each mesh of the scene."""
    out = []
    for k, m in enumerate(scene.meshes):
        name = str(getattr(m, "path", "") or f"mesh{k}").split("/")[-1]
        out.append((name, slice(m.vertex_offset, m.vertex_offset + m.vertex_count)))
    return out


# ---- part 1: per-vertex rows ------------------------------------------------------------------


def graph_rows(scene, lighting, quick, ssdf128, gt_samples, timing_frames, log):
    """Compile and run every graph row; their runtimes stay for the interleaved timing."""
    from warpshade.measure import ground_truth, reference_model, run_setting
    from warpshade.measure import GT_SEED

    rows, runtimes, truths = [], [], {}
    for method, setting, stages in settings(quick, ssdf128):
        t0 = time.perf_counter()
        try:
            res = run_setting(scene, lighting, stages, list(ERROR_FRAMES), timing_frames=timing_frames[:3], device="cpu",
                              cache_dir="default", name=f"sg-bench-{method}-{setting}".replace(" ", "-"))
        except Exception as exc:  # a failing row is reported, never silently dropped
            print(f"  {method} {setting}: FAILED {exc!r}", flush=True)
            rows.append({"method": method, "setting": setting, "failed": repr(exc)})
            continue
        rt = res["runtime"]
        model = reference_model(rt)
        # one truth for every row: the stages hand the same BRDF and eye, and colours that differ only
        # by float32 rounding (0.9 vs 0.89999998), which would otherwise hash to another reference
        desc = json.dumps({"brdf": model["brdf"].describe(), "eye": np.round(np.asarray(model["eye"], float), 5).tolist(),
                           "color": np.round(np.asarray(model["color"], float), 5).tolist()}, sort_keys=True)
        if desc not in truths:
            truths[desc] = ground_truth(scene, lighting, list(ERROR_FRAMES), gt_samples, "cpu", model=model, seed=GT_SEED,
                                        progress=True)
        precompute_s, cached = log.charge(rt)
        row = {"method": method, "setting": setting, "params": [dict(name=n, type=t, **p) for (n, t, p, _) in stages],
               "precompute_s": precompute_s, "precompute_from_cache": cached, "compile_and_setup_s": res["compile_s"],
               "model_bytes": int(res["model_bytes"]), "stage_ms": res["stage_ms"], "reference": json.loads(desc),
               "reports": _jsonable(res["reports"]), **_errors(res["radiance"], truths[desc], _meshes(scene))}
        rows.append(row)
        runtimes.append((row, rt))
        e = row["per_frame"]
        pre = "not measured" if precompute_s is None else f"{precompute_s:.1f} s"
        print(f"  {method} {setting}: precompute {pre}{' (cached)' if cached else ''}, "
              f"{row['model_bytes'] / 2**20:.2f} MB, rel RMS " + ", ".join(f"frame {k}: {v['rel_rms']:.4f}" for k, v in e.items())
              + f" ({time.perf_counter() - t0:.0f} s)", flush=True)
    return rows, runtimes, truths


def baseline_rows(scene, lighting, truth, spps):
    """Brute force: the glossy reference estimator itself each frame at low sample counts."""
    from warpshade.reference import GlossyReferenceShader
    from warpshade.scene import _materials as M

    brdf = M.Microfacet(ROUGHNESS, "beckmann", f0=F0)
    eye = np.asarray(scene.camera.position, np.float64)
    rows, shaders = [], []
    for k, spp in enumerate(spps):
        shader = GlossyReferenceShader(scene, brdf, eye, lighting.lights_at(ERROR_FRAMES[0]), spp, "mis", SPECULAR, "cpu",
                                       BASELINE_SEED + k)
        radiance = {float(f): shader.shade(f).radiance for f in ERROR_FRAMES}
        row = {"method": "brute force", "setting": f"glossy reference {spp} spp", "samples": spp, "precompute_s": 0.0,
               "model_bytes": 0, "seed": BASELINE_SEED + k, **_errors(radiance, truth, _meshes(scene))}
        rows.append(row)
        shaders.append((row, shader))
        print(f"  brute force {spp} spp: rel RMS " + ", ".join(f"frame {f}: {v['rel_rms']:.4f}" for f, v in row["per_frame"].items()),
              flush=True)
    return rows, shaders


def interleaved_timing(steppers, frames, rounds: int):
    """Median ms per frame of each ``(row, step(frame))``, rows stepped in turn at every frame."""
    from warpshade._wp import wp

    times = [[] for _ in steppers]
    for _ in range(rounds):
        for f in frames:
            for i, (_, step) in enumerate(steppers):
                wp.synchronize()
                t0 = time.perf_counter()
                step(f)
                wp.synchronize()
                times[i].append(time.perf_counter() - t0)
    for (row, _), t in zip(steppers, times):
        row["median_frame_ms"] = 1e3 * float(np.median(t))
        row["frames_timed"] = len(t)


def _runtime_step(rt):
    def step(f):
        out = rt.step(float(f))
        if hasattr(out, "numpy"):
            out.numpy()  # the frame is done when its radiance is on the host
    return step


def _shader_step(shader):
    def step(f):
        state = shader.scene.evaluate(float(f), device=shader.device)
        shader.shade_state(state.points, state.normals)
        shader.radiance.numpy()
    return step


# ---- part 2: per pixel ------------------------------------------------------------------------


def _sg_runtime(scene, lighting, stages, name):
    from warpshade.graph import GraphSpec, StageSpec

    spec = GraphSpec([StageSpec(n, t, dict(p), dict(i)) for (n, t, p, i) in stages], "shade.radiance", name=name)
    return spec.compile(scene, device="cpu", cache_dir="default", lighting=lighting)


def pixel_timing(rt, frames, width, height):
    """Full frames (:func:`render_frame`) and relighting only (shade over a reused G-buffer)."""
    from warpshade._wp import wp
    from warpshade.measure._pixels import pixel_bvh, pixel_stage, render_frame
    from warpshade.render import camera_for, render_gbuffer

    render_frame(rt, frames[0], width, height)  # warm-up: kernels built, BVH made
    parts = {"step": [], "gbuffer": [], "materials": [], "shade": [], "total": [], "frame": []}
    for f in frames:
        t0 = time.perf_counter()
        im = render_frame(rt, f, width, height)
        parts["frame"].append(time.perf_counter() - t0)
        for k in ("step", "gbuffer", "materials", "shade", "total"):
            parts[k].append(im.seconds[k])
    st = pixel_stage(rt)
    rt.step(float(frames[-1]))
    cam = camera_for(rt.scene, float(frames[-1]), aspect=width / height)
    gb = render_gbuffer(pixel_bvh(rt), rt.state.normals, cam, width, height)
    relight = []
    st.render_pixels(gb).numpy()
    for _ in range(max(5, len(frames))):
        wp.synchronize()
        t0 = time.perf_counter()
        st.render_pixels(gb).numpy()
        relight.append(time.perf_counter() - t0)
    med = {f"{k}_ms": 1e3 * float(np.median(v)) for k, v in parts.items()}
    med["relight_ms"] = 1e3 * float(np.median(relight))
    med["frame_with_host_copy_ms"] = med.pop("frame_ms")
    med["fps_full"] = 1e3 / med["frame_with_host_copy_ms"]
    med["fps_relight"] = 1e3 / med["relight_ms"]
    med.update(width=width, height=height, frames=[float(f) for f in frames], relight_repeats=len(relight))
    return med


def _rel_rms(img, ref, mask):
    d = (img - ref)[mask]
    r = ref[mask]
    denom = float(np.sqrt(np.mean(r * r))) if r.size else 0.0
    return float(np.sqrt(np.mean(d * d)) / denom) if denom > 0 else float("nan"), denom


def vertex_vs_pixel(rt, frames, width, height, samples):
    """Fig. 8: per-vertex radiance interpolated per pixel and per-pixel shading, both against the
    per-pixel glossy reference (same BRDF, eye, colour, sky); images for the strip."""
    from warpshade.measure import ground_truth_model
    from warpshade.measure._pixels import pixel_bvh, pixel_stage, render_frame
    from warpshade.reference import reference_image
    from warpshade.render import interpolate_vertex_values, render_gbuffer

    st = pixel_stage(rt)
    out, images = {}, None
    for f in frames:
        im = render_frame(rt, f, width, height)
        vert = rt.step(float(f))
        vert = vert.numpy() if hasattr(vert, "numpy") else np.asarray(vert)
        gb = render_gbuffer(pixel_bvh(rt), rt.state.normals, im.camera, width, height)
        per_vertex = interpolate_vertex_values(gb, vert.astype(np.float32)).numpy().reshape(height, width, 3)
        model = ground_truth_model(st, rt.state.materials, rt.state.eye.numpy()[0])
        t0 = time.perf_counter()
        ref = reference_image(rt.scene, float(f), model["brdf"], camera=im.camera, width=width, height=height, samples=samples,
                              eye=model["eye"], lighting=rt.lighting.lights_at(float(f)), specular=im.materials["specular"],
                              include=("specular",), seed=PIXEL_SEED, device="cpu")
        ref_s = time.perf_counter() - t0
        mask = ref.mask & (im.coverage >= 1.0)
        e_px, denom = _rel_rms(im.linear, ref.radiance, mask)
        e_vx, _ = _rel_rms(per_vertex, ref.radiance, mask)
        noise = float(np.sqrt(np.mean(ref.stderr[mask] ** 2)) / denom) if denom > 0 else float("nan")
        out[f"{f:g}"] = {"per_pixel_rel_rms": e_px, "per_vertex_rel_rms": e_vx, "reference_noise_rel_rms": noise,
                         "pixels": int(mask.sum()), "reference_seconds": ref_s}
        print(f"  per pixel vs per vertex, frame {f:g}: per pixel {e_px:.4f}, per vertex {e_vx:.4f} "
              f"(reference noise {noise:.4f}, {int(mask.sum())} pixels)", flush=True)
        if images is None:
            images = (per_vertex, im.linear, ref.radiance, mask)
    return out, images


def textured_pixels(scene, env_only, stem, res, samples, width, height, frames, lights_size=(640, 480)):
    """Per-pixel error of the textured variant (environment only) and one frame with every light
    of the scene, the moving lamp included (PNG + EXR, ``lights_size`` pixels).

    :func:`warpshade.measure._pixels.measure_pixels` cannot measure it: it asks the stage for its
    reference model, which ``sg.shade`` refuses with ``textures = true``. So the same measurement
    is made here: the per-pixel materials the method shaded with (textures sampled at each hit)
    go to :func:`reference_image` as per-ray roughness and specular colour, with the stage's
    Beckmann BRDF, eye and the frame's lights; relative RMS over fully covered pixels."""
    from warpshade.measure._pixels import render_frame, write_pixel_images
    from warpshade.reference import reference_image
    from warpshade.scene import LightingSource
    from warpshade.scene import _materials as M

    out_dir = Path(stem).parent
    prefix = Path(stem).name
    rt = _sg_runtime(scene, env_only, sg_stages(res, textures=True), f"{prefix}-textured")
    brdf = M.Microfacet(ROUGHNESS, "beckmann", f0=F0)
    report = {"width": width, "height": height, "samples": samples, "seed": PIXEL_SEED, "frames": {},
              "measured_by": "bench_sg.textured_pixels (measure_pixels refuses textures = true)"}
    images = None
    for f in frames:
        im = render_frame(rt, f, width, height, textures=True)
        mats = im.materials
        eye = rt.state.eye.numpy()[0].astype(np.float64)
        ref = reference_image(scene, float(f), brdf, camera=im.camera, width=width, height=height, samples=samples, eye=eye,
                              lighting=env_only.lights_at(float(f)), roughness=mats["roughness"], specular=mats["specular"],
                              include=("specular",), seed=PIXEL_SEED, device="cpu")
        mask = ref.mask & (im.coverage >= 1.0)
        rel, denom = _rel_rms(im.linear, ref.radiance, mask)
        noise = float(np.sqrt(np.mean(ref.stderr[mask] ** 2)) / denom) if denom > 0 else float("nan")
        hit = np.asarray(mats["roughness"])[np.asarray(mats["roughness"]) > 0]
        report["frames"][f"{f:g}"] = {"rel_rms": rel, "noise": noise, "pixels": int(mask.sum()),
                                      "roughness_range": [float(hit.min()), float(hit.max())] if hit.size else None}
        print(f"  textured per pixel, frame {f:g}: rel RMS {rel:.4f} (reference noise {noise:.4f}; roughness "
              f"{report['frames'][f'{f:g}']['roughness_range']})", flush=True)
        if images is None:
            images = (im.linear, ref.radiance, rel)
    strip(f"{stem}-textured.png", [("SG per pixel, textured", images[0]), ("reference", images[1]),
                                   (f"|difference| x4 (rel RMS {images[2]:.3f})", images[0] - images[1])], images[1])
    report["image"] = f"{stem}-textured.png"
    lamp = LightingSource.fixed(list(scene.lights), scene.up_axis)
    rt2 = _sg_runtime(scene, lamp, sg_stages(res, textures=True, component="both", specular=[1.0, 1.0, 1.0]),
                      f"{prefix}-lights")
    frame = float(frames[-1])
    render_frame(rt2, frame, *(min(a, b) for a, b in zip((160, 120), lights_size)))  # warm-up
    t0 = time.perf_counter()
    paths = write_pixel_images(rt2, out_dir, frames=[frame], width=lights_size[0], height=lights_size[1], textures=True)
    report["lights_image"] = {"frame": frame, "paths": [str(p) for p in paths], "seconds": time.perf_counter() - t0,
                              "lights": [type(light).__name__ for light in scene.lights], "component": "both"}
    print(f"  lamp frame {frame:g}: wrote {', '.join(Path(p).name for p in paths)}", flush=True)
    return report


def strip(path, panels, ref):
    """A row of tone-mapped images (one exposure from ``ref``); differences shown as |x| at 4x."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from warpshade._fileio import atomic_path
    from warpshade.measure._pixels import exposure_for
    from warpshade.render import tonemap_f64

    ex = exposure_for(ref.reshape(-1, 3))
    fig, axes = plt.subplots(1, len(panels), figsize=(3.2 * len(panels), 2.9), squeeze=False)
    for ax, (title, img) in zip(axes[0], panels):
        diff = title.startswith("|")
        ax.imshow(tonemap_f64(np.abs(img) if diff else img, exposure=ex + (2.0 if diff else 0.0)))
        ax.set_title(title, fontsize=7)
        ax.axis("off")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


# ---- charts -------------------------------------------------------------------------------------


def pareto(doc, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    from warpshade._fileio import atomic_path

    rows = [r for r in doc["rows"] if "failed" not in r]
    methods = sorted({r["method"] for r in rows})
    cmap = plt.get_cmap("tab10")
    color = {m: cmap(i) for i, m in enumerate(methods)}
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8))
    for ax, key in zip(axes, ("rel_rms", "rel_rms_debiased")):
        sg_rows = 0
        for r in rows:
            x, y = r["median_frame_ms"], max(float(r["mean"].get(key) or 0.0), 1e-4)
            ax.scatter(x, y, s=30, color=color[r["method"]], marker="s" if r["method"] == "brute force" else "o", zorder=3)
            if r["method"] == "sg":  # the SG rows sit at one error: labels stacked below them, linked by a line
                ax.annotate(r["setting"], (x, y), fontsize=6, xytext=(4, -14 - 8 * sg_rows), textcoords="offset points",
                            color=color["sg"], arrowprops={"arrowstyle": "-", "lw": 0.4, "color": color["sg"]})
                sg_rows += 1
            else:
                ax.annotate(r["setting"], (x, y), fontsize=6, xytext=(3, 2), textcoords="offset points")
        brute = sorted((r["median_frame_ms"], r["mean"].get(key) or 1e-4) for r in rows if r["method"] == "brute force")
        if len(brute) > 1:
            ax.plot(*zip(*brute), color=color["brute force"], lw=1, ls="--", zorder=1)
        pts = sorted((r["median_frame_ms"], r["mean"].get(key) or 1e-4) for r in rows)
        front, best = [], np.inf
        for x, y in pts:
            if y < best:
                front.append((x, y))
                best = y
        if len(front) > 1:
            ax.plot(*zip(*front), color="0.6", lw=1, ls=":", zorder=1, label="Pareto front")
        noise = np.mean([r["mean"].get("noise_rel_rms", np.nan) for r in rows if r["method"] != "brute force"])
        if key == "rel_rms" and np.isfinite(noise):
            ax.axhline(noise, color="0.3", lw=0.8, ls="-.", label=f"reference noise ({doc['gt_samples']} spp)")
        ax.set_xscale("log")
        ax.set_yscale("log")
        for axis in (ax.xaxis, ax.yaxis):
            axis.set_major_formatter(matplotlib.ticker.LogFormatterSciNotation())
            axis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_xlabel("time per frame (ms, CPU)")
        ax.set_ylabel(f"{key.replace('_', ' ')} of specular radiance, frames 0 + 24")
        ax.grid(True, which="both", alpha=0.25)
        ax.set_title("raw" if key == "rel_rms" else "reference variance removed", fontsize=9)
    handles = [plt.Line2D([], [], marker="s" if m == "brute force" else "o", ls="", color=color[m], label=m) for m in methods]
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8, frameon=False)
    fig.suptitle(f"sunlit ({doc['vertex_count']:,} vertices), sharp sky, Beckmann 0.2: time per frame vs error against the "
                 f"glossy reference ({doc['date']}, cpu)", fontsize=9)
    fig.tight_layout(rect=(0, 0.06, 1, 0.95))
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist() if x.size <= 64 else f"array{list(x.shape)}"
    if isinstance(x, (np.floating, np.integer, np.bool_)):
        return x.item()
    if isinstance(x, (str, int, float, bool)) or x is None:
        return x
    return repr(x)


def table(doc) -> str:
    lines = ["| method | setting | ms/frame | precompute s | model MB | rel RMS f0 | f24 | mean | debiased mean |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in doc["rows"]:
        if "failed" in r:
            lines.append(f"| {r['method']} | {r['setting']} | FAILED: {r['failed'][:60]} |")
            continue
        pf = r["per_frame"]
        pre = "n/m" if r["precompute_s"] is None else f"{r['precompute_s']:.1f}"
        lines.append(f"| {r['method']} | {r['setting']} | {r['median_frame_ms']:.2f} | {pre} | "
                     f"{r['model_bytes'] / 2**20:.2f} | {pf['0']['rel_rms']:.4f} | {pf['24']['rel_rms']:.4f} | "
                     f"{r['mean']['rel_rms']:.4f} | {r['mean'].get('rel_rms_debiased', float('nan')):.4f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    from warpshade._fileio import write_json_atomic
    from warpshade._wp import cpu_workers, wp

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true",
                    help="smoke profile: SSDF 8, 16-ray LDPRT and RPO, 32-spp truth, tiny pictures")
    ap.add_argument("--ssdf128", action="store_true", help="also the paper's SSDF 128 (512 traced; ~7+ min of bake)")
    ap.add_argument("--gt-samples", type=int, default=None, help="rays per vertex of the truth (default 1024; quick 32)")
    ap.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    ap.add_argument("--replot", default=None, metavar="JSON", help="redraw the Pareto chart of an earlier results JSON")
    args = ap.parse_args(argv)
    if args.replot:
        path = Path(args.replot)
        try:
            doc = json.loads(path.read_text())
            doc["rows"], doc["gt_samples"]
        except (OSError, ValueError, KeyError) as exc:
            raise SystemExit(f"--replot {path}: not a bench_sg results file ({exc})")
        pareto(doc, str(path)[: -len(".json")] + "-pareto.png")
        print(table(doc))
        return 0
    quick = args.quick
    if quick and args.out is None:
        ap.error("--quick writes only into --out DIR (never benchmarks/results)")
    gt_samples = args.gt_samples or (32 if quick else 1024)
    t_all = time.perf_counter()
    scene, lighting = load(quick)
    date = str(datetime.date.today())
    out = Path(args.out or RESULTS)
    out.mkdir(parents=True, exist_ok=True)
    stem = str(out / f"sg-{date}-cpu{'-quick' if quick else ''}")
    timing_frames = [float(f) for f in scene.frames[:: max(1, len(scene.frames) // (4 if quick else 12))]]
    doc = {"date": date, "device": "cpu", "machine": f"{platform.processor() or platform.machine()}",
           "threads": cpu_workers(), "warp": wp.config.version, "command": " ".join(["python", *sys.argv]),
           "scene": "bundled:sunlit", "vertex_count": scene.vertex_count,
           "lighting": "scene environment only (sharp sky: 1.2 deg sun), not turning",
           "brdf": {"model": "beckmann", "roughness": ROUGHNESS, "f0": F0, "specular": SPECULAR},
           "gt_samples": gt_samples, "error_frames": list(ERROR_FRAMES), "timing_frames": timing_frames,
           "error_note": "rel_rms: raw relative RMS over vertices against the cached glossy reference; rel_rms_debiased: "
                         "its Monte Carlo variance removed; noise_rel_rms: the reference's own noise"}
    log = PrecomputeLog()
    print(f"part 1: per-vertex rows ({scene.vertex_count} vertices, truth {gt_samples} spp)", flush=True)
    rows, runtimes, truths = graph_rows(scene, lighting, quick, args.ssdf128, gt_samples, timing_frames, log)
    truth = next(iter(truths.values()))
    base_rows, shaders = baseline_rows(scene, lighting, truth, (4,) if quick else (16, 64, 256))
    doc["reference_models"] = len(truths)
    steppers = [(row, _runtime_step(rt)) for row, rt in runtimes] + [(row, _shader_step(s)) for row, s in shaders]
    print(f"  timing {len(steppers)} rows interleaved over {len(timing_frames)} frames", flush=True)
    interleaved_timing(steppers, timing_frames, 1 if quick else 2)
    doc["rows"] = rows + base_rows
    for r in doc["rows"]:
        if "failed" not in r:
            pre = "    n/m" if r["precompute_s"] is None else f"{r['precompute_s']:7.1f}"
            print(f"  {r['method']:12s} {r['setting']:28s} {r['median_frame_ms']:9.2f} ms/frame  precompute "
                  f"{pre} s  rel RMS {r['per_frame']['0']['rel_rms']:.4f} / "
                  f"{r['per_frame']['24']['rel_rms']:.4f}", flush=True)
    keep = {id(rt) for row, rt in runtimes if row["setting"] == (QUICK_SG if quick else "ssdf 32 x4 e8")}
    sg_rt = next(rt for row, rt in runtimes if id(rt) in keep)
    best_rt = next((rt for row, rt in runtimes if row["setting"] == "ssdf 128 x4 e8"), None)
    del steppers, shaders

    print("part 2: per pixel (SG, SSDF %d)" % (QUICK_SSDF if quick else 32), flush=True)
    w, h = (64, 48) if quick else (640, 480)
    doc["pixels"] = {"ssdf_resolution": QUICK_SSDF if quick else 32}
    doc["pixels"]["timing"] = pixel_timing(sg_rt, timing_frames[: 5 if not quick else 3] if not quick else timing_frames[:3],
                                           w, h)
    t = doc["pixels"]["timing"]
    print(f"  {w}x{h}: full frame {t['frame_with_host_copy_ms']:.1f} ms ({t['fps_full']:.1f} fps; step {t['step_ms']:.1f}, "
          f"G-buffer {t['gbuffer_ms']:.1f}, materials {t['materials_ms']:.1f}, shade {t['shade_ms']:.1f}), relight only "
          f"{t['relight_ms']:.1f} ms ({t['fps_relight']:.1f} fps)", flush=True)
    px_samples = 8 if quick else 512
    pw, ph = (40, 30) if quick else (160, 120)
    doc["pixels"]["vertex_vs_pixel"], images = vertex_vs_pixel(sg_rt, list(ERROR_FRAMES), pw, ph, px_samples)
    doc["pixels"]["vertex_vs_pixel_settings"] = {"width": pw, "height": ph, "samples": px_samples, "seed": PIXEL_SEED}
    pv, pp, ref, _ = images
    e0 = doc["pixels"]["vertex_vs_pixel"][f"{ERROR_FRAMES[0]:g}"]
    strip(f"{stem}-pixels.png", [(f"SG per vertex, interpolated (rel RMS {e0['per_vertex_rel_rms']:.3f})", pv),
                                 (f"SG per pixel (rel RMS {e0['per_pixel_rel_rms']:.3f})", pp),
                                 (f"reference {px_samples} spp", ref), ("|per vertex - reference| x4", pv - ref),
                                 ("|per pixel - reference| x4", pp - ref)], ref)
    if best_rt is not None:
        print("  the same at SSDF 128", flush=True)
        doc["pixels"]["vertex_vs_pixel_ssdf128"], images128 = vertex_vs_pixel(best_rt, list(ERROR_FRAMES[:1]), 160, 120,
                                                                             px_samples)
        pv, pp, ref, _ = images128
        e0 = doc["pixels"]["vertex_vs_pixel_ssdf128"][f"{ERROR_FRAMES[0]:g}"]
        strip(f"{stem}-pixels-ssdf128.png", [(f"SSDF 128 per vertex (rel RMS {e0['per_vertex_rel_rms']:.3f})", pv),
                                             (f"SSDF 128 per pixel (rel RMS {e0['per_pixel_rel_rms']:.3f})", pp),
                                             (f"reference {px_samples} spp", ref), ("|per vertex - reference| x4", pv - ref),
                                             ("|per pixel - reference| x4", pp - ref)], ref)
        del best_rt
    if quick:
        doc["pixels"]["textured"] = textured_pixels(scene, lighting, stem, QUICK_SSDF, 8, pw, ph, ERROR_FRAMES[:1], (pw, ph))
    else:
        doc["pixels"]["textured"] = textured_pixels(scene, lighting, stem, 32, 256, 160, 120, ERROR_FRAMES)
    del runtimes
    doc["meshes"] = [{"name": n, "vertices": [sl.start, sl.stop], "animation": m.animation}
                     for (n, sl), m in zip(_meshes(scene), scene.meshes)]
    doc["seconds"] = time.perf_counter() - t_all
    write_json_atomic(f"{stem}.json", _jsonable(doc), indent=1)
    pareto(doc, f"{stem}-pareto.png")
    print(table(doc))
    print(f"wrote {stem}.json, -pareto.png, -pixels.png in {doc['seconds']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
