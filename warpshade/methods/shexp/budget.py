"""Model no more than the scene needs: choose SHEXP's order, sphere count and exp method.

:func:`choose_setting` measures every candidate setting (SH order x leaf-sphere budget x exp
method) on the scene at hand -- error against ray-traced ground truth on a few sampled frames,
and the median time per frame of the SHEXP shading stage -- and returns the cheapest one whose
error meets the target (or, when none does, the most accurate, flagged as not meeting it).

Command line (also reachable as ``python benchmarks/bench_shexp.py --parts budget``)::

    python -m warpshade.methods.shexp.budget --scene figure --target 0.2
    python -m warpshade.methods.shexp.budget --scene usd_assets/blockers.usda --target 0.14 --json out.json

``--scene`` takes a bundled key (blockers, figure, bunny, bear) or any scene spec accepted by
:func:`warpshade.io.load_scene`. The error is the relative RMS of per-vertex radiance over
vertices and channels, combined over the sampled frames (the harness's metric).
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time
from dataclasses import asdict, dataclass, field

import numpy as np

__all__ = ["Candidate", "BudgetChoice", "choose_setting", "pick", "budget_report", "DEFAULT_ORDERS", "DEFAULT_SPHERE_BUDGETS",
           "DEFAULT_METHODS", "main"]

DEFAULT_ORDERS = (3, 4, 5, 6)
DEFAULT_SPHERE_BUDGETS = (8, 16, 32, 64)
DEFAULT_METHODS = ("ol", "hyb", "ps_star")


@dataclass
class Candidate:
    """One measured setting."""

    order: int
    spheres: int
    method: str
    rel_rms: float = float("nan")
    stage_ms: float = float("nan")
    leaf_spheres: int = 0
    fallbacks: int = 0
    meets_target: bool = False

    @property
    def label(self) -> str:
        return f"n{self.order} {self.spheres} spheres {self.method}"


@dataclass
class BudgetChoice:
    """The outcome of :func:`choose_setting`.

    Attributes:
        scene: the scene's source.
        target: the error target (relative RMS).
        chosen: the cheapest candidate meeting it (or the most accurate when none does).
        met: whether ``chosen`` meets the target.
        candidates: every measured candidate.
        frames: the frames the error was measured on; gt_samples: ground-truth rays per vertex.
        seconds: wall time of the search.
    """

    scene: str
    target: float
    chosen: Candidate
    met: bool
    candidates: list = field(default_factory=list)
    frames: list = field(default_factory=list)
    gt_samples: int = 0
    seconds: float = 0.0

    def to_dict(self) -> dict:
        d = asdict(self)
        d["chosen"]["label"] = self.chosen.label
        return d

    def summary(self) -> str:
        c = self.chosen
        state = "meets" if self.met else "does NOT meet (most accurate shown)"
        return (f"{self.scene}: target rel RMS {self.target:.3f} -> order {c.order}, {c.leaf_spheres} leaf spheres "
                f"(budget {c.spheres}), {c.method}: error {c.rel_rms:.4f}, {c.stage_ms:.2f} ms/frame; {state} "
                f"({len(self.candidates)} candidates, {self.seconds:.0f} s)")


def choose_setting(
    scene,
    target_error: float,
    *,
    lighting=None,
    orders=DEFAULT_ORDERS,
    sphere_budgets=DEFAULT_SPHERE_BUDGETS,
    methods=DEFAULT_METHODS,
    frames=None,
    frame_count: int = 2,
    gt_samples: int = 1024,
    hierarchy: bool = False,
    blocker_params=None,
    device="cpu",
    cache_dir="default",
    progress: bool = False,
) -> BudgetChoice:
    """Cheapest (order, sphere budget, exp method) meeting ``target_error`` on a scene.

    Args:
        scene: a :class:`~warpshade.scene.Scene`.
        target_error: relative RMS error against ray-traced ground truth to meet (> 0).
        lighting: a :class:`~warpshade.graph.LightingSource` (default: the scene's lights, fixed).
        orders, sphere_budgets, methods: the candidate grid.
        frames: frames to measure on (default: ``frame_count`` spread over the scene).
        gt_samples: ground-truth rays per vertex (cached on disk).
        hierarchy: candidates use the sphere hierarchy and receiver clusters.
        blocker_params: extra ``shexp.blockers`` parameters (e.g. a cheaper fit).
        device: Warp device; cache_dir: artifact cache (sphere sets are fit once per budget).

    Returns:
        :class:`BudgetChoice`. Time is the median per-frame launch time of the shading stage
        (what the setting changes), measured after a warm-up frame.
    """
    from . import graph_stages
    from .evaluation import combined_error, error_frames, ground_truth, run_setting

    if not (isinstance(target_error, (int, float)) and target_error > 0):
        raise ValueError(f"choose_setting: target_error must be > 0, got {target_error!r}")
    for m in methods:
        if m not in ("ps", "ps_star", "ol", "hyb"):
            raise ValueError(f"choose_setting: unknown exp method {m!r}")
    if lighting is None:
        from ...graph import LightingSource

        lighting = LightingSource(scene.lights, scene.up_axis, 0.0, float(scene.frames[0]))
    t0 = time.perf_counter()
    frames = error_frames(scene, frame_count) if frames is None else np.asarray(frames, np.float64).reshape(-1)
    gt = ground_truth(scene, lighting, frames, gt_samples, device, cache_dir)
    timing_frames = list(frames) * 2
    candidates = []
    for spheres, order, method in itertools.product(sphere_budgets, orders, methods):
        stages = graph_stages(order, method, spheres, hierarchy=hierarchy, blocker_params=blocker_params)
        res = run_setting(scene, lighting, stages, frames, timing_frames=timing_frames, device=device, cache_dir=cache_dir)
        err = combined_error(res["radiance"], gt)
        shade = next(s for s in res["runtime"].stages if s.name == "shade")
        c = Candidate(order, spheres, method, err["rel_rms"], res["stage_ms"], shade.model.leaf_count, res["fallbacks"],
                      err["rel_rms"] <= target_error)
        candidates.append(c)
        if progress:
            print(f"    {c.label:28s} rel RMS {c.rel_rms:.4f}  {c.stage_ms:7.2f} ms  {'ok' if c.meets_target else ''}", flush=True)
    chosen, met = pick(candidates, target_error)
    return BudgetChoice(str(scene.source), float(target_error), chosen, met, candidates, [float(f) for f in frames],
                        int(gt_samples), time.perf_counter() - t0)


def pick(candidates, target_error: float) -> tuple[Candidate, bool]:
    """The cheapest candidate with error <= target, or the most accurate one (and False)."""
    meeting = [c for c in candidates if c.rel_rms <= target_error]
    for c in candidates:
        c.meets_target = c.rel_rms <= target_error
    if meeting:
        return min(meeting, key=lambda c: c.stage_ms), True
    return min(candidates, key=lambda c: c.rel_rms), False


#: The demonstration of ``bench_shexp.py --parts budget``: targets and two scenes. The
#: candidates are measured once per scene; the choice for each target is read off them.
REPORT_TARGETS = (0.1, 0.15, 0.2, 0.25)
REPORT_SCENES = ("blockers", "figure")


def budget_report(quick: bool = False, targets=REPORT_TARGETS, scenes=REPORT_SCENES) -> dict:
    """Run :func:`choose_setting` on two bundled scenes and read the choice per target."""
    from .evaluation import load_bench_scene

    out = {"targets": list(targets), "scenes": {}}
    for key in scenes:
        scene, lighting = load_bench_scene(key)
        choice = choose_setting(scene, min(targets), lighting=lighting, orders=(3, 4, 6) if quick else DEFAULT_ORDERS,
                                sphere_budgets=(8, 32) if quick else DEFAULT_SPHERE_BUDGETS,
                                methods=("ol", "hyb") if quick else DEFAULT_METHODS, gt_samples=512 if quick else 1024,
                                progress=True)
        per_target = {}
        for t in targets:
            c, met = pick(choice.candidates, t)
            per_target[str(t)] = {"order": c.order, "spheres": c.spheres, "leaf_spheres": c.leaf_spheres, "method": c.method,
                                  "rel_rms": c.rel_rms, "stage_ms": c.stage_ms, "met": met}
            print(f"  {key}: target {t:.3f} -> n{c.order}, {c.leaf_spheres} leaf spheres (budget {c.spheres}), {c.method}: "
                  f"error {c.rel_rms:.4f}, {c.stage_ms:.2f} ms/frame{'' if met else ' (NOT met: most accurate)'}", flush=True)
        pick(choice.candidates, min(targets))
        out["scenes"][key] = {"per_target": per_target, "search": choice.to_dict()}
    out["choices_differ"] = {str(t): len({(out["scenes"][k]["per_target"][str(t)]["order"], out["scenes"][k]["per_target"][str(t)]["spheres"],
                                           out["scenes"][k]["per_target"][str(t)]["method"]) for k in scenes}) > 1 for t in targets}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", required=True, help="bundled key (blockers, figure, bunny, bear) or a scene spec")
    ap.add_argument("--target", type=float, required=True, help="relative RMS error target")
    ap.add_argument("--orders", default=",".join(map(str, DEFAULT_ORDERS)))
    ap.add_argument("--spheres", default=",".join(map(str, DEFAULT_SPHERE_BUDGETS)), help="leaf-sphere budgets")
    ap.add_argument("--methods", default=",".join(DEFAULT_METHODS))
    ap.add_argument("--gt-samples", type=int, default=1024)
    ap.add_argument("--hierarchy", action="store_true")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--json", default=None, help="write the full result here")
    args = ap.parse_args(argv)
    from .evaluation import SCENES, load_bench_scene

    if args.scene in SCENES:
        scene, lighting = load_bench_scene(args.scene)
    else:
        from ...graph import LightingSource
        from ...io import load_scene

        scene = load_scene(args.scene)
        lighting = LightingSource(scene.lights, scene.up_axis, 0.0, float(scene.frames[0]))
    choice = choose_setting(scene, args.target, lighting=lighting, orders=[int(x) for x in args.orders.split(",")],
                            sphere_budgets=[int(x) for x in args.spheres.split(",")], methods=args.methods.split(","),
                            gt_samples=args.gt_samples, hierarchy=args.hierarchy, device=args.device, progress=True)
    print(choice.summary())
    if args.json:
        from ..._fileio import write_json_atomic

        write_json_atomic(args.json, choice.to_dict(), indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
