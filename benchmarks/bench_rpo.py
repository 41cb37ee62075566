"""Reflectance product operators: error against the glossy ray-traced reference, cost, swaps.

Part 1 -- the operators' share of the error (k = 1..16 factors, n = 3..6) on the bend, the cloth
and the figure, under a constant sky (no SH truncation of the lighting) and under the scenes' own
sunny sky: SH visibility ray traced in the tangent frames (1024 rays, open below the horizon),
shaded in float64 (:func:`warpshade.methods.rpo.shade_f64`) with the operators of each
(n, k), against the glossy ray-traced reference of the same BRDF, eye and colour; next to the
exact BRDF under the same order-n visibility and lighting
(:func:`~warpshade.methods.rpo.shade_exact_brdf`, quadrature): the issue's goal is RPO error
within 1.1x of that. Variants at n = 4, k = 8: the 3-lobe ZH lighting, the cosine re-applied by
the product matrix of eq. 14, view factors at the paper's order n.

Part 2 -- against glossy LDPRT on the bend (rest pose frame 0, bent frame 30) and the figure
(frame 30): the same BRDF, eye and colour through the stage graphs (``stages/bend_ldprt_glossy``
as is, and rebaked at the frame; ``rpo.shade`` over per-frame traced visibility and over the
rest-pose bake), every run measured against the same cached reference.

Part 3 -- cost per frame (median of replayed frames, and per stage from a profile) of each
visibility generator plus the operators, and of the shading alone per setting (rotation vs ZH
lighting, Gaunt vs dense matrices, k); BRDF build time per kind, a run-time swap (first build and
cached), storage per BRDF.

Part 4 -- where it fails: unshadowed operators against quadrature of the BRDF itself over GGX
roughness (n = 4 and 6, full rank): where low-order SH stops being the right basis.

Writes ``rpo-<date>-cpu[-quick].json`` and ``-sweep.png``, ``-roughness.png``, ``-cost.png``.

Usage::

    python benchmarks/bench_rpo.py [--quick] [--scenes bend,cloth,figure] [--gt-samples 1024] [--out DIR]
"""

from __future__ import annotations

import argparse
import datetime
import platform
import sys
import time
from pathlib import Path

import numpy as np

#: Smoke profile (tests/test_benchmarks.py): slow, kept out of the default suite (``-m "not slow"``):
#: 42 s: operator builds and reference shading.
PROFILE = {"slow": True}

ROOT = Path(__file__).resolve().parent.parent

RESULTS = ROOT / "benchmarks" / "results"
GT_SEED = 4343
BRDF_PARAMS = {"roughness": 0.5}
COLOR = (0.9, 0.9, 0.9)
ORDERS = (3, 4, 5, 6)
RANKS = (1, 2, 4, 8, 12, 16)


def _rel(est, truth, debiased: bool = False) -> float:
    """Relative RMS against the reference; ``debiased``: with the reference's own noise removed."""
    from warpshade.measure import error_metrics

    m = error_metrics(est, truth["radiance"], truth["stderr"])
    return float(m["rel_rms_debiased" if debiased else "rel_rms"])


def _lightings(scene):
    from warpshade.graph import lighting_from_spec
    from warpshade.scene import LightingSource

    return {"constant": lighting_from_spec({"source": "constant"}, scene, None),
            "sky": LightingSource.fixed(scene.lights, scene.up_axis)}


def sweep(key, frames, gt_samples, quick):
    """Part 1 on one scene: errors per (lighting, frame, n, k)."""
    from warpshade.geometry._frames import TangentFrames
    from warpshade.measure import ground_truth, load_bench_scene
    from warpshade.methods.rpo import build_operator, fit_zh_lighting, shade_exact_brdf, shade_f64
    from warpshade.scene import _materials as M
    from warpshade.transfer import compute

    scene, _ = load_bench_scene(key, rotate_degrees_per_frame=0.0)
    brdf = M.Microfacet(**BRDF_PARAMS)
    eye = np.asarray(scene.camera.position, np.float64)
    model = {"brdf": brdf, "eye": eye, "color": np.array(COLOR)}
    tf = TangentFrames.from_scene(scene, device="cpu")
    orders = (4,) if quick else ORDERS
    ranks = (8,) if quick else RANKS
    ops = {(n, k): build_operator(brdf, n, k) for n in orders for k in ranks if k <= n * n}
    out = []
    for lname, lighting in _lightings(scene).items():
        truth = ground_truth(scene, lighting, frames, gt_samples, "cpu", model=model, seed=GT_SEED, progress=True)
        for f in frames:
            st = scene.evaluate(f, device="cpu")
            fr = tf.compute(st.points, st.normals).numpy().astype(np.float64)
            pts = st.points.numpy().astype(np.float64)
            vis6 = compute(scene, f, max(orders), 64 if quick else 1024, space="local", device="cpu", seed=3, below_horizon="visible").visibility
            row = {"scene": key, "lighting": lname, "frame": float(f), "noise": float(
                np.sqrt(np.mean(truth[f]["stderr"] ** 2)) / np.sqrt(np.mean(truth[f]["radiance"] ** 2))), "orders": {}}
            for n in orders:
                vis = vis6[:, : n * n].astype(np.float64)
                light = lighting.sh(n, float(f))
                exact = shade_exact_brdf(fr, pts, eye, vis, light, brdf, COLOR)
                entry = {"exact_brdf": _rel(exact, truth[f]), "exact_brdf_debiased": _rel(exact, truth[f], True),
                         "rpo": {}, "rpo_debiased": {}}
                for k in ranks:
                    if k > n * n:
                        continue
                    est, _ = shade_f64(fr, pts, eye, vis, [ops[(n, k)]], np.zeros(len(pts), int), light, COLOR)
                    entry["rpo"][str(k)] = _rel(est, truth[f])
                    entry["rpo_debiased"][str(k)] = _rel(est, truth[f], True)
                if n == 4:
                    zh = fit_zh_lighting(light, 3)
                    est, _ = shade_f64(fr, pts, eye, vis, [ops[(4, 8)]], np.zeros(len(pts), int), light, COLOR, zh=zh)
                    entry["rpo_k8_zh3"] = _rel(est, truth[f])
                    entry["zh3_fit_error"] = zh.error
                    cos_op = build_operator(brdf, 4, 8, cosine="product")
                    est, _ = shade_f64(fr, pts, eye, vis, [cos_op], np.zeros(len(pts), int), light, COLOR)
                    entry["rpo_k8_cosine_product"] = _rel(est, truth[f])
                    paper_op = build_operator(brdf, 4, 8, view_order=4)
                    est, _ = shade_f64(fr, pts, eye, vis, [paper_op], np.zeros(len(pts), int), light, COLOR)
                    entry["rpo_k8_view_order_n"] = _rel(est, truth[f])
                    entry["ratio_k8_debiased"] = entry["rpo_debiased"]["8"] / max(entry["exact_brdf_debiased"], 1e-12)
                row["orders"][str(n)] = entry
            e4 = row["orders"]["4"]
            print(f"  {key} {lname} frame {f:g}: exact BRDF n4 {e4['exact_brdf']:.4f} (debiased {e4['exact_brdf_debiased']:.4f}), "
                  f"RPO n4 k8 {e4['rpo']['8']:.4f} ({e4['rpo_debiased']['8']:.4f}; ratio {e4['ratio_k8_debiased']:.3f}), "
                  f"zh3 {e4['rpo_k8_zh3']:.4f}, noise {row['noise']:.4f}", flush=True)
            out.append(row)
    return out


def versus_ldprt(key, frames, gt_samples, samples=(256, 256, 1024)):
    """Part 2: glossy LDPRT (rest bake, rebaked) and RPO graphs, the same reference; ``samples``:
    rays per vertex of the glossy LDPRT fit, the traced and the rest-pose visibility."""
    from warpshade.graph import GraphSpec, StageSpec
    from warpshade.measure import load_bench_scene, measure_error

    scene, _ = load_bench_scene(key, rotate_degrees_per_frame=0.0)
    lighting = _lightings(scene)["constant"]
    ldprt = lambda frame=None: [  # noqa: E731
        StageSpec("fit", "ldprt.glossy_fit", {"order": 4, "lobes": 3, "rank": 3, "brdf": "microfacet", "samples": samples[0],
                                              **BRDF_PARAMS, **({} if frame is None else {"frame": frame})}),
        StageSpec("tangents", "ldprt.tangents"),
        StageSpec("shade", "ldprt.glossy_shade", {"order": 4, "lobes": 3, "rank": 3, "specular": list(COLOR)})]
    rpo_shade = StageSpec("shade", "rpo.shade", {"order": 4, "rank": 8, "brdf": "ggx", **BRDF_PARAMS, "specular": list(COLOR)})
    settings = {"glossy LDPRT n4 b3 N3 (rest bake)": ldprt()}
    for f in frames:
        if f != scene.frames[0]:
            settings[f"glossy LDPRT n4 b3 N3 (baked at frame {f:g})"] = ldprt(float(f))
    settings[f"RPO n4 k8, traced visibility s{samples[1]}"] = [
        StageSpec("vis", "rpo.visibility_traced", {"order": 4, "samples": samples[1]}), rpo_shade]
    settings["RPO n4 k8, rest-pose visibility"] = [StageSpec("vis", "rpo.visibility_static", {"order": 4, "samples": samples[2]}),
                                                    StageSpec("tangents", "ldprt.tangents"), rpo_shade]
    out = []
    for label, stages in settings.items():
        rt = GraphSpec(stages=stages, output="shade.radiance").compile(scene, device="cpu", lighting=lighting, progress=False)
        m = measure_error(rt, frames=list(frames), samples=gt_samples, seed=GT_SEED)
        per = {str(p["frame"]): p["rel_rms"] for p in m.error["per_frame"]}
        print(f"  {key} constant sky: {label}: " + ", ".join(f"frame {k}: {v:.4f}" for k, v in per.items()), flush=True)
        out.append({"scene": key, "lighting": "constant", "setting": label, "per_frame": per,
                    "noise": [p["noise_rel_rms"] for p in m.error["per_frame"]]})
    return out


def costs(key, quick):
    """Part 3: per-frame cost of each generator + the operators, and of settings of the shading."""
    from warpshade.measure import load_bench_scene, run_setting
    from warpshade.methods.rpo._rows import rpo_stages

    scene, lighting = load_bench_scene(key)
    frames = list(scene.frames[:: max(1, len(scene.frames) // (2 if quick else 16))])
    gens = ["traced", "static"] + (["shexp"] if key == "figure" else [])
    if quick:
        settings = {f"{g} n4 k8": rpo_stages(g, samples=32) for g in gens}
    else:
        settings = {f"{g} n4 k8": rpo_stages(g, samples=1024 if g == "static" else 256) for g in gens}
    if not quick:
        settings.update({
            "static n4 k8 zh3": rpo_stages("static", lighting="zh", samples=1024),
            "static n4 k8 matrices": rpo_stages("static", evaluation="matrices", samples=1024),
            "static n4 k4": rpo_stages("static", rank=4, samples=1024),
            "static n4 k16": rpo_stages("static", rank=16, samples=1024),
            "static n3 k8": rpo_stages("static", order=3, samples=1024),
            "static n6 k8": rpo_stages("static", order=6, samples=1024),
        })
    out = []
    for label, stages in settings.items():
        res = run_setting(scene, lighting, stages, frames[:1], timing_frames=frames, device="cpu", cache_dir="default",
                          name=f"rpo-{label}".replace(" ", "-"))
        row = {"scene": key, "setting": label, "frame_ms": res["frame_ms"], "stage_ms": res["stage_ms"],
               "model_bytes": res["model_bytes"], "vertices": scene.vertex_count}
        print(f"  {key}: {label}: {res['frame_ms']:.2f} ms/frame, stages {({k: round(v, 2) for k, v in res['stage_ms'].items()})}",
              flush=True)
        out.append(row)
    return out


def kernel_costs(vertices: int = 65536, repeats: int = 7, orders=(3, 4, 6)):
    """Part 3: the shading kernel alone on synthetic receivers, settings measured side by side
    (interleaved repeats, medians): ns per vertex and the ratio to the default setting."""
    from warpshade._wp import launch_parallel, wp
    from warpshade.basis import sh
    from warpshade.basis.sh_warp import sh_kernels
    from warpshade.methods.rpo import build_operator, _kernels as kernels
    from warpshade.scene import _materials as M

    rng = np.random.default_rng(0)
    dev = "cpu"
    q, _ = np.linalg.qr(rng.normal(size=(vertices, 3, 3)))
    frames = wp.array(q.astype(np.float32), dtype=wp.mat33, device=dev)
    pts = wp.array((rng.normal(size=(vertices, 3)) * 0.1).astype(np.float32), dtype=wp.vec3, device=dev)
    eye = wp.array(np.array([[0.0, 0.0, 5.0]], np.float32), dtype=wp.vec3, device=dev)
    configs = {}
    for n in orders:
        for label, kw in (("rotate gaunt", {}), ("zh3 gaunt", {"lighting": "zh"}), ("rotate matrices", {"evaluation": "matrices"}),
                          ("rotate gaunt cosine-product", {"cosine": "product"})):
            configs[f"n{n} k8 {label}"] = (n, kw)
    setups = {}
    for name, (n, kw) in configs.items():
        op = build_operator(M.Microfacet(0.5), n, 8, cosine=kw.get("cosine", "brdf"))
        mats = op.matrices()[None] if kw.get("evaluation") == "matrices" else np.zeros((1, 1, 1, 1))
        k = kernels.shade_kernel(n, op.view_order, kw.get("lighting", "rotate"), kw.get("cosine", "brdf"), "local",
                                 kw.get("evaluation", "gaunt"))
        surface = kernels.Receivers()
        surface.frames, surface.points = frames, pts
        surface.visibility = wp.array(rng.normal(size=(vertices, n * n)).astype(np.float32), device=dev)
        surface.material = wp.zeros(vertices, dtype=wp.int32, device=dev)
        ops = kernels.Operators()
        ops.light_sh = wp.array(op.light_sh[None].astype(np.float32), device=dev)
        ops.view_sh = wp.array(op.view_sh[None].astype(np.float32), device=dev)
        ops.rank = wp.array(np.array([8], np.int32), device=dev)
        ops.channels = wp.array(np.array([1], np.int32), device=dev)
        ops.matrices = wp.array(mats.astype(np.float32), device=dev)
        ops.cos_sh = wp.array(sh.clamped_cosine_sh(n).astype(np.float32), device=dev)
        ops.specular = wp.vec3(1.0, 1.0, 1.0)
        lit = kernels.ViewLighting()
        lit.eye = eye
        lit.sh = wp.array(rng.normal(size=(3, n * n)).astype(np.float32), device=dev)
        lit.zh_axes = wp.array(rng.normal(size=(3, 3)).astype(np.float32), dtype=wp.vec3, device=dev)
        lit.zh_coeffs = wp.zeros((3, 3, n), dtype=wp.float32, device=dev)
        args = [surface, ops, lit, sh_kernels(n).tables(dev)]
        out = kernels.ShadeOutputs()
        out.radiance = wp.zeros((vertices, 3), dtype=wp.float32, device=dev)
        out.flags = wp.zeros(vertices, dtype=wp.int32, device=dev)
        out = [out]
        setups[name] = (k, args, out)
        launch_parallel(k, vertices, lambda a, b, args=args, out=out: args + [a] + out, dev)  # compile
    times = {name: [] for name in setups}
    for _ in range(repeats):
        for name, (k, args, out) in setups.items():
            wp.synchronize()
            t0 = time.perf_counter()
            launch_parallel(k, vertices, lambda a, b, args=args, out=out: args + [a] + out, dev)
            wp.synchronize()
            times[name].append(time.perf_counter() - t0)
    res = {}
    for name, t in times.items():
        n = configs[name][0]
        base = float(np.median(times[f"n{n} k8 rotate gaunt"]))
        res[name] = {"ns_per_vertex": 1e9 * float(np.median(t)) / vertices, "ratio_to_rotate_gaunt": float(np.median(t)) / base}
        print(f"  kernel {name}: {res[name]['ns_per_vertex']:.0f} ns/vertex ({res[name]['ratio_to_rotate_gaunt']:.2f}x)", flush=True)
    return res


def swaps_and_builds(key="figure", samples=256, repeats=3, quick=False):
    """Part 3: BRDF build time per kind (median of ``repeats``; ``quick``: GGX and the tabulated
    one only), a run-time swap on a scene (the figure; rest-pose visibility of ``samples`` rays),
    storage per BRDF."""
    import tempfile

    from warpshade.graph import GraphSpec, StageSpec
    from warpshade.measure import load_bench_scene
    from warpshade.methods.rpo import build_operator
    from warpshade.methods.rpo import _stages as rpo_stages_mod
    from warpshade.scene import _materials as M
    from warpshade.scene._tabulated import read_merl, write_merl

    builds = {}
    with tempfile.TemporaryDirectory() as tmp:
        merl = Path(tmp) / "ggx05.binary"
        write_merl(merl, M.Microfacet(0.5))
        kinds = {"lambert": M.Lambert(), "phong 20": M.Phong(20.0), "blinn-phong 40": M.BlinnPhong(40.0),
                 "ggx 0.5": M.Microfacet(0.5), "beckmann 0.3": M.Microfacet(0.3, "beckmann"),
                 "tabulated MERL 90x90x180 (GGX 0.5)": read_merl(merl)}
        if quick:
            kinds = {k: v for k, v in kinds.items() if k.startswith(("ggx", "tabulated"))}
        for name, brdf in kinds.items():
            t = []
            for _ in range(repeats):
                t.append(build_operator(brdf, 4, 8).build_s)
            builds[name] = float(np.median(t))
            print(f"  build n4 k8 {name}: {builds[name] * 1000:.0f} ms", flush=True)
    op = build_operator(M.Microfacet(0.5), 4, 8)
    storage = {"gaunt_floats": op.storage_floats("gaunt"), "matrices_floats": op.storage_floats("matrices"),
               "paper_bound_floats": 8 * 16 * (1 + 16), "gaunt_bytes": 4 * op.storage_floats("gaunt"),
               "matrices_bytes": 4 * op.storage_floats("matrices")}
    scene, lighting = load_bench_scene(key)
    spec = GraphSpec(stages=[StageSpec("vis", "rpo.visibility_static", {"order": 4, "samples": samples}),
                             StageSpec("tangents", "ldprt.tangents"),
                             StageSpec("shade", "rpo.shade", {"order": 4, "rank": 8, "brdf": "ggx", "roughness": 0.5})],
                     output="shade.radiance")
    rt = spec.compile(scene, device="cpu", lighting=lighting, progress=False)
    for _ in range(3):
        before = rt.step(10.0).numpy().copy()
    rpo_stages_mod.OPERATORS._items.clear()
    new = M.BlinnPhong(12.0)
    t0 = time.perf_counter()
    rt.set_material(new)
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    after = rt.step(10.0).numpy().copy()
    step_after = time.perf_counter() - t0
    rt.set_material(None)
    t0 = time.perf_counter()
    rt.set_material(new)
    cached = time.perf_counter() - t0
    again = rt.step(10.0).numpy().copy()
    rt.set_material(None)
    back = rt.step(10.0).numpy().copy()
    swap = {"set_material_first_s": first, "set_material_cached_s": cached, "next_frame_s": step_after,
            "next_frame_changed": bool(not np.allclose(after, before)), "cached_equal": bool(np.array_equal(after, again)),
            "swap_back_exact": bool(np.array_equal(back, before)), "scene": key, "vertices": scene.vertex_count}
    print(f"  swap on the {key}: set_material {first * 1000:.0f} ms (first), {cached * 1000:.2f} ms (cached); next frame "
          f"{step_after * 1000:.1f} ms, changed {swap['next_frame_changed']}, swap back exact {swap['swap_back_exact']}", flush=True)
    return builds, storage, swap


def roughness_sweep(quick):
    """Part 4: unshadowed operators vs quadrature of the BRDF over roughness."""
    from warpshade.basis import sh
    from warpshade.methods.rpo import build_operator
    from warpshade.scene import Environment, LightingSource
    from warpshade.scene import _materials as M

    rng = np.random.default_rng(5)
    count, z_nodes, phi_nodes = (30, 64, 128) if quick else (300, 256, 512)
    views = rng.normal(size=(count, 3))
    views[:, 2] = np.abs(views[:, 2]) + 0.15
    views /= np.linalg.norm(views, axis=1, keepdims=True)
    out = []
    for n in (4, 6):
        light = LightingSource.fixed([Environment.sky()], "Z").sh(n, 0.0)
        vis = np.zeros((count, n * n))
        vis[:, 0] = np.sqrt(4 * np.pi)
        for rough in ((0.5,) if quick else (0.02, 0.05, 0.1, 0.2, 0.3, 0.5, 0.8, 1.0)):
            brdf = M.Microfacet(rough)
            want = M.shade_unshadowed(brdf, views, lambda d: sh.basis(d, n) @ light.T, z_nodes=z_nodes, phi_nodes=phi_nodes)
            for k in sorted({8, n * n}):
                op = build_operator(brdf, n, k)
                got = op.shade_local(views, vis, light)
                err = float(np.sqrt(np.mean((got - want) ** 2) / np.mean(want**2)))
                out.append({"order": n, "rank": k, "roughness": rough, "rel_rms": err, "svd_truncation": op.truncation_error(),
                            "view_fit_error": op.view_fit_error})
            print(f"  roughness {rough:g} n{n}: " + ", ".join(f"k{r['rank']} {r['rel_rms']:.3f}" for r in out[-2:]), flush=True)
    return out


def charts(doc, stem):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = doc["sweep"]
    keys = sorted({(r["scene"], r["lighting"], r["frame"]) for r in rows})
    cols = min(4, len(keys))
    nrows = (len(keys) + cols - 1) // cols
    fig, axes = plt.subplots(nrows, cols, figsize=(4.2 * cols, 3.4 * nrows), squeeze=False)
    for ax, (sc, li, fr) in zip(axes.flat, keys):
        r = next(x for x in rows if (x["scene"], x["lighting"], x["frame"]) == (sc, li, fr))
        for i, (n, e) in enumerate(sorted(r["orders"].items())):
            ks = sorted(int(k) for k in e["rpo"])
            c = plt.get_cmap("viridis")(i / max(1, len(r["orders"]) - 1))
            ax.plot(ks, [e["rpo"][str(k)] for k in ks], "o-", color=c, label=f"RPO n={n}")
            ax.axhline(e["exact_brdf"], color=c, ls="--", lw=0.8)
        ax.axhline(r["noise"], color="grey", ls=":", lw=0.8, label="reference noise")
        ax.set_xscale("log", base=2)
        ax.set_yscale("log")
        ax.set_title(f"{sc} frame {fr:g}, {li} sky", fontsize=9)
        ax.set_xlabel("BRDF factors k")
        ax.set_ylabel("rel. RMS vs glossy reference")
        ax.legend(fontsize=6)
    for ax in list(axes.flat)[len(keys):]:
        ax.axis("off")
    fig.suptitle("RPO (GGX 0.5) over traced visibility; dashed: the exact BRDF under the same order-n visibility and lighting",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(f"{stem}-sweep.png", dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(5.5, 3.8))
    for n in (4, 6):
        for k in sorted({r["rank"] for r in doc["roughness"] if r["order"] == n}):
            sub = [r for r in doc["roughness"] if r["order"] == n and r["rank"] == k]
            ax.plot([r["roughness"] for r in sub], [r["rel_rms"] for r in sub], "o-", label=f"n={n}, k={k}")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("GGX roughness")
    ax.set_ylabel("unshadowed rel. RMS vs quadrature")
    ax.set_title("where low-order SH stops being the basis", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(f"{stem}-roughness.png", dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(7.5, 3.8))
    labels = [f"{c['scene']}: {c['setting']}" for c in doc["costs"]]
    vis = [sum(v for s, v in c["stage_ms"].items() if s not in ("shade", "scene")) for c in doc["costs"]]
    shade = [c["stage_ms"].get("shade", 0.0) for c in doc["costs"]]
    y = np.arange(len(labels))
    ax.barh(y, vis, label="visibility (+ frames)")
    ax.barh(y, shade, left=vis, label="RPO shading")
    ax.set_yticks(y, labels, fontsize=6)
    ax.set_xscale("log")
    ax.set_xlabel("ms per frame (profiled stages)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(f"{stem}-cost.png", dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    from warpshade._fileio import write_json_atomic

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true",
                    help="smoke profile: the bend at frame 0, n4 k8 only, 32-64 rays per vertex, one roughness")
    ap.add_argument("--scenes", default=None, help="comma-separated scenes (default bend,cloth,figure; quick: bend)")
    ap.add_argument("--gt-samples", type=int, default=None, help="reference rays per vertex (default 4096; quick 64)")
    ap.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    ap.add_argument("--kernels-into", default=None, metavar="JSON",
                    help="only measure the kernel costs and add them to an earlier results JSON")
    args = ap.parse_args(argv)
    if args.quick and args.out is None:
        ap.error("--quick writes only into --out DIR (never benchmarks/results)")
    args.scenes = args.scenes or ("bend" if args.quick else "bend,cloth,figure")
    args.gt_samples = args.gt_samples or (64 if args.quick else 4096)
    if args.kernels_into:
        import json

        doc = json.loads(Path(args.kernels_into).read_text())
        doc["kernels"] = kernel_costs()
        doc["kernels_command"] = " ".join(sys.argv)
        write_json_atomic(args.kernels_into, doc)
        return 0
    scenes = [s for s in args.scenes.split(",") if s]
    frames = {"bend": [0.0, 30.0], "cloth": [20.0, 40.0], "figure": [30.0]}
    if args.quick:
        frames = {k: v[:1] for k, v in frames.items()}
    t0 = time.perf_counter()
    doc = {"date": str(datetime.date.today()), "device": "cpu", "machine": platform.machine(), "command": " ".join(sys.argv),
           "brdf": {"model": "ggx", **BRDF_PARAMS}, "color": COLOR, "gt_samples": args.gt_samples}
    print("part 1: factorisation sweep", flush=True)
    doc["sweep"] = [r for s in scenes for r in sweep(s, frames[s], args.gt_samples, args.quick)]
    print("part 2: against glossy LDPRT", flush=True)
    if args.quick:
        doc["versus_ldprt"] = [r for s in scenes if s in ("bend", "figure") for r in versus_ldprt(s, frames[s], args.gt_samples,
                                                                                                  (32, 32, 32))]
    else:
        doc["versus_ldprt"] = [r for s in scenes if s in ("bend", "figure")
                               for r in versus_ldprt(s, frames[s] if s != "bend" else [0.0, 30.0], args.gt_samples)]
    print("part 3: cost", flush=True)
    doc["costs"] = [r for s in scenes for r in costs(s, args.quick)]
    doc["kernels"] = kernel_costs(1024, 1, (4,)) if args.quick else kernel_costs()
    doc["builds_s"], doc["storage"], doc["swap"] = swaps_and_builds(scenes[0], 32, 1, True) if args.quick else swaps_and_builds()
    print("part 4: roughness", flush=True)
    doc["roughness"] = roughness_sweep(args.quick)
    doc["seconds"] = time.perf_counter() - t0
    out = Path(args.out or RESULTS)
    out.mkdir(parents=True, exist_ok=True)
    stem = str(out / f"rpo-{doc['date']}-cpu{'-quick' if args.quick else ''}")
    write_json_atomic(f"{stem}.json", doc)
    charts(doc, stem)
    print(f"wrote {stem}.json and -sweep/-roughness/-cost PNGs in {doc['seconds']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
