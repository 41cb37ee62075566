"""Speed of the SH Warp kernels against the float64 NumPy reference, measured side by side.

Cases (issue 2, section 4): basis evaluation of 10^6 directions (orders 4, 6, 8), 10^5 batched
SH products (orders 4, 6) and 10^5 rotations (orders 4, 6). For each case the script reports

* ``numpy_s``: the float64 reference (``warpshade.basis.sh``), NumPy in, NumPy out;
* ``warp_kernel_s``: one launch of the float32 kernel on data already on the device;
* ``warp_chunked_s``: the same work split into chunks launched from a thread pool (Warp's CPU
  backend runs one launch on one thread and releases the GIL, so chunks can use every core);
* ``warp_host_api_s``: the host call with ``device=`` (includes NumPy <-> Warp copies);

all as the median of ``--repeats`` runs after a warm-up launch (compile time excluded), plus the
ratios. ``--compile-times`` additionally measures the first (cold-cache) compile of each kernel
of the per-order bundles in a subprocess with an empty Warp kernel cache.

Usage::

    python benchmarks/bench_sh.py [--quick] [--device cpu] [--workers 2] [--compile-times]

Writes ``benchmarks/results/sh-<date>-<device>.json`` (atomically).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from warpshade._fileio import write_json_atomic
from warpshade._wp import launch_parallel, resolve_device, wp
from warpshade.basis import quadrature, sh
from warpshade.basis.sh_warp import sh_kernels

RESULTS_DIR = Path(__file__).resolve().parent / "results"


def median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def median_times_interleaved(fns, repeats: int) -> list[float]:
    times = [[] for _ in fns]
    for _ in range(repeats):
        for fn, acc in zip(fns, times):
            t0 = time.perf_counter()
            fn()
            acc.append(time.perf_counter() - t0)
    return [statistics.median(t) for t in times]


def random_dirs(count: int, rng) -> np.ndarray:
    d = rng.standard_normal((count, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


class Case:
    """One benchmark case: a reference call, a kernel with resident inputs, and its chunking."""

    def __init__(self, name, order, count, reference, host_api, kernel, inputs_fn, row_args):
        self.name, self.order, self.count = name, order, count
        self.reference, self.host_api = reference, host_api
        self.kernel, self.inputs_fn, self.row_args = kernel, inputs_fn, row_args


def chunked_launcher(kernel, inputs, row_args, count, device, workers):
    """Launch ``kernel`` over ``workers`` contiguous row ranges in parallel
    (:func:`warpshade._wp.launch_parallel`, one chunk per worker).

    ``row_args`` lists the indices of the inputs indexed by the thread id (sliced per chunk);
    the others (tables, constants) are shared.
    """

    def inputs_for(lo, hi):
        return [a[lo:hi] if i in row_args else a for i, a in enumerate(inputs)]

    def run():
        launch_parallel(kernel, count, inputs_for, device, workers=workers, chunks=workers)
        wp.synchronize_device(device)

    return run


def build_cases(sizes, device, rng):
    dev = resolve_device(device)
    cases = []
    for order in sizes["basis_orders"]:
        n = sizes["basis"]
        dirs = random_dirs(n, rng)
        k = sh_kernels(order)

        def inputs(dirs=dirs, k=k):
            return [
                wp.array(dirs.astype(np.float32), dtype=wp.vec3, device=dev),
                wp.empty((dirs.shape[0], k.coeff_count), dtype=wp.float32, device=dev),
            ]

        cases.append(
            Case(
                "basis", order, n,
                lambda dirs=dirs, o=order: sh.basis(dirs, o),
                lambda dirs=dirs, o=order: sh.basis(dirs, o, device=dev),
                k.basis_kernel, inputs, {0, 1},
            )
        )
    for order in sizes["product_orders"]:
        n = sizes["product"]
        f = rng.standard_normal((n, order * order)) / (1 + sh.band_of(order))
        g = rng.standard_normal((n, order * order)) / (1 + sh.band_of(order))
        k = sh_kernels(order)

        def inputs(f=f, g=g, k=k):
            return [
                wp.array(f.astype(np.float32), dtype=wp.float32, device=dev),
                wp.array(g.astype(np.float32), dtype=wp.float32, device=dev),
                k.tables(dev),
                wp.empty(f.shape, dtype=wp.float32, device=dev),
            ]

        cases.append(
            Case(
                "product", order, n,
                lambda f=f, g=g: sh.product(f, g),
                lambda f=f, g=g: sh.product(f, g, device=dev),
                k.product_kernel, inputs, {0, 1, 3},
            )
        )
    for order in sizes["rotate_orders"]:
        n = sizes["rotate"]
        f = rng.standard_normal((n, order * order))
        r = quadrature.random_rotations(n, seed=order)
        k = sh_kernels(order)

        def inputs(f=f, r=r, k=k):
            return [
                wp.array(f.astype(np.float32), dtype=wp.float32, device=dev),
                wp.array(r.astype(np.float32), dtype=wp.mat33, device=dev),
                k.tables(dev),
                wp.empty(f.shape, dtype=wp.float32, device=dev),
            ]

        cases.append(
            Case(
                "rotate", order, n,
                lambda f=f, r=r: sh.rotate(f, r),
                lambda f=f, r=r: sh.rotate(f, r, device=dev),
                k.rotate_kernel, inputs, {0, 1, 3},
            )
        )
    return cases


def run_cases(cases, device, repeats, workers):
    dev = resolve_device(device)
    rows = []
    for c in cases:
        inputs = c.inputs_fn()

        def single(c=c, inputs=inputs):
            wp.launch(c.kernel, dim=c.count, inputs=inputs, device=dev)
            wp.synchronize_device(dev)

        chunked = chunked_launcher(c.kernel, inputs, c.row_args, c.count, dev, workers)
        single()  # warm-up: compile / load the module
        single_out = inputs[-1].numpy().copy()
        inputs[-1].zero_()
        chunked()
        if not np.array_equal(inputs[-1].numpy(), single_out):
            raise RuntimeError(f"{c.name} n={c.order}: chunked launches disagree with one launch")
        ref_out = c.reference()  # warm-up (caches the Gaunt tensor, etc.)
        # Correctness guard: the timed kernel computes what the reference computes.
        err = float(np.abs(c.host_api() - ref_out).max())
        t_ref = median_time(c.reference, max(1, repeats // 2))
        # Single and chunked launches alternate so that background load hits both alike.
        t_kernel, t_chunked = median_times_interleaved([single, chunked], repeats)
        t_host = median_time(c.host_api, max(1, repeats // 2))
        row = {
            "case": c.name,
            "order": c.order,
            "count": c.count,
            "numpy_s": t_ref,
            "warp_kernel_s": t_kernel,
            "warp_chunked_s": t_chunked,
            "warp_host_api_s": t_host,
            "speedup_kernel_vs_numpy": t_ref / t_kernel,
            "speedup_chunked_vs_single_launch": t_kernel / t_chunked,
            "speedup_host_api_vs_numpy": t_ref / t_host,
            "max_abs_diff_vs_float64": err,
        }
        rows.append(row)
        print(
            f"{c.name:8s} n={c.order:2d} count={c.count:8d}  numpy {t_ref * 1e3:9.2f} ms  "
            f"warp {t_kernel * 1e3:8.2f} ms  chunked({workers}) {t_chunked * 1e3:8.2f} ms  "
            f"host-api {t_host * 1e3:8.2f} ms  | numpy/warp {row['speedup_kernel_vs_numpy']:6.1f}x  "
            f"single/chunked {row['speedup_chunked_vs_single_launch']:4.2f}x  max|diff| {err:.1e}",
            flush=True,
        )
    return rows


_COMPILE_KERNELS = ["basis_kernel", "product_kernel", "product_matrix_kernel", "rotate_kernel",
                    "zh_to_sh_kernel", "zh_from_sh_kernel"]


def compile_worker(order: int, device: str) -> None:
    """Child process (empty kernel cache): time the first load of each kernel of one bundle."""
    dev = resolve_device(device)
    out = {}

    @wp.kernel(enable_backward=False, module="unique")
    def warmup(a: wp.array(dtype=wp.float32)):
        a[wp.tid()] = 1.0

    # The first compile in a process also pays the compiler's one-time start-up: time it on a
    # trivial kernel so that the per-kernel numbers below are the kernels' own cost.
    t0 = time.perf_counter()
    warmup.module.load(dev)
    out["compiler_startup_s"] = time.perf_counter() - t0
    k = sh_kernels(order)
    t0 = time.perf_counter()
    k.tables(dev)
    out["tables_build_s"] = time.perf_counter() - t0
    for name in _COMPILE_KERNELS:
        kernel = getattr(k, name)
        t0 = time.perf_counter()
        kernel.module.load(dev)
        out[name] = time.perf_counter() - t0
    print(json.dumps(out))


def measure_compile_times(orders, device):
    results = {}
    for order in orders:
        with tempfile.TemporaryDirectory() as cache:
            env = dict(os.environ, WARP_CACHE_PATH=cache)
            proc = subprocess.run(
                [sys.executable, __file__, "--_compile-worker", str(order), "--device", device],
                env=env, capture_output=True, text=True, check=True,
            )
        times = json.loads(proc.stdout.strip().splitlines()[-1])
        results[str(order)] = times
        total = sum(v for key, v in times.items() if key.endswith("_kernel"))
        print(f"cold compile, order {order}: " + ", ".join(f"{k} {v:.2f}s" for k, v in times.items())
              + f" | kernels total {total:.2f}s", flush=True)
    return results


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="small sizes (smoke run)")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--workers", type=int, default=2, help="thread-pool size for chunked launches")
    parser.add_argument("--repeats", type=int, default=None)
    parser.add_argument("--compile-times", action="store_true", help="also time cold compiles (orders 6, 10)")
    parser.add_argument("--out", type=Path, default=None, help="output directory (default benchmarks/results; required with --quick)")
    parser.add_argument("--_compile-worker", type=int, default=None, dest="compile_worker", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.compile_worker is not None:
        compile_worker(args.compile_worker, args.device)
        return 0
    if args.quick and args.out is None:
        parser.error("--quick writes only into --out DIR (never benchmarks/results)")
    args.out = args.out or RESULTS_DIR

    if args.quick:
        sizes = dict(basis=10_000, product=2_000, rotate=2_000, basis_orders=[4, 6, 8], product_orders=[4, 6],
                     rotate_orders=[4, 6])
        repeats = args.repeats or 1
    else:
        sizes = dict(basis=1_000_000, product=100_000, rotate=100_000, basis_orders=[4, 6, 8],
                     product_orders=[4, 6], rotate_orders=[4, 6])
        repeats = args.repeats or 5
    dev = resolve_device(args.device)
    rng = np.random.default_rng(0)
    print(f"warpshade SH benchmark on {dev} ({platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} cores), {'quick' if args.quick else 'full'} sizes, {args.workers} workers")
    sparsity = {}
    for order in range(1, 9):
        k_nonzero = len(sh.triple_product_tensor(order)[1])
        sparsity[str(order)] = {"nonzeros": k_nonzero, "dense": order**6, "fraction": k_nonzero / order**6}
    print("triple product tensor nonzeros K (vs n^6): "
          + ", ".join(f"n={o}: {v['nonzeros']} ({100 * v['fraction']:.2f}%)" for o, v in sparsity.items()))

    rows = run_cases(build_cases(sizes, dev, rng), dev, repeats, args.workers)
    compile_times = measure_compile_times([6, 10], args.device) if args.compile_times else None
    chunk_pays = {f"{r['case']}-{r['order']}": r["speedup_chunked_vs_single_launch"] > 1.1 for r in rows}
    print("chunked thread-pool launches pay (>1.1x) for: "
          + ", ".join(k for k, v in chunk_pays.items() if v) + " | not for: "
          + ", ".join(k for k, v in chunk_pays.items() if not v))
    date = _dt.date.today().isoformat()
    device_name = str(dev.alias).replace(":", "")
    result = {
        "date": date,
        "device": str(dev.alias),
        "machine": {"platform": platform.platform(), "processor": platform.processor(), "cpu_count": os.cpu_count(),
                    "python": platform.python_version(), "numpy": np.__version__, "warp": wp.config.version},
        "quick": args.quick,
        "workers": args.workers,
        "repeats": repeats,
        "command": " ".join([os.path.relpath(__file__)] + (argv if argv is not None else sys.argv[1:])),
        "triple_product_sparsity": sparsity,
        "cases": rows,
        "chunked_launch_pays": chunk_pays,
        "cold_compile_s": compile_times,
    }
    suffix = "-quick" if args.quick else ""
    path = args.out / f"sh-{date}-{device_name}{suffix}.json"
    write_json_atomic(path, result)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
