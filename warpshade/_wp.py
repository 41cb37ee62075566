"""Shared Warp set-up: quiet initialisation and explicit device resolution.

Every module that launches kernels imports ``wp`` from here so that Warp is initialised once,
quietly, and so that device handling is the same everywhere: a device is always an explicit
argument (``"cpu"``, ``"cuda:0"``, ...) that defaults to Warp's default device, and nothing
falls back silently from CUDA to the CPU.
"""

from __future__ import annotations

import os

import warp as wp

__all__ = ["wp", "resolve_device", "init"]

_initialised = False


def init() -> None:
    """Initialise Warp once, without the start-up banner unless WARPSHADE_VERBOSE is set."""
    global _initialised
    if _initialised:
        return
    if not os.environ.get("WARPSHADE_VERBOSE"):
        # Warp >= 1.10 uses log_level; older versions use the quiet flag.
        if hasattr(wp, "LOG_WARNING"):
            wp.config.log_level = wp.LOG_WARNING
        wp.config.quiet = True
    wp.init()
    _initialised = True


def resolve_device(device=None) -> wp.context.Device:
    """Return the Warp device for ``device`` (None means Warp's default device).

    Raises:
        ValueError: if the device does not exist on this machine (for example ``"cuda:0"`` on a
            machine without a GPU). There is no silent fallback to the CPU.
    """
    init()
    try:
        return wp.get_device(device)
    except Exception as exc:  # Warp raises RuntimeError / ValueError depending on version
        available = ", ".join(str(d) for d in wp.get_devices())
        raise ValueError(f"device {device!r} is not available (available: {available})") from exc


init()
