"""Float64 mirrors of the LDPRT kernels (the oracles of the tests).

Local frame: the per-vertex tangent frame ``F`` (rows tangent, bitangent, normal) of
:mod:`warpshade.geometry.frames`; local -> world is ``F^T``. Diffuse radiance is
``albedo / pi * dot(L, t~_world)`` (the convention of static PRT), glossy exit radiance
``u(v_local) . (rows_world L)`` (eq. 16).
"""

from __future__ import annotations

import numpy as np

from ...basis import zh
from .glossy import GlossyModel
from .model import LDPRTModel

__all__ = [
    "rotate_stored",
    "shade_glossy_f64",
]


def rotate_stored(stored: np.ndarray, rotations: np.ndarray, order: int) -> np.ndarray:
    """Stored DC + linear bands rotated to world, as SH (V, n*n) float64 (zero from band 2)."""
    out = np.zeros((stored.shape[0], order * order))
    out[:, 0] = stored[:, 0]
    if order > 1:
        w = np.stack([-stored[:, 3], -stored[:, 1], stored[:, 2]], axis=1).astype(np.float64)
        ww = np.einsum("vij,vj->vi", rotations, w)
        out[:, 1], out[:, 2], out[:, 3] = -ww[:, 1], ww[:, 2], -ww[:, 0]
    return out


def world_transfer_f64(model: LDPRTModel, frames: np.ndarray) -> np.ndarray:
    """World-frame transfer of the model under per-vertex frames (float64), (V, n*n).

    Args:
        frames: (V, 3, 3) tangent frames (rows t, b, n); local -> world is ``F^T``.
    """
    rot = np.swapaxes(np.asarray(frames, np.float64), 1, 2)
    axes = zh.rotate(model.axes.astype(np.float64), rot)
    mask = np.arange(model.lobe_capacity)[None, :] < model.counts[:, None]
    t = zh.to_sh(axes, model.coeffs.astype(np.float64) * mask[:, :, None])
    return t + rotate_stored(model.stored, rot, model.order)


def shade_f64(model: LDPRTModel, frames: np.ndarray, light: np.ndarray, albedo: np.ndarray) -> np.ndarray:
    """Float64 mirror of the LDPRT shading kernels, (V, 3) linear RGB.

    ``radiance_c = albedo_c / pi * dot(L_c, t~_world)`` with ``L`` the world-frame lighting SH
    (3, n*n).
    """
    t = world_transfer_f64(model, frames)
    return np.asarray(albedo, np.float64) / np.pi * (t @ np.asarray(light, np.float64).T)


def shade_glossy_f64(model: GlossyModel, frames, view_world, light) -> np.ndarray:
    """Float64 mirror of the glossy shading kernel: (V, C) exit radiance.

    Args:
        frames: (V, 3, 3) tangent frames (rows t, b, n). view_world: (V, 3) unit directions
            towards the viewer. light: (C, n*n) world lighting SH.
    """
    f = np.asarray(frames, dtype=np.float64)
    rot = np.swapaxes(f, 1, 2)
    view_local = np.einsum("vij,vj->vi", f, np.asarray(view_world, np.float64))
    u = model.factorization.view_factors_at(view_local)  # (V, n_b)
    axes = zh.rotate(model.axes.astype(np.float64), rot[:, None])  # (V, n_b, N, 3)
    rows = zh.to_sh(axes, model.coeffs.astype(np.float64))  # (V, n_b, n^2)
    stored = np.stack([rotate_stored(model.stored[:, j], rot, model.order) for j in range(model.rank)], axis=1)
    rows_world = rows + stored
    # negative radiance (SH truncation) is clamped to zero, as the kernel does
    return np.maximum(np.einsum("vj,vjk,ck->vc", u, rows_world, np.asarray(light, np.float64)), 0.0)
