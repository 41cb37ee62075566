"""Settings of the SG/SSDF method for the speed-vs-accuracy harness."""

from __future__ import annotations

from .._rows import HarnessRow

__all__ = [
    "sg_stages",
]

#: The glossy material of every SG row: Beckmann microfacets (the NDF is one SG lobe).
BRDF = {"brdf": "beckmann", "roughness": 0.3}


def sg_stages(resolution: int = 32, supersample: int = 4, error_budget: float = 0.02, env_lobes: int = 8,
              brdf: dict | None = None, sun: str = "separate") -> tuple:
    """SSDFs baked at the first frame (tangent frames), then SG shading toward the eye; a small,
    very bright sun is taken out of the sky and shaded as a narrow light (``sun = "keep"``: the
    paper's way)."""
    shade = dict(brdf or BRDF)
    return (("ssdf", "sg.ssdf", {"resolution": resolution, "supersample": supersample, "error_budget": error_budget}, {}),
            ("environment", "sg.environment", {"lobes": env_lobes, "sun": sun}, {}),
            ("tangents", "ldprt.tangents", {}, {}),
            ("shade", "sg.shade", shade, {}))


def harness_rows(quick: bool = False) -> list:
    """SG shading (Beckmann 0.3) with SSDF visibility baked at the first frame, against the
    glossy ray-traced reference."""
    note = "SG Beckmann 0.3 toward the scene camera vs the glossy ray-traced reference; SSDF baked at the first frame"
    return [
        HarnessRow("sg", "ssdf 32 x4 e8", sg_stages(32, 4), "shade.radiance", scenes=("skinned", "deforming"), quick=True,
                   notes=note),
    ]
