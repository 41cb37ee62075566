"""Glossy LDPRT: BRDF-specialised transfer rows fitted with ZH lobes (Sloan et al. 2005, eq. 14-16).

With the BRDF factorised as ``B ~ U~ S~ V~`` (:func:`warpshade.scene._materials.factorize`) and
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
from ...scene import _materials as materials
from ._model import STORED_BANDS, stored_from_sh

__all__ = ["GlossyModel", "BRDF_KINDS", "brdf_arrays", "brdf_from_arrays", "brdf_from_params", "fit_glossy", "glossy_rows"]


@dataclass
class GlossyModel:
    """Per-vertex glossy ZH transfer (local frame).

    Attributes:
        axes: (V, n_b, N, 3) float32 lobe axes per BRDF row.
        coeffs: (V, n_b, N, n) float32 convolution coefficients.
        stored: (V, n_b, 4) float32 exactly stored DC + linear SH per row.
        factorization: the :class:`~warpshade.scene._materials.BRDFFactorization` (view factors).
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


#: The BRDF models glossy LDPRT factorises (stage parameter ``brdf``).
BRDF_KINDS = ("microfacet", "beckmann", "phong", "blinn-phong", "lambert")


def brdf_arrays(kind: str, roughness: float, exponent: float, f0: float) -> dict:
    """A BRDF's stage parameters as named arrays (an "arrays" artifact port)."""
    if kind not in BRDF_KINDS:
        raise ValueError(f"glossy LDPRT: unknown BRDF {kind!r} ({', '.join(BRDF_KINDS)})")
    return {"kind": np.array(kind), "roughness": np.array(float(roughness)), "exponent": np.array(float(exponent)),
            "f0": np.array(float(f0))}


def brdf_from_arrays(arrays: dict) -> materials.BRDF:
    """The BRDF of :func:`brdf_arrays` (e.g. the ``brdf`` port of ``ldprt.glossy_fit``)."""
    try:
        return brdf_from_params(str(arrays["kind"]), float(arrays["roughness"]), float(arrays["exponent"]),
                                float(arrays["f0"]))
    except KeyError as exc:
        raise ValueError(f"glossy LDPRT: not a BRDF description (missing {exc})") from None


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
