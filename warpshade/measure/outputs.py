"""What a run writes: the USD layer of its recorded frames and its JSON report."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._fileio import write_json_atomic

__all__: list[str] = []


def write_usd(runtime, path, extra_primvars: dict | None = None) -> Path:
    """Write the run's recorded frames as a new USD layer (never over the input).

    The layer sublayers the input scene (when it came from a file) and adds per-vertex
    ``primvars:displayColor`` (vertex interpolation, time-sampled per recorded frame) to each
    shaded mesh; meshes not in the input file (e.g. a generated ground plane) are written in
    full (:func:`warpshade.io.usd_write.write_vertex_colors`).

    Raises:
        ValueError: when the run recorded no frames.
    """
    from ..io.usd_write import write_vertex_colors

    if not runtime.results:
        raise ValueError("write_usd: the run recorded no frames (step with record=True, or run())")
    frames = sorted(runtime.results)
    colors = np.stack([runtime.results[f] for f in frames])
    return write_vertex_colors(path, runtime.scene, np.array(frames), colors, extra_primvars=extra_primvars)


def report(runtime, error: dict | None = None) -> dict:
    """The run's description (:meth:`~warpshade.graph.Runtime.describe`) with its error."""
    out = runtime.describe()
    out["error"] = error
    return out


def write_report(runtime, path, error: dict | None = None) -> Path:
    """Write :func:`report` as JSON, atomically."""
    return write_json_atomic(path, report(runtime, error))
