"""Settings of the reflectance product operators for the speed-vs-accuracy harness."""

from __future__ import annotations

from .._rows import HarnessRow

__all__ = [
    "rpo_stages",
]

#: The glossy material of every RPO row: the BRDF, eye and colour of the glossy LDPRT rows.
BRDF = {"brdf": "ggx", "roughness": 0.5}


def rpo_stages(visibility: str = "traced", order: int = 4, rank: int = 8, lighting: str = "rotate",
               samples: int = 256, evaluation: str = "gaunt") -> tuple:
    """The stages of one RPO setting over one visibility generator ("traced", "static", "shexp")."""
    shade = {"order": order, "rank": rank, "lighting": lighting, "evaluation": evaluation, **BRDF}
    if visibility == "traced":
        return (("vis", "rpo.visibility_traced", {"order": order, "samples": samples}, {}),
                ("shade", "rpo.shade", shade, {}))
    if visibility == "static":
        return (("vis", "rpo.visibility_static", {"order": order, "samples": samples}, {}),
                ("tangents", "ldprt.tangents", {}, {}),
                ("shade", "rpo.shade", shade, {}))
    if visibility == "shexp":
        return (("tables", "shexp.tables", {"order": order}, {}),
                ("blockers", "shexp.blockers", {"budget": 48, "hierarchy": True}, {}),
                ("vis", "shexp.visibility", {"order": order, "method": "hyb"}, {}),
                ("tangents", "ldprt.tangents", {}, {}),
                ("shade", "rpo.shade", {**shade, "visibility_space": "world"}, {}))
    raise ValueError(f"rpo rows: unknown visibility generator {visibility!r}")


def harness_rows(quick: bool = False) -> list:
    """RPO (GGX roughness 0.5, k = 8, n = 4) over traced, static and SHEXP visibility, and the
    ZH-lighting variant; measured against the glossy ray-traced reference."""
    note = "RPO k8 GGX 0.5 toward the scene camera vs the glossy ray-traced reference"
    scenes = ("skinned", "deforming")
    return [
        HarnessRow("rpo", "traced n4 k8 s256", rpo_stages("traced"), "shade.radiance", scenes=scenes, quick=True,
                   notes=note + "; visibility ray traced every frame"),
        HarnessRow("rpo", "traced n4 k8 s256 zh3", rpo_stages("traced", lighting="zh"), "shade.radiance", scenes=scenes,
                   quick=False, notes=note + "; 3-lobe ZH lighting"),
        HarnessRow("rpo", "static n4 k8", rpo_stages("static", samples=1024), "shade.radiance", scenes=scenes, quick=True,
                   notes=note + "; visibility baked at the first frame (tangent frame)"),
        HarnessRow("rpo", "shexp n4 k8", rpo_stages("shexp"), "shade.radiance", scenes=("figure",), quick=False,
                   notes=note + "; SHEXP HYB visibility from 48 blocker spheres"),
    ]
