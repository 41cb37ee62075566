"""Float64 mirrors of the static PRT kernels (the oracles of the tests)."""

from __future__ import annotations

import numpy as np

from ...basis import sh

__all__: list[str] = []


def shade_transfer_f64(transfer, light, albedo) -> np.ndarray:
    """``albedo_c / pi * max(0, dot(L_c, t_v))``, shape (V, 3), float64.

    Args:
        transfer: (V, n*n) world-frame transfer, or (V, 3, n*n) per channel (interreflected);
            light: (3, n*n) world-frame SH lighting;
            albedo: (V, 3) linear RGB.
    """
    t = np.asarray(transfer, np.float64)
    if t.ndim == 3:  # per-channel transfer (V, 3, n*n)
        rgb = np.einsum("vci,ci->vc", t, np.asarray(light, np.float64))
    else:
        rgb = t @ np.asarray(light, np.float64).T
    return np.asarray(albedo, np.float64) / np.pi * np.maximum(rgb, 0.0)


def shade_unshadowed_f64(normals, light, albedo, order: int) -> np.ndarray:
    """``albedo_c / pi * max(0, sum_lm A_l L_c,lm y_lm(n_v))`` (clamped-cosine irradiance), (V, 3).

    Args:
        normals: (V, 3) unit world normals; light: (3, n*n); albedo: (V, 3).
    """
    conv = sh.clamped_cosine_zh(order)[sh.band_of(order)]
    irradiance = sh.basis(np.asarray(normals, np.float64), order) @ (np.asarray(light, np.float64)[:, : order * order] * conv).T
    return np.asarray(albedo, np.float64) / np.pi * np.maximum(irradiance, 0.0)
