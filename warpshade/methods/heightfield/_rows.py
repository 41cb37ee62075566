"""Settings of the height field for the speed-vs-accuracy harness (``benchmarks/run.py``).

They apply to height-field scenes only (a regular grid whose vertices move along z): the bundled
water, ``--scenes bundled:ripples``.
"""

from __future__ import annotations

from .._rows import HarnessRow

__all__ = [
    "HEIGHT_FIELD_SCENES",
    "heightfield_stages",
]

#: The scene keys the rows apply to.
HEIGHT_FIELD_SCENES = ("bundled:ripples",)
#: The glossy material of every row: that of ``stages/ripples_height_rpo.toml``.
BRDF = {"brdf": "ggx", "roughness": 0.3, "specular": [0.9, 0.9, 0.9]}


def heightfield_stages(order: int = 4, rank: int = 8, resolution: int = 128, azimuths: int = 16,
                       factors: str = "rpo") -> tuple:
    """The stages of one setting: ``heightfield.visibility`` at ``resolution``^2 texels and
    ``azimuths`` wedges, then ``heightfield.shade`` with ``rank`` factors (or the BRDF's own
    projection, ``factors = "exact"``) at SH order ``order``."""
    vis = {"order": order, "resolution": resolution, "azimuths": azimuths, "samples_per_octave": 1,
           "per_vertex": False}
    shade = {"order": order, "rank": rank, "factors": factors, **BRDF}
    return (("vis", "heightfield.visibility", vis, {}),
            ("shade", "heightfield.shade", shade, {}))


def harness_rows(quick: bool = False) -> list:
    """The ready-made graph's setting (n = 4, k = 8, 128^2 texels, 16 azimuths) and its coarser
    and finer neighbours; measured against the glossy ray-traced reference."""
    note = "height-field visibility + RPO GGX 0.3 toward the scene camera vs the glossy ray-traced reference"
    rows = []
    for order, rank, resolution, azimuths in ((4, 8, 128, 16), (3, 8, 64, 8), (4, 16, 256, 32)):
        rows.append(HarnessRow("heightfield", f"n{order} k{rank} {resolution}^2 a{azimuths}",
                               heightfield_stages(order, rank, resolution, azimuths), "shade.radiance",
                               scenes=HEIGHT_FIELD_SCENES, quick=(order, rank, resolution) == (4, 8, 128), notes=note))
    return rows
