"""Per-frame host data into fixed device buffers (the capture-safe way stages take lighting).

A frame stage's ``launch`` may only read buffers whose addresses never change (so the launch
sequence can be captured once as a CUDA graph); what changes per frame on the host -- the
frame's SH lighting above all -- is copied into such a buffer in ``prepare``.
"""

from __future__ import annotations

import numpy as np

from .._wp import wp

__all__ = ["StagedUpload", "LightingUpload"]


class StagedUpload:
    """A fixed device array refreshed from host values, through a pinned buffer on CUDA.

    Args:
        shape: array shape.
        dtype: Warp scalar dtype (``wp.float32``, ``wp.int32``, ...).
        device: the Warp device of the fixed array.

    Attributes:
        array: the fixed device array (pass it to kernels once, in ``setup``).

    The host staging buffer is reused each frame; the runtime synchronises the device at the
    end of every frame, so the previous (asynchronous) copy has completed before it is reused.
    """

    def __init__(self, shape, dtype, device):
        self.array = wp.zeros(shape, dtype=dtype, device=device)
        self._host = wp.zeros(shape, dtype=dtype, device="cpu", pinned=device.is_cuda)
        self._previous: np.ndarray | None = None

    def upload(self, values) -> bool:
        """Copy ``values`` into :attr:`array`; returns whether they differ from the last upload."""
        host = self._host.numpy()
        new = np.asarray(values, dtype=host.dtype)
        if new.shape != host.shape:
            raise ValueError(f"upload: expected shape {host.shape}, got {new.shape}")
        changed = self._previous is None or not np.array_equal(new, self._previous)
        self._previous = new.copy()
        host[...] = new
        wp.copy(self.array, self._host)
        return changed


class LightingUpload:
    """The frame's world-frame SH lighting, (3, n*n) float32, in a fixed device buffer.

    Attributes:
        light: the fixed (3, n*n) device array.
        changed: a fixed (1,) int32 device flag, 1 when the lighting differs from the previous
            frame's (kernels that tabulate lighting, e.g. LDPRT's light-specialised table, skip
            rebuilding it when 0).
    """

    def __init__(self, order: int, device):
        self.order = order
        self._light = StagedUpload((3, order * order), wp.float32, device)
        self._changed = StagedUpload((1,), wp.int32, device)
        self.light = self._light.array
        self.changed = self._changed.array

    def upload(self, coeffs) -> bool:
        """Upload (3, n*n) coefficients; returns whether they changed."""
        coeffs = np.asarray(coeffs, np.float64)
        if coeffs.shape != (3, self.order * self.order) or not np.all(np.isfinite(coeffs)):
            raise ValueError(f"lighting must be finite with shape (3, {self.order ** 2}), got {coeffs.shape}")
        changed = self._light.upload(coeffs)
        self._changed.upload([1 if changed else 0])
        return changed
