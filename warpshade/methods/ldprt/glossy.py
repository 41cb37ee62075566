"""Glossy LDPRT: BRDF-specialised transfer rows fitted with ZH lobes (Sloan et al. 2005, eq. 14-16).

With the BRDF factorised as ``B ~ U~ S~ V~`` (:func:`warpshade.scene.materials.factorize`) and
``T`` the per-vertex transfer matrix from source lighting to shadowed incident lighting (local
frame), exit radiance towards a view ``v`` is ``r(v) = u(v) . (M' e)`` with ``M' = V~ T``
(n_b x n^2, eq. 15). Each of the n_b rows of ``M'`` is an SH vector in the local frame; each is
fitted with N ZH lobes, rotated with the surface per frame exactly like diffuse transfer
(eq. 16)::

    r(v) = sum_j u_j(v_local) sum_i sum_lm y_lm(F^T s*_ji) g*_jil e_lm

``T`` here is the SH product matrix of the ray-traced local visibility ``V(s)``
(``T_ij = integral V y_i y_j``, computed by :func:`warpshade.basis.sh.product_matrix` from the
order-n visibility vector: exact when nothing is occluded, a band-limited approximation of the
shadowing otherwise). Inter-reflections are not included.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...basis import sh, zh
from ...scene import materials
from .model import STORED_BANDS, rotate_stored, stored_from_sh

__all__ = ["GlossyModel", "brdf_from_params", "fit_glossy", "glossy_rows", "shade_glossy_reference"]


@dataclass
class GlossyModel:
    """Per-vertex glossy ZH transfer (local frame).

    Attributes:
        axes: (V, n_b, N, 3) float32 lobe axes per BRDF row.
        coeffs: (V, n_b, N, n) float32 convolution coefficients.
        stored: (V, n_b, 4) float32 exactly stored DC + linear SH per row.
        factorization: the :class:`~warpshade.scene.materials.BRDFFactorization` (view factors).
        fit_error: (V,) float32 L2 fit error of all rows relative to the RMS row-set norm.
        total_error: the paper's metric over all rows and vertices.
        max_lobe_norm_ratio: largest lobe-set norm over its row's norm (about 1 unless lobes
            cancel; see the ``ridge`` of :func:`warpshade.basis.zh.fit`).
    """

    axes: np.ndarray
    coeffs: np.ndarray
    stored: np.ndarray
    factorization: materials.BRDFFactorization
    fit_error: np.ndarray
    total_error: float
    max_lobe_norm_ratio: float = 0.0

    @property
    def rank(self) -> int:
        return int(self.axes.shape[1])

    @property
    def lobe_count(self) -> int:
        return int(self.axes.shape[2])

    @property
    def order(self) -> int:
        return int(self.coeffs.shape[-1])

    def rows_sh(self) -> np.ndarray:
        """Reconstructed rows, (V, n_b, n*n) float64, local frame."""
        out = zh.to_sh(self.axes.astype(np.float64), self.coeffs.astype(np.float64))
        out[..., :4] += self.stored[..., : min(4, self.order**2)]
        return out


def brdf_from_params(kind: str, roughness: float = 0.3, exponent: float = 30.0, f0: float = 0.04) -> materials.BRDF:
    """A BRDF from stage parameters: "microfacet" (GGX), "beckmann", "phong", "blinn-phong", "lambert"."""
    if kind == "microfacet":
        return materials.Microfacet(roughness=roughness, distribution="ggx", f0=f0)
    if kind == "beckmann":
        return materials.Microfacet(roughness=roughness, distribution="beckmann", f0=f0)
    if kind == "phong":
        return materials.Phong(exponent=exponent)
    if kind == "blinn-phong":
        return materials.BlinnPhong(exponent=exponent)
    if kind == "lambert":
        return materials.Lambert()
    raise ValueError(f"glossy LDPRT: unknown BRDF {kind!r} (microfacet, beckmann, phong, blinn-phong, lambert)")


def glossy_rows(visibility, factorization: materials.BRDFFactorization) -> np.ndarray:
    """``M'_v = V~ T_v`` for every vertex, (V, n_b, n*n) float64 (local frame).

    Args:
        visibility: local-frame SH visibility vectors, (V, n*n).
    """
    vis = np.asarray(visibility, dtype=np.float64)
    if vis.shape[-1] != factorization.order**2:
        raise ValueError(f"glossy_rows: visibility has {vis.shape[-1]} coefficients, the BRDF factorisation "
                         f"order {factorization.order} needs {factorization.order ** 2}")
    t = sh.product_matrix(vis)  # (V, n^2, n^2), symmetric
    return np.einsum("ji,vik->vjk", factorization.rows, t)


def fit_glossy(visibility, factorization: materials.BRDFFactorization, lobes: int, stored_bands: str = "paper",
               **fit_options) -> GlossyModel:
    """Fit N lobes to every BRDF-specialised row of every vertex (batched over V * n_b rows)."""
    rows = glossy_rows(visibility, factorization)
    v, nb, n2 = rows.shape
    res = zh.fit(rows.reshape(v * nb, n2), int(lobes), stored_bands=STORED_BANDS[stored_bands], **fit_options)
    err = res.error.reshape(v, nb)
    scale = float(np.sqrt(np.mean(np.sum(rows**2, axis=(1, 2))))) or 1.0
    return GlossyModel(
        axes=res.axes.reshape(v, nb, lobes, 3).astype(np.float32),
        coeffs=res.coeffs.reshape(v, nb, lobes, -1).astype(np.float32),
        stored=stored_from_sh(res.stored).reshape(v, nb, 4).astype(np.float32),
        factorization=factorization,
        fit_error=(np.sqrt(np.sum(err**2, axis=1)) / scale).astype(np.float32),
        total_error=float(np.sqrt(np.sum(err**2) / max(np.sum(rows**2), 1e-300))),
        max_lobe_norm_ratio=float(res.notes["max_lobe_norm_ratio"]),
    )


def shade_glossy_reference(model: GlossyModel, frames, view_world, light) -> np.ndarray:
    """Float64 reference of the glossy shading kernel: (V, C) exit radiance.

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
    return np.einsum("vj,vjk,ck->vc", u, rows_world, np.asarray(light, np.float64))
