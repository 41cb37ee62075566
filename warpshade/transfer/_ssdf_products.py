"""Look-ups of compressed SSDF maps and their products with spherical Gaussians (Wang et al. 2009,
eq. 25-31): float64 NumPy (:func:`ssdf_lookup`, :func:`ssdf_product`, :func:`ssdf_integral`)
and the Warp kernels of :mod:`._ssdf_warp` run on a model (:func:`evaluate_ssdf_warp`,
:func:`product_warp`). Directions are local to each vertex's tangent frame (:mod:`._ssdf`).
"""

from __future__ import annotations

import numpy as np

from .._wp import resolve_device, wp
from ..basis import sg
from ..scene._materials import hemisphere_to_concentric
from . import _ssdf_warp as ssdf_warp
from ._ssdf import SSDF_LIMIT, check_resolution
from ._ssdf_pca import SSDFModel, as_maps

__all__ = [
    "bilinear_taps",
]


def _dirs(dirs_local, name: str = "dirs_local") -> np.ndarray:
    d = np.asarray(dirs_local, dtype=np.float64)
    if d.ndim != 2 or d.shape[1] != 3:
        raise ValueError(f"ssdf: {name} must have shape (P, 3), got {d.shape}")
    n = np.linalg.norm(d, axis=1)
    if not np.all(np.isfinite(d)) or np.any(n == 0.0):
        raise ValueError(f"ssdf: {name} must be finite and nonzero")
    return d / n[:, None]


def bilinear_taps(dirs_local, resolution: int):
    """Bilinear taps between texel centres at the concentric coordinates of local directions.

    Args:
        dirs_local: (P, 3) local directions (normalised here; below the horizon clamped to it).
        resolution: map side R (>= 2).

    Returns:
        ``(texels, weights)``: flat texel indices (P, 4) int64 and weights (P, 4) float64 summing
        to 1 (edge-clamped: outside the outermost texel centres the edge value is held).
    """
    r = check_resolution(resolution, "resolution")
    ab = hemisphere_to_concentric(_dirs(dirs_local))
    f = (ab + 1.0) * 0.5 * r - 0.5
    i = np.clip(np.floor(f).astype(np.int64), 0, r - 2)
    t = np.clip(f - i, 0.0, 1.0)
    ia, ib, ta, tb = i[:, 0], i[:, 1], t[:, 0], t[:, 1]
    t00 = ia * r + ib
    texels = np.stack([t00, t00 + 1, t00 + r, t00 + r + 1], 1)
    weights = np.stack([(1 - ta) * (1 - tb), (1 - ta) * tb, ta * (1 - tb), ta * tb], 1)
    return texels, weights


def sample_maps(maps, dirs_local) -> np.ndarray:
    """Uncompressed lookup: map p at direction p, bilinear (float64).

    Args:
        maps: (P, R, R) SSDFs, one per direction.
        dirs_local: (P, 3) local directions.

    Returns:
        (P,) float64 radians.
    """
    m = as_maps(maps)
    d = _dirs(dirs_local)
    if d.shape[0] != m.shape[0]:
        raise ValueError(f"ssdf: {m.shape[0]} maps but {d.shape[0]} directions")
    texels, w = bilinear_taps(d, m.shape[1])
    flat = m.reshape(m.shape[0], -1).astype(np.float64)
    return np.sum(np.take_along_axis(flat, texels, axis=1) * w, axis=1)


def _coeff_rows(model: SSDFModel, coeffs_rows, count: int) -> np.ndarray:
    c = np.asarray(coeffs_rows, dtype=np.float64)
    if c.ndim != 2 or c.shape != (count, model.terms):
        raise ValueError(f"ssdf: coeffs_rows must have shape ({count}, {model.terms}), got {c.shape}")
    if not np.all(np.isfinite(c)):
        raise ValueError("ssdf: coeffs_rows contains NaN or infinite values")
    return c


def ssdf_lookup(model: SSDFModel, coeffs_rows, dirs_local) -> np.ndarray:
    """The compressed SSDF (eq. 24) of per-point coefficients at local directions (float64).

    Args:
        model: :class:`SSDFModel`.
        coeffs_rows: (P, N) coefficients per point (a vertex's row of ``model.coeffs`` or any blend).
        dirs_local: (P, 3) local directions.

    Returns:
        (P,) float64 radians (not clamped), bilinear between texel centres.
    """
    d = _dirs(dirs_local)
    c = _coeff_rows(model, coeffs_rows, d.shape[0])
    texels, w = bilinear_taps(d, model.resolution)
    mean = model.mean.astype(np.float64)[texels]  # (P, 4)
    basis = model.basis.astype(np.float64)[:, texels]  # (N, P, 4)
    values = mean + np.einsum("pn,npk->pk", c, basis)
    return np.sum(values * w, axis=1)


def _lobe_args(sharpness, amplitude, count: int):
    lam = np.broadcast_to(np.asarray(sharpness, np.float64), (count,))
    if not np.all(np.isfinite(lam)) or np.any(lam < 0.0):
        raise ValueError("ssdf: sharpness must be finite and >= 0")
    mu = np.broadcast_to(np.asarray(amplitude, np.float64), (count,))
    if not np.all(np.isfinite(mu)):
        raise ValueError("ssdf: amplitude must be finite")
    return lam, mu


def ssdf_product(model: SSDFModel, coeffs_rows, axis_local, sharpness, amplitude=1.0, fh_method: str = "erf") -> np.ndarray:
    """eq. 31: the amplitude of ``G(i; p, lambda, mu) (x) V(i)``, ``mu f_h(Vd(p), lambda) / f_h(pi/2, lambda)``.

    Args:
        model, coeffs_rows: as :func:`ssdf_lookup`.
        axis_local: (P, 3) lobe axes in the local tangent frame.
        sharpness: lambda, scalar or (P,).
        amplitude: mu, scalar or (P,).
        fh_method: :func:`warpshade.basis.sg.hemisphere_integral` method.

    Returns:
        (P,) float64; the product lobe keeps the axis and sharpness.
    """
    theta = ssdf_lookup(model, coeffs_rows, axis_local)
    lam, mu = _lobe_args(sharpness, amplitude, theta.shape[0])
    return mu * sg.visible_fraction(np.clip(theta, -SSDF_LIMIT, SSDF_LIMIT), lam, method=fh_method)


def ssdf_integral(model: SSDFModel, coeffs_rows, axis_local, sharpness, amplitude=1.0, fh_method: str = "erf") -> np.ndarray:
    """eq. 30: ``integral G(i; p, lambda, mu) V(i) di ~ mu f_h(Vd(p), lambda)``, (P,) float64."""
    theta = ssdf_lookup(model, coeffs_rows, axis_local)
    lam, mu = _lobe_args(sharpness, amplitude, theta.shape[0])
    return mu * sg.hemisphere_integral(np.clip(theta, -SSDF_LIMIT, SSDF_LIMIT), lam, method=fh_method)


def _model_arrays(model: SSDFModel, dev):
    return (wp.array(model.mean, dtype=float, device=dev), wp.array(model.basis, dtype=float, device=dev),
            wp.array(model.coeffs, dtype=float, device=dev))


def _blend_args(model: SSDFModel, vertex_ids, weights, count: int):
    ids = np.asarray(vertex_ids)
    if ids.shape != (count, 3) or (ids.size and not np.issubdtype(ids.dtype, np.integer)):
        raise ValueError(f"ssdf: vertex_ids must be integer (P, 3) = ({count}, 3), got {ids.dtype} {ids.shape}")
    if ids.size and (ids.min() < 0 or ids.max() >= model.vertex_count):
        raise ValueError(f"ssdf: vertex_ids must index 0..{model.vertex_count - 1}")
    w = np.asarray(weights, np.float64)
    if w.shape != (count, 3) or not np.all(np.isfinite(w)):
        raise ValueError(f"ssdf: weights must be finite (P, 3) = ({count}, 3), got {w.shape}")
    return ids.astype(np.int32), w.astype(np.float32)


def evaluate_ssdf_warp(model: SSDFModel, vertex_ids, weights, dirs_local, device=None) -> np.ndarray:
    """:func:`~warpshade.transfer._ssdf_warp.ssdf_eval` over a batch (Warp, float32).

    Args:
        model: :class:`SSDFModel`.
        vertex_ids: (P, 3) int rows of ``model.coeffs`` (the same id three times for a vertex).
        weights: (P, 3) barycentric weights.
        dirs_local: (P, 3) local directions.
        device: Warp device.

    Returns:
        (P,) float32 radians.
    """
    dev = resolve_device(device)
    d = _dirs(dirs_local)
    ids, w = _blend_args(model, vertex_ids, weights, d.shape[0])
    mean, basis, coeffs = _model_arrays(model, dev)
    out = wp.empty(d.shape[0], dtype=float, device=dev)
    if d.shape[0]:
        wp.launch(ssdf_warp.ssdf_eval_kernel, dim=d.shape[0],
                  inputs=[mean, basis, coeffs, wp.array(ids, dtype=wp.vec3i, device=dev), wp.array(w, dtype=wp.vec3, device=dev),
                          wp.array(d.astype(np.float32), dtype=wp.vec3, device=dev), model.resolution, model.terms, out],
                  device=dev)
    return out.numpy()


def product_warp(model: SSDFModel, vertex_ids, weights, axes_local, sharpness, device=None):
    """eq. 31 over a batch (Warp): ``(theta_d, fraction)``, each (P,) float32, ``theta_d`` clamped
    to [-pi/2, pi/2] and ``fraction = f_h(theta_d, lambda) / f_h(pi/2, lambda)`` (erf form)."""
    dev = resolve_device(device)
    d = _dirs(axes_local, "axes_local")
    ids, w = _blend_args(model, vertex_ids, weights, d.shape[0])
    lam, _ = _lobe_args(sharpness, 1.0, d.shape[0])
    mean, basis, coeffs = _model_arrays(model, dev)
    theta = wp.empty(d.shape[0], dtype=float, device=dev)
    frac = wp.empty(d.shape[0], dtype=float, device=dev)
    if d.shape[0]:
        wp.launch(ssdf_warp.ssdf_product_kernel, dim=d.shape[0],
                  inputs=[mean, basis, coeffs, wp.array(ids, dtype=wp.vec3i, device=dev), wp.array(w, dtype=wp.vec3, device=dev),
                          wp.array(d.astype(np.float32), dtype=wp.vec3, device=dev),
                          wp.array(lam.astype(np.float32), dtype=float, device=dev), model.resolution, model.terms, theta, frac],
                  device=dev)
    return theta.numpy(), frac.numpy()
