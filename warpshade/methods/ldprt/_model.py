"""The LDPRT per-vertex model: ZH lobes fitted to local-frame transfer, and its float64 mirror.

Local frame: the per-vertex tangent frame ``F`` of :mod:`warpshade.geometry._frames` (rows
tangent, bitangent, normal), the same frame ``warpshade.transfer.compute(space="local")`` uses
-- a direction ``w`` has local coordinates ``F w``. The transfer ``t_local`` is ray traced once
(at a bake frame) in that frame; per frame the deformed mesh's frames ``F(t)`` rotate every
lobe axis to world space, ``s_world = F(t)^T s_local``, so the transfer is carried rigidly by
each vertex's neighbourhood.

What it captures and what it does not: shadowing and inter-reflection that *rotate with the
surface* (local geometry: creases, folds, self-occlusion by nearby surface). Occlusion by
distant parts of the scene that move relative to the vertex (an arm swinging in front of the
torso, the ground under a bending limb) is frozen at the bake pose and rotated along with the
vertex, which is wrong for those parts; no LDPRT variant models a change of distant occlusion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...basis import zh

__all__ = [
    "STORED_BANDS",
    "stored_from_sh",
]

#: Stage-parameter names of the DC/linear storage rule -> :func:`warpshade.basis.zh.fit` values.
STORED_BANDS = {"paper": "paper", "none": 0, "dc": 1, "dc+linear": 2}


@dataclass
class LDPRTModel:
    """Per-vertex ZH transfer (local frame), padded to ``lobe_capacity`` lobes.

    Attributes:
        axes: unit lobe axes, shape (V, L, 3), float32, local tangent frame.
        coeffs: convolution coefficients ``g*``, shape (V, L, n), float32 (zero in stored bands
            and for unused lobes).
        counts: lobes used per vertex, shape (V,), int32 (1..L).
        stored: exactly stored DC and linear SH coefficients (local frame), shape (V, 4),
            float32 (zeros where not stored).
        fit_error: L2 fit error per vertex relative to ``scale``, shape (V,), float32.
        scale: the error scale (RMS transfer norm over the vertices), float.
        total_error: ``sqrt(sum |t~ - t|^2 / sum |t|^2)``, the paper's mesh metric.
        restarted: vertices where the multi-start engaged, shape (V,), bool.
        seconds: fitting time.
    """

    axes: np.ndarray
    coeffs: np.ndarray
    counts: np.ndarray
    stored: np.ndarray
    fit_error: np.ndarray
    scale: float
    total_error: float
    restarted: np.ndarray
    seconds: float

    @property
    def order(self) -> int:
        return int(self.coeffs.shape[-1])

    @property
    def lobe_capacity(self) -> int:
        return int(self.axes.shape[1])

    @property
    def histogram(self) -> dict:
        """``{lobe count: vertices}``."""
        k, c = np.unique(self.counts, return_counts=True)
        return {int(a): int(b) for a, b in zip(k, c)}

    def to_sh(self) -> np.ndarray:
        """Reconstructed local-frame transfer, shape (V, n*n), float64."""
        out = np.zeros((self.axes.shape[0], self.order**2))
        mask = np.arange(self.lobe_capacity)[None, :] < self.counts[:, None]
        out += zh.to_sh(self.axes.astype(np.float64), self.coeffs.astype(np.float64) * mask[:, :, None])
        k = min(4, self.order**2)
        out[:, :k] += self.stored[:, :k]
        return out

    def arrays(self) -> dict:
        """The stage artifacts (NumPy, float32/int32)."""
        return {"axes": self.axes, "coeffs": self.coeffs, "counts": self.counts, "stored": self.stored,
                "fit_error": self.fit_error}


def stored_from_sh(stored_sh: np.ndarray) -> np.ndarray:
    """First four SH coefficients (DC + linear) of (V, n*n) stored bands, padded to (V, 4)."""
    out = np.zeros((stored_sh.shape[0], 4))
    k = min(4, stored_sh.shape[1])
    out[:, :k] = stored_sh[:, :k]
    return out


def fit_transfer(
    transfer,
    lobes: int,
    target_error: float | None = None,
    stored_bands: str = "paper",
    **fit_options,
) -> LDPRTModel:
    """Fit the LDPRT model to per-vertex local-frame transfer vectors.

    Args:
        transfer: (V, n*n) local-frame transfer (e.g. :func:`local_transfer`).
        lobes: fixed lobe count, or the maximum when ``target_error`` is given.
        target_error: None for ``lobes`` lobes everywhere; else the per-vertex lobe count is the
            smallest meeting ``|t~_v - t_v| <= target_error * rms_v |t_v|`` (see
            :func:`warpshade.basis.zh.fit_budget`), capped at ``lobes``.
        stored_bands: "paper" (DC; DC + linear for N >= 3), "none", "dc" or "dc+linear".
        **fit_options: passed to :func:`warpshade.basis.zh.fit`.
    """
    if stored_bands not in STORED_BANDS:
        raise ValueError(f"ldprt: stored_bands must be one of {sorted(STORED_BANDS)}, got {stored_bands!r}")
    t = np.asarray(transfer, dtype=np.float64)
    if t.ndim != 2:
        raise ValueError(f"ldprt: transfer must have shape (V, n*n), got {t.shape}")
    rule = STORED_BANDS[stored_bands]
    scale = float(np.sqrt(np.mean(np.sum(t * t, axis=1)))) if t.shape[0] else 1.0
    scale = scale if scale > 0.0 else 1.0
    if target_error is None:
        res = zh.fit(t, int(lobes), stored_bands=rule, **fit_options)
        axes, coeffs, stored_sh = res.axes, res.coeffs, res.stored
        counts = np.full(t.shape[0], int(lobes), np.int32)
        err, restarted, seconds = res.error, res.restarted, res.seconds
    else:
        b = zh.fit_budget(t, float(target_error), int(lobes), stored_bands=rule, **fit_options)
        axes, coeffs, stored_sh, counts = b.axes, b.coeffs, b.stored, b.counts
        err, restarted, seconds = b.error, b.restarted, b.seconds
    total = float(np.sqrt(np.sum(err**2) / max(np.sum(t * t), 1e-300)))
    return LDPRTModel(
        axes=axes.astype(np.float32),
        coeffs=coeffs.astype(np.float32),
        counts=counts.astype(np.int32),
        stored=stored_from_sh(stored_sh).astype(np.float32),
        fit_error=(err / scale).astype(np.float32),
        scale=scale,
        total_error=total,
        restarted=np.asarray(restarted, bool),
        seconds=float(seconds),
    )


def local_transfer(scene, frame, order: int, samples: int, device=None, seed: int = 0, vertices=None,
                   progress: bool = False) -> np.ndarray:
    """Ray-traced diffuse transfer in the per-vertex tangent frame at ``frame``, (V, n*n) float32."""
    from ...transfer import compute

    return compute(scene, frame, order, samples, space="local", device=device, seed=seed, vertices=vertices,
                   progress=progress).transfer
