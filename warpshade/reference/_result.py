"""The result of a reference shading (:class:`ShadingResult`), host memory."""

from __future__ import annotations

import numpy as np

__all__: list[str] = []


class ShadingResult:
    """Reference shading of the receivers of one frame (NumPy, host memory).

    Attributes:
        radiance: outgoing radiance, shape (receiver_count, 3), float32, linear RGB.
        stderr: its Monte Carlo standard error, shape (receiver_count, 3), float32.
        vertices: receiver vertex indices (rows), shape (receiver_count,), int64.
        samples, method, frame, seed: how it was computed.
        bounces: diffuse bounces of the indirect light included (0: direct light only).
    """

    def __init__(self, radiance, stderr, vertices, samples, method, frame, seed, bounces: int = 0):
        self.radiance = radiance
        self.stderr = stderr
        self.vertices = vertices
        self.samples = samples
        self.method = method
        self.frame = frame
        self.seed = seed
        self.bounces = bounces

    def __array__(self, dtype=None, copy=None):
        return np.asarray(self.radiance, dtype=dtype)

    def __repr__(self) -> str:
        bounces = f", bounces={self.bounces}" if self.bounces else ""
        return f"ShadingResult(receivers={self.radiance.shape[0]}, samples={self.samples}, method={self.method!r}{bounces})"
