"""Model no more than the scene needs: choose a method's setting from an error budget.

Each method package that has one provides ``budget.candidates(**grid)`` -- the settings worth
trying (stage tuples, the facts that describe them, the stage whose time counts) -- and
``budget.GRID`` (the default grid). :func:`choose` measures every candidate on the scene at
hand -- error against ray-traced ground truth on a few sampled frames (cached), and the median
time per frame of the candidate's timed stage -- and returns the cheapest one whose error meets
the target, or, when none does, the most accurate, flagged as not meeting it. The report says
what was chosen and why (every candidate's error and time).

Command line::

    warpshade budget --method shexp --scene figure --target 0.2
    warpshade budget --method prt --scene bunny --target 0.08 --grid orders=3,4,6 samples=256
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time
from dataclasses import asdict, dataclass, field

import numpy as np

__all__ = [
    "main",
]


@dataclass
class Candidate:
    """One measured setting.

    Attributes:
        label: short name ("n4 16 spheres hyb").
        facts: what the setting is (order, sphere budget, method, ...), plus what its
            precompute reports added (e.g. the sphere count really fitted).
        rel_rms: relative RMS error against ground truth, combined over the frames.
        stage_ms: median time per frame of the timed stage; frame_ms: of the whole frame.
        meets_target: ``rel_rms <= target``.
        diagnostics: what the stages reported after the last frame (e.g. SHEXP fallbacks).
    """

    label: str
    facts: dict = field(default_factory=dict)
    rel_rms: float = float("nan")
    stage_ms: float = float("nan")
    frame_ms: float = float("nan")
    meets_target: bool = False
    diagnostics: dict = field(default_factory=dict)


@dataclass
class BudgetChoice:
    """The outcome of :func:`choose`: the chosen candidate, whether it meets the target, and
    every candidate measured (so the choice can be re-read for other targets with :func:`pick`)."""

    scene: str
    method: str
    target: float
    chosen: Candidate
    met: bool
    candidates: list = field(default_factory=list)
    frames: list = field(default_factory=list)
    gt_samples: int = 0
    seconds: float = 0.0

    def to_dict(self) -> dict:
        return asdict(self)

    def summary(self) -> str:
        c = self.chosen
        state = "meets it" if self.met else "does NOT meet it (the most accurate is shown)"
        facts = ", ".join(f"{k} {v}" for k, v in c.facts.items())
        return (f"{self.scene}: {self.method} for a target rel RMS {self.target:.3f} -> {c.label} ({facts}): error "
                f"{c.rel_rms:.4f}, {c.stage_ms:.2f} ms/frame; {state} ({len(self.candidates)} candidates, {self.seconds:.0f} s)")


def method_candidates(method: str, **grid) -> list[dict]:
    """``warpshade.methods.<method>.budget.candidates(**grid)``, with the method's default grid.

    Raises:
        ValueError: a method without a budget module, or an unknown grid key.
    """
    try:
        mod = importlib.import_module(f"warpshade.methods.{method}._budget")
    except ModuleNotFoundError:
        raise ValueError(f"budget: method {method!r} has no error budget (warpshade/methods/{method}/_budget.py)") from None
    unknown = set(grid) - set(mod.GRID)
    if unknown:
        raise ValueError(f"budget: method {method!r} has no grid key(s) {sorted(unknown)} (keys: {sorted(mod.GRID)})")
    return mod.candidates(**grid)


def pick(candidates, target_error: float) -> tuple[Candidate, bool]:
    """The cheapest candidate with error <= target, or the most accurate one (and False)."""
    for c in candidates:
        c.meets_target = bool(c.rel_rms <= target_error)
    meeting = [c for c in candidates if c.meets_target]
    if meeting:
        return min(meeting, key=lambda c: c.stage_ms), True
    return min(candidates, key=lambda c: c.rel_rms), False


def choose(scene, candidates, target_error: float, *, lighting=None, method: str = "", frames=None, frame_count: int = 2,
           gt_samples: int = 1024, device="cpu", cache_dir="default", progress: bool = False) -> BudgetChoice:
    """The cheapest candidate meeting ``target_error`` on ``scene``.

    Args:
        scene: a :class:`~warpshade.scene.Scene`.
        candidates: ``{"label", "stages", "facts", "timed_stage"}`` dicts (a method's
            ``budget.candidates``, or :func:`method_candidates`); ``timed_stage`` None charges
            the whole frame. A candidate whose output stage names a glossy reference is measured
            against it.
        target_error: relative RMS error against ray-traced ground truth to meet (> 0).
        lighting: a :class:`~warpshade.scene.LightingSource` (default: the scene's lights, fixed).
        frames: frames to measure on (default: ``frame_count`` spread inside the scene's range).
        gt_samples: ground-truth rays per vertex (cached on disk).
        device, cache_dir: Warp device and artifact cache (each sphere set, transfer, ... is
            computed once and shared by the candidates that use it).
    """
    from ..scene import LightingSource
    from ._harness import run_setting, setting_error
    from ._scenes import error_frames
    from ._truth import ground_truth, reference_model

    if isinstance(target_error, bool) or not isinstance(target_error, (int, float)) or not target_error > 0:
        raise ValueError(f"budget: target_error must be a number > 0, got {target_error!r}")
    candidates = list(candidates)
    if not candidates:
        raise ValueError("budget: no candidates")
    lighting = lighting or LightingSource.fixed(scene.lights, scene.up_axis)
    t0 = time.perf_counter()
    frames = error_frames(scene, frame_count) if frames is None else np.asarray(frames, np.float64).reshape(-1)
    truth = ground_truth(scene, lighting, frames, gt_samples, device, cache_dir)
    measured = []
    for cand in candidates:
        timed = cand.get("timed_stage", "shade")
        res = run_setting(scene, lighting, cand["stages"], frames, timing_frames=list(frames) * 2, device=device,
                          cache_dir=cache_dir, name=f"budget-{cand['label']}".replace(" ", "-"))
        model = reference_model(res["runtime"])  # a glossy method is measured against the glossy reference
        err = setting_error(res["radiance"], truth if model is None else
                            ground_truth(scene, lighting, frames, gt_samples, device, cache_dir, model=model))
        facts = dict(cand.get("facts", {}))
        for report in res["reports"].values():
            if "leaf_spheres" in report:
                facts["leaf_spheres"] = int(report["leaf_spheres"])
        stage_ms = float(res["frame_ms"]) if timed is None else float(res["stage_ms"].get(timed, np.nan))
        c = Candidate(cand["label"], facts, float(err["rel_rms"]), stage_ms,
                      float(res["frame_ms"]), bool(err["rel_rms"] <= target_error), res["diagnostics"])
        measured.append(c)
        if progress:
            print(f"    {c.label:32s} rel RMS {c.rel_rms:.4f}  {c.stage_ms:7.2f} ms  {'ok' if c.meets_target else ''}", flush=True)
    chosen, met = pick(measured, target_error)
    return BudgetChoice(str(scene.source), method, float(target_error), chosen, met, measured, [float(f) for f in frames],
                        int(gt_samples), time.perf_counter() - t0)


def _grid_value(text: str):
    items = [x.strip() for x in text.split(",") if x.strip()]
    out = []
    for x in items:
        try:
            out.append(int(x))
        except ValueError:
            try:
                out.append(float(x))
            except ValueError:
                out.append(x)
    return tuple(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="warpshade budget", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--method", required=True, help="method package with a budget module (prt, shexp, ldprt, rpo, ...)")
    ap.add_argument("--scene", required=True, help="bundled key (bunny, bear, blockers, figure, cloth, bend) or a scene spec")
    ap.add_argument("--target", type=float, required=True, help="relative RMS error target")
    ap.add_argument("--grid", nargs="*", default=[], metavar="KEY=A,B", help="override grid axes, e.g. orders=3,4 spheres=8,16")
    ap.add_argument("--gt-samples", type=int, default=1024)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--json", default=None, help="write the full result here")
    args = ap.parse_args(argv)
    from ._scenes import load_bench_scene

    grid = {}
    for item in args.grid:
        if "=" not in item:
            ap.error(f"--grid: expected KEY=A,B, got {item!r}")
        k, v = item.split("=", 1)
        grid[k.strip()] = _grid_value(v)
    try:
        cands = method_candidates(args.method, **grid)
        scene, _ = load_bench_scene(args.scene)
    except ValueError as exc:
        ap.error(str(exc))
    from ..scene import LightingSource

    choice = choose(scene, cands, args.target, lighting=LightingSource.fixed(scene.lights, scene.up_axis), method=args.method,
                    gt_samples=args.gt_samples, device=args.device, progress=True)
    print(choice.summary())
    if args.json:
        from .._fileio import write_json_atomic

        write_json_atomic(args.json, choice.to_dict(), indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
