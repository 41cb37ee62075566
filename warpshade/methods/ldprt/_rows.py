"""Settings of LDPRT for the speed-vs-accuracy harness (``benchmarks/run.py``)."""

from __future__ import annotations

from .._rows import HarnessRow

__all__ = [
    "HARNESS_ORDER",
]

#: SH order of the harness rows (the paper uses n = 6 for diffuse LDPRT).
HARNESS_ORDER = 4


def _ldprt_stages(lobes: int, target_error=None, evaluation: str = "table", order: int = HARNESS_ORDER) -> tuple:
    fit = {"order": order, "lobes": lobes, "samples": 256}
    if target_error is not None:
        fit["target_error"] = target_error
    return (
        ("fit", "ldprt.fit", fit, {}),
        ("tangents", "ldprt.tangents", {}, {}),
        ("shade", "ldprt.shade", {"order": order, "lobes": lobes, "evaluation": evaluation}, {}),
    )


def harness_rows(quick: bool = False) -> list:
    """N = 1..4 lobes (table), an error-budgeted lobe count, direct SH evaluation, the full-SH-
    rotation baseline and glossy LDPRT; on the deforming (skinned and point-cached) scenes."""
    scenes = ("skinned", "deforming")
    note = "transfer baked at the first frame in tangent frames, rotated per vertex per frame"
    rows = [
        HarnessRow("ldprt", f"N{n} n{HARNESS_ORDER}", _ldprt_stages(n), "shade.radiance", scenes=scenes,
                   quick=(n in (1, 3)), notes=note)
        for n in (1, 2, 3, 4)
    ]
    rows.append(HarnessRow("ldprt", f"budget 0.05 n{HARNESS_ORDER}", _ldprt_stages(4, target_error=0.05),
                           "shade.radiance", scenes=scenes, quick=False,
                           notes=note + "; lobe count per vertex from a 5% error budget"))
    rows.append(HarnessRow("ldprt", f"N3 direct n{HARNESS_ORDER}", _ldprt_stages(3, evaluation="direct"),
                           "shade.radiance", scenes=scenes, quick=False, notes=note + "; direct SH evaluation"))
    # n_b = 3 loses a lot at grazing views (cloth, frame 0: 0.36 / 0.19 / 0.09 for n_b = 3 / 6 / 16);
    # over rotating sunny frames the order-4 sky truncation dominates and 6 vs 16 rows tie
    for order, rank, lobes, quick_row in ((4, 6, 3, True), (4, 16, 3, False), (6, 12, 4, False)):
        rows.append(HarnessRow(
            "ldprt-glossy", f"n{order} b{rank} N{lobes}",
            (("fit", "ldprt.glossy_fit", {"order": order, "lobes": lobes, "rank": rank, "samples": 256,
                                          "brdf": "microfacet", "roughness": 0.5}, {}),
             ("tangents", "ldprt.tangents", {}, {}),
             ("shade", "ldprt.glossy_shade", {"order": order, "lobes": lobes, "rank": rank}, {})),
            "shade.radiance", scenes=scenes, quick=quick_row,
            notes="glossy LDPRT (GGX roughness 0.5) towards the scene camera, vs the glossy ray-traced reference",
        ))
    rows.append(HarnessRow(
        "ldprt", f"rotated SH n{HARNESS_ORDER}",
        (("bake", "ldprt.transfer", {"order": HARNESS_ORDER, "samples": 256}, {}),
         ("tangents", "ldprt.tangents", {}, {}),
         ("shade", "ldprt.shade_rotated", {"order": HARNESS_ORDER}, {})),
        "shade.radiance", scenes=scenes, quick=False, notes="full local SH transfer rotated per vertex (zxzxz)",
    ))
    return rows
