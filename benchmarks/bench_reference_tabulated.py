"""Time of the glossy reference with a tabulated (MERL-layout) BRDF against the analytic model it
was tabulated from, in one run; optionally the analytic path of another checkout interleaved with
this one's (``--base``: did the tabulated model slow the analytic path down?).

Usage::

    python benchmarks/bench_reference_tabulated.py                  # CPU, a floor + ball scene
    python benchmarks/bench_reference_tabulated.py --base /path/to/older/checkout --rounds 5
    python benchmarks/bench_reference_tabulated.py --quick --out /tmp/x

Writes ``benchmarks/results/reference-tabulated-<date>-<device>.json`` and a bar chart ``.png``
next to it. Cases (each :class:`~warpshade.reference.GlossyReferenceShader` built once, then
``shade`` timed ``--repeats`` times after a warm-up, the minimum reported; on the CPU the
process's CPU time of one launch thread, which other processes on a shared machine disturb far
less than the wall clock; on a GPU the wall clock):

* ``analytic``: GGX (alpha 0.3, f0 0.1);
* ``table_one_channel``: that GGX tabulated (90 x 90 x 180, linear lookup; 24 x 12 x 24 with
  ``--quick``), channel "g";
* ``table_rgb``: the same table in colour (three passes, one per channel).

With ``--base DIR`` the ``analytic`` case also runs in subprocesses with ``DIR`` (a checkout's
root, holding ``warpshade/``) first on the import path, alternating with this checkout for
``--rounds`` rounds: ``analytic_base_s`` and ``analytic_this_s`` are the minima over the rounds.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from warpshade._fileio import write_json_atomic  # noqa: E402
from warpshade._wp import resolve_device, wp  # noqa: E402


def scene_and_lights():
    import trimesh

    from warpshade.scene import Environment, Mesh, Scene

    coords = np.linspace(-1.5, 1.5, 9)
    gx, gy = np.meshgrid(coords, coords, indexing="ij")
    points = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], 1)
    idx = np.arange(gx.size).reshape(gx.shape)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    ball = trimesh.creation.icosphere(2, radius=0.4)
    return Scene.from_meshes([Mesh("floor", points, faces),
                              Mesh("ball", np.asarray(ball.vertices) + [0.2, 0.1, 0.7], np.asarray(ball.faces))],
                             lights=[Environment.sky(height=32, width=64)])


EYE = (0.3, -2.0, 1.5)


def time_case(brdf, samples, repeats, device):
    from warpshade.reference import GlossyReferenceShader

    scene = scene_and_lights()
    shader = GlossyReferenceShader(scene, brdf, EYE, samples=samples, device=device, workers=1)
    shader.shade(0.0)  # warm-up: compilation
    times, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        shader.shade(0.0)
        wp.synchronize_device(shader.device)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return (min(cpu) if shader.device.is_cpu else min(times)), scene.vertex_count


def analytic():
    from warpshade.scene import _materials as materials

    return materials.Microfacet(roughness=0.3, distribution="ggx", f0=0.1)


def child(args) -> None:
    """``--child``: time the analytic case only and print its seconds as JSON (for ``--base``)."""
    seconds, _ = time_case(analytic(), args.samples, args.repeats, resolve_device(args.device))
    print(json.dumps({"seconds": seconds}))


def run_child(tree: Path, args) -> float:
    env = {**os.environ, "PYTHONPATH": str(tree)}  # the child imports that checkout's warpshade
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", "--samples", str(args.samples), "--repeats",
           str(args.repeats), "--device", args.device]
    out = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True, cwd=str(tree))
    return float(json.loads(out.stdout.strip().splitlines()[-1])["seconds"])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--samples", type=int, default=1024)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--base", default=None, help="another checkout's root: its analytic path, interleaved")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="few samples and repeats (a smoke run)")
    parser.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        return child(args)
    if args.quick:
        if args.out is None:
            parser.error("--quick writes only into --out DIR (never benchmarks/results)")
        args.samples, args.repeats, args.rounds = 64, 1, 1
    dims = (24, 12, 24) if args.quick else (90, 90, 180)
    out_dir = Path(args.out or ROOT / "benchmarks" / "results")
    device = resolve_device(args.device)

    from warpshade.scene._tabulated import TabulatedBRDF

    ggx = analytic()
    one = TabulatedBRDF.from_brdf(ggx, dims=dims, channel="g", interpolation="linear")
    rgb = TabulatedBRDF(one.table, "rgb", "linear")
    results = {}
    for name, brdf in (("analytic", ggx), ("table_one_channel", one), ("table_rgb", rgb)):
        seconds, receivers = time_case(brdf, args.samples, args.repeats, device)
        results[name] = {"seconds": seconds, "receivers": int(receivers), "samples": args.samples}
    ratios = {"table_one_channel_over_analytic": results["table_one_channel"]["seconds"] / results["analytic"]["seconds"],
              "table_rgb_over_analytic": results["table_rgb"]["seconds"] / results["analytic"]["seconds"]}
    if args.base is not None:
        base, this = [], []
        for _ in range(args.rounds):
            base.append(run_child(Path(args.base).resolve(), args))
            this.append(run_child(ROOT, args))
        results["analytic_base_s"], results["analytic_this_s"] = min(base), min(this)
        results["analytic_rounds"] = {"base": base, "this": this}
        ratios["analytic_this_over_base"] = min(this) / min(base)
    date = datetime.date.today().isoformat()
    report = {"benchmark": "reference_tabulated", "date": date, "device": str(device), "load_average": os.getloadavg(),
              "table_dims": list(dims), "timer": "process CPU time" if device.is_cpu else "wall clock",
              "results": results, "ratios": ratios}
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = f"reference-tabulated-{date}-{str(device).replace(':', '')}{'-quick' if args.quick else ''}"
    write_json_atomic(out_dir / f"{stem}.json", report)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = ["analytic", "table_one_channel", "table_rgb"]
    fig, ax = plt.subplots(figsize=(5, 3))
    ax.bar(names, [results[n]["seconds"] for n in names])
    ax.set_ylabel("seconds per shade")
    ax.set_title(f"glossy reference, {results['analytic']['receivers']} receivers, {args.samples} spp ({device})")
    fig.tight_layout()
    fig.savefig(out_dir / f"{stem}.png", dpi=100)
    plt.close(fig)
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
