"""The artifact of static PRT: per-vertex diffuse transfer vectors, and how it is made.

A transfer vector ``t_v`` is the SH projection of ``V(s) max(0, n_v . s)`` at vertex ``v``
(world frame, no albedo, no 1/pi; see :mod:`warpshade.transfer._raytrace`), so the outgoing
radiance of a diffuse vertex of albedo ``rho`` under distant lighting with SH coefficients
``L_c`` is ``rho_c / pi * dot(L_c, t_v)``. It is ray traced once, at one frame: exact (up to SH
truncation and sampling) for meshes that do not move, the "undeformed PRT" baseline otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__: list[str] = []


@dataclass
class TransferModel:
    """Per-vertex diffuse transfer of one scene.

    Attributes:
        transfer: shape (vertex_count, order**2), float32, world frame.
    """

    transfer: np.ndarray

    @property
    def order(self) -> int:
        return int(round(np.sqrt(self.transfer.shape[1])))

    def arrays(self) -> dict:
        """The stage artifacts (what the cache stores)."""
        return {"transfer": self.transfer}

    @classmethod
    def from_arrays(cls, arrays: dict, vertex_count: int | None = None, order: int | None = None) -> "TransferModel":
        """Rebuild from :meth:`arrays`; raises ValueError for anything that is not one (the cache
        then recomputes): a wrong shape, dtype or a non-finite value."""
        t = np.asarray(arrays["transfer"])
        if t.ndim != 2 or t.dtype != np.float32:
            raise ValueError(f"prt: transfer must be a float32 (V, n*n) array, got {t.dtype} {t.shape}")
        if vertex_count is not None and t.shape[0] != vertex_count:
            raise ValueError(f"prt: transfer has {t.shape[0]} rows for {vertex_count} vertices")
        if order is not None and t.shape[1] != order * order:
            raise ValueError(f"prt: transfer has {t.shape[1]} coefficients, order {order} needs {order * order}")
        if not np.all(np.isfinite(t)):
            raise ValueError("prt: transfer contains NaN or infinite values")
        return cls(t)


def bake_transfer(scene, frame, order: int, samples: int, seed: int = 0, device=None, progress: bool = False) -> TransferModel:
    """Ray trace the transfer of every vertex of ``scene`` at time code ``frame`` (``progress``:
    a progress bar over the vertices)."""
    from ...transfer import compute

    result = compute(scene, frame, order, samples, space="world", device=device, seed=seed, progress=progress)
    return TransferModel(np.asarray(result.transfer, dtype=np.float32))
