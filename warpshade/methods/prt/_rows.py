"""Settings of static PRT for the speed-vs-accuracy harness (``benchmarks/run.py``)."""

from __future__ import annotations

from .._rows import HarnessRow

__all__: list[str] = []


def harness_rows(quick: bool = False) -> list:
    """Static PRT over SH order and ray count, per-frame ray-traced transfer, unshadowed irradiance."""
    rows = []
    for order in (2, 3, 4, 6):
        for samples in (64, 256, 1024):
            rows.append(HarnessRow(
                "prt", f"n{order} s{samples}",
                (("bake", "prt.transfer", {"order": order, "samples": samples}, {}),
                 ("shade", "prt.shade", {"order": order}, {"transfer": "bake.transfer"})),
                "shade.radiance", scenes=("all",), quick=(samples == 256 and order in (3, 4)),
                notes="transfer baked at the first frame (exact only for static scenes)",
            ))
    for order, samples in ((4, 256), (4, 1024), (6, 1024)):
        rows.append(HarnessRow(
            "traced", f"n{order} s{samples}",
            (("shade", "prt.trace", {"order": order, "samples": samples}, {}),),
            "shade.radiance", scenes=("all",), quick=(order, samples) == (4, 256),
            notes="transfer ray traced at every frame (the brute-force baseline to beat)",
        ))
    for order in (2, 3, 4):
        rows.append(HarnessRow(
            "unshadowed", f"n{order}",
            (("shade", "prt.unshadowed", {"order": order}, {}),),
            "shade.radiance", scenes=("all",), quick=(order == 3),
            notes="normal-indexed irradiance, no visibility",
        ))
    return rows
