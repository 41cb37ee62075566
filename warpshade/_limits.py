"""Sizes warpshade refuses before allocating, with a message naming what asked for them.

A request that would not fit (a hundred billion rays per vertex, a stage whose time range spans
a billion time codes) is refused up front with the parameter and the limit in the message,
instead of ending in a MemoryError, a swap storm or an hour of silence. The limits are far above
what the methods need; change them here, with a reason.
"""

from __future__ import annotations

__all__ = ["MAX_RAYS_PER_VERTEX", "MAX_TIME_CODES", "MAX_TABLE_BYTES", "MAX_FIT_RESTARTS", "MAX_VIEW_RESOLUTION",
           "MAX_LOOKUP_TABLE_WIDTH", "MAX_IMAGE_PIXELS", "check_bytes", "format_bytes"]

#: Rays (samples) per vertex of any ray-traced estimate (transfer, ground truth): 2**20.
MAX_RAYS_PER_VERTEX = 1 << 20
#: Time codes a scene may sample (a USD stage's startTimeCode..endTimeCode, ``frame_count``):
#: an hour at 24 fps is 86,400.
MAX_TIME_CODES = 100_000
#: Bytes of per-frame animation tables kept on the device (transforms, joint poses, lights).
MAX_TABLE_BYTES = 2 << 30
#: Random multi-starts of a per-vertex lobe fit (``restarts``): each start holds a copy of every
#: restarted vertex's fit and its optimiser state; the methods use 1-8.
MAX_FIT_RESTARTS = 64
#: Texels per side of a view-direction grid (``view_resolution``): the sampled BRDF matrix is
#: res^2 x n^2 float64 and each texel costs a hemisphere quadrature; the papers use 32.
MAX_VIEW_RESOLUTION = 256
#: Longitudes of a light-specialised look-up table (``table_width``): (width / 2 + 1) x width x 3
#: x order float32 on the device, ~200 MiB at 2048 and order 8; the methods use 64-256.
MAX_LOOKUP_TABLE_WIDTH = 2048
#: Pixels of an image read from a file (an environment map): 16384 x 8192; decoding takes ~80
#: bytes per pixel, so a header that claims more is refused before allocating.
MAX_IMAGE_PIXELS = 1 << 27


def format_bytes(n: float) -> str:
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB"):
        if abs(n) < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1024.0
    return f"{n:.1f} TiB"


def check_bytes(nbytes: float, what: str, limit: float, hint: str = "") -> None:
    """Raise ValueError when ``nbytes`` exceeds ``limit`` (``what`` says what needs it)."""
    if nbytes > limit:
        raise ValueError(f"{what} would need {format_bytes(nbytes)}, more than the limit of {format_bytes(limit)}"
                         + (f"; {hint}" if hint else ""))
