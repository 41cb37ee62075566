"""The material a ``.svbrdf`` texture (:mod:`.svbrdf`) describes, before any fit: what the
ray-traced reference shades for ``brdf = "svbrdf"`` (:mod:`warpshade.reference.svbrdf_warp` is
its device side). Float64.

At a surface point the texel is the nearest one of the point's UV, the SG shading's own look-up
(:func:`.svbrdf_warp.svbrdf_texel`: ``u`` repeats, ``v`` is clamped, row 0 at ``v = 1``). The
texel's BRDF is eq. 13 with the file's curves, ``rho(o, i) = F(|i.h|, eta) S(theta_o) S(theta_i)
D(theta_h) / (pi max(n.i, c) max(n.o, c))`` (``c`` = :data:`.brdf.COS_FLOOR`, as
:meth:`.svbrdf.SVBRDFTexture.remaining_factor`), 0 below either horizon, with the curves read
between their samples (uniform in theta over [0, pi/2]) as:

* ``S``: linearly in theta between the two samples around the angle -- the SG shading's decode
  (:func:`.svbrdf_warp.svbrdf_shadow`) of the uncompressed curve;
* ``D``: geometrically in ``cos theta_h`` between the two samples around ``theta_h`` (``log D``
  linear in the cosine; linearly where either sample is 0). It is exact for one SG lobe about the
  normal, the shape the method fits; on the bundled texture's sharpest Beckmann lobe (slope
  0.08, one sample per degree) it is within 1e-4 of the analytic NDF where linear
  interpolation in theta is 1e-2 off (relative to the peak).

Sampling (for unbiased Monte Carlo estimators): each texel gets a GGX lobe of half vectors, its
alpha the one of :data:`LOBE_ALPHAS` whose half-vector density is closest to the texel's
normalised ``D(h) cos theta_h`` in the chi-square sense (the variance of estimating ``integral D
cos`` with it), mixed with the cosine lobe with probability :data:`COSINE_WEIGHT`: the mixture of
:mod:`warpshade.scene.materials_warp`'s tabulated model, positive wherever the BRDF can be.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..._hashing import hash_arrays
from ...scene.materials import BRDF
from .brdf import COS_FLOOR, fresnel_cook_torrance
from .svbrdf import SVBRDFTable, _check_table, read_svbrdf

__all__ = ["COSINE_WEIGHT", "LOBE_ALPHAS", "SVBRDFMaterial", "svbrdf_material"]

#: GGX alphas a texel's sampling lobe is chosen from (log-spaced).
LOBE_ALPHAS = np.geomspace(0.01, 1.0, 48)
#: Probability of the cosine lobe in every texel's sampling mixture (the rest is the GGX lobe):
#: it keeps the pdf positive over the hemisphere, whatever the fit.
COSINE_WEIGHT = 0.15
#: Polar angles of h the lobe choice integrates over (midpoints on [0, pi/2]).
_FIT_NODES = 1024


@dataclass(eq=False)
class SVBRDFMaterial(BRDF):
    """A texture of eq.-13 materials as stored (module docstring).

    Attributes:
        ndf, shadow: ``D`` and ``S`` per texel, (height, width, samples) float64, at ``samples``
            uniform polar angles over [0, pi/2] (row 0 at ``v = 1``).
        eta: the Fresnel index; source: the file it came from, or "<array>".

    :meth:`evaluate_texels` evaluates texels' BRDFs; the plain :meth:`evaluate` of a
    :class:`~warpshade.scene.materials.BRDF` has no texel and refuses.
    """

    ndf: np.ndarray = field(repr=False)
    shadow: np.ndarray = field(repr=False)
    eta: float = 1.33
    source: str = "<array>"
    name = "svbrdf"

    def __post_init__(self):
        d, s, e = _check_table(self.ndf, self.shadow, self.eta, f"SVBRDFMaterial {self.source}")
        self.ndf, self.shadow, self.eta = d, s, e
        self._lobes = None

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.ndf.shape[0]), int(self.ndf.shape[1])

    @property
    def samples(self) -> int:
        return int(self.ndf.shape[2])

    @property
    def texel_count(self) -> int:
        return int(self.ndf.shape[0] * self.ndf.shape[1])

    def describe(self) -> dict:
        h, w = self.shape
        return {"model": self.name, "source": self.source, "size": [h, w], "samples": self.samples, "eta": self.eta,
                "content": hash_arrays([np.ascontiguousarray(self.ndf), np.ascontiguousarray(self.shadow)])[:16]}

    def evaluate(self, view, light):
        raise ValueError(f"SVBRDFMaterial {self.source}: a texture of materials is evaluated per texel "
                         "(evaluate_texels(texels, view, light))")

    def _flat(self, texels) -> np.ndarray:
        rc = np.asarray(texels, np.int64)
        h, w = self.shape
        if rc.shape[-1:] != (2,) or np.any(rc < 0) or np.any(rc[..., 0] >= h) or np.any(rc[..., 1] >= w):
            raise ValueError(f"SVBRDFMaterial {self.source}: texels must be (..., 2) (row, column) inside {h} x {w}")
        return rc[..., 0] * w + rc[..., 1]

    def _bracket(self, cos_theta):
        """The samples around each angle: (index i, fraction in theta, cos theta_i, cos theta_i+1)."""
        n = self.samples
        step = 0.5 * np.pi / (n - 1)
        theta = np.arccos(np.clip(np.asarray(cos_theta, np.float64), 0.0, 1.0))
        x = theta / step
        i = np.clip(np.floor(x).astype(np.int64), 0, n - 2)
        return i, np.clip(x - i, 0.0, 1.0), np.cos(i * step), np.cos((i + 1) * step)

    def ndf_at(self, texels, cos_h) -> np.ndarray:
        """The texels' ``D`` at cosines of theta_h (module docstring: log-linear in the cosine)."""
        flat = self._flat(texels)
        c = np.clip(np.asarray(cos_h, np.float64), 0.0, 1.0)
        i, _, c0, c1 = self._bracket(c)
        d = self.ndf.reshape(self.texel_count, -1)
        d0, d1 = d[flat, i], d[flat, i + 1]
        t = np.clip((c0 - c) / (c0 - c1), 0.0, 1.0)
        both = (d0 > 0.0) & (d1 > 0.0)
        geo = np.exp((1.0 - t) * np.log(np.where(both, d0, 1.0)) + t * np.log(np.where(both, d1, 1.0)))
        return np.where(both, geo, (1.0 - t) * d0 + t * d1)

    def shadow_at(self, texels, cos_t) -> np.ndarray:
        """The texels' ``S`` at cosines of the polar angle (linear in theta, in [0, 1])."""
        flat = self._flat(texels)
        i, f, _, _ = self._bracket(cos_t)
        s = self.shadow.reshape(self.texel_count, -1)
        return np.clip((1.0 - f) * s[flat, i] + f * s[flat, i + 1], 0.0, 1.0)

    def evaluate_texels(self, texels, view, light) -> np.ndarray:
        """``rho(o, i)`` (1/sr) of texels (..., 2) (row, column) at unit local directions (..., 3)
        (+z the normal); 0 below either horizon."""
        o = np.asarray(view, np.float64)
        i = np.asarray(light, np.float64)
        h = o + i
        h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
        co, ci = o[..., 2], i[..., 2]
        val = (fresnel_cook_torrance(np.sum(i * h, axis=-1), self.eta) * self.shadow_at(texels, co)
               * self.shadow_at(texels, ci) * self.ndf_at(texels, h[..., 2])
               / (np.pi * np.maximum(co, COS_FLOOR) * np.maximum(ci, COS_FLOOR)))
        return np.where((co > 0.0) & (ci > 0.0), val, 0.0)

    def sampling_lobes(self) -> tuple[np.ndarray, np.ndarray]:
        """Per texel (flat, row-major) the GGX alpha of its sampling lobe and the lobe's
        probability in the mixture (module docstring): two (texels,) float64 arrays."""
        if self._lobes is None:
            theta = (np.arange(_FIT_NODES) + 0.5) * (0.5 * np.pi / _FIT_NODES)
            c = np.cos(theta)
            w = 2.0 * np.pi * np.sin(theta) * (0.5 * np.pi / _FIT_NODES)
            h, wd = self.shape
            rc = np.stack(np.meshgrid(np.arange(h), np.arange(wd), indexing="ij"), -1).reshape(-1, 1, 2)
            target = self.ndf_at(np.broadcast_to(rc, (rc.shape[0], theta.size, 2)), c[None]) * c[None]
            mass = target @ w
            p = target / np.maximum(mass, 1e-300)[:, None]
            a2 = LOBE_ALPHAS[:, None] ** 2
            ggx = a2 / (np.pi * (c[None] ** 2 * (a2 - 1.0) + 1.0) ** 2) * c[None]  # (A, nodes), unit mass
            cost = (p**2 * w[None]) @ (1.0 / np.maximum(ggx, 1e-300)).T  # (texels, A)
            alpha = LOBE_ALPHAS[np.argmin(cost, axis=1)]
            alpha = np.where(mass > 0.0, alpha, 0.5)
            self._lobes = (alpha, np.full(alpha.shape, 1.0 - COSINE_WEIGHT))
        return self._lobes


def svbrdf_material(path_or_table) -> SVBRDFMaterial:
    """The :class:`SVBRDFMaterial` of a ``.svbrdf`` file (:func:`.svbrdf.read_svbrdf`) or of an
    :class:`.svbrdf.SVBRDFTable`."""
    table = path_or_table if isinstance(path_or_table, SVBRDFTable) else read_svbrdf(path_or_table)
    return SVBRDFMaterial(table.ndf, table.shadow, table.eta, table.path or "<array>")
