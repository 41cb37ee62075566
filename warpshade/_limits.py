"""Sizes warpshade refuses before allocating, with a message naming what asked for them.

A request that would not fit (a hundred billion rays per vertex, a stage whose time range spans
a billion time codes) is refused up front with the parameter and the limit in the message,
instead of ending in a MemoryError, a swap storm or an hour of silence. The limits are far above
what the methods need; change them here, with a reason.
"""

from __future__ import annotations

__all__ = ["MAX_RAYS_PER_VERTEX", "MAX_TIME_CODES", "MAX_TABLE_BYTES", "check_bytes", "format_bytes"]

#: Rays (samples) per vertex of any ray-traced estimate (transfer, ground truth): 2**20.
MAX_RAYS_PER_VERTEX = 1 << 20
#: Time codes a scene may sample (a USD stage's startTimeCode..endTimeCode, ``frame_count``):
#: an hour at 24 fps is 86,400.
MAX_TIME_CODES = 100_000
#: Bytes of per-frame animation tables kept on the device (transforms, joint poses, lights).
MAX_TABLE_BYTES = 2 << 30


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
