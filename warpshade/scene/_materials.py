"""BRDF models and their view/light factorisation in the SH lighting basis (float64 mirrors).

Frame and conventions: BRDFs are evaluated in a local shading frame whose +z is the surface
normal; ``view`` (towards the viewer) and ``light`` (towards the light) are unit vectors, and
``evaluate(view, light)`` returns ``b(v, s)`` in 1/sr *without* the cosine factor; it is 0 when
either direction is below the horizon. Outgoing radiance under distant radiance ``L`` is
``r(v) = integral_H b(v, s) L(s) s_z ds``.

Models: :class:`Lambert`, :class:`Phong` (energy-normalised modified Phong about the mirror
direction), :class:`BlinnPhong` (normalised, about the half vector), :class:`Microfacet`
(Cook-Torrance: Beckmann or GGX distribution, Smith shadowing-masking, Schlick Fresnel, with a
``glossiness`` parameter).

View/light factorisation (Sloan, Luna, Snyder 2005, eq. 14-16; also used by
reflectance-product-operator methods): sample the BRDF at ``nv`` view directions and build::

    B_ij = integral_H b(v_i, s) y_j(s) s_z ds                 (nv x n^2, eq. 14)
    B = U S V  ~  U~ S~ V~     (the n_b largest singular values)

so that for lighting SH ``e`` (local frame) ``r(v) ~ u(v) . (V~ e)`` with the view factors
``u(v) = gamma(v)^T U~ S~`` (``gamma`` interpolates between view samples) and ``V~`` the
n_b x n^2 "BRDF-specialised" rows. View samples lie on a square grid mapped to the hemisphere by
Shirley and Chiu's concentric square-to-disk map followed by the area-preserving disk-to-
hemisphere map, and ``gamma`` is bilinear on that square (the paper's 32 x 32 texture).
:func:`factorize` returns a :class:`BRDFFactorization`; :func:`shade_unshadowed` is the
brute-force quadrature reference of ``r(v)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..basis import sh

__all__ = [
    "BRDF",
    "AnisotropicMicrofacet",
    "BRDFFactorization",
    "BlinnPhong",
    "Lambert",
    "Microfacet",
    "Phong",
    "brdf_matrix",
    "concentric_to_hemisphere",
    "factorize",
    "hemisphere_quadrature",
    "hemisphere_to_concentric",
    "resolved_exponent",
    "shade_unshadowed",
    "view_grid",
]


def _unit(v, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    if a.shape[-1:] != (3,):
        raise ValueError(f"{name}: expected directions of shape (..., 3), got {a.shape}")
    n = np.linalg.norm(a, axis=-1, keepdims=True)
    if np.any(n == 0.0) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: directions must be finite and nonzero")
    return a / n


class BRDF:
    """Base class: ``evaluate(view, light)`` -> b (broadcast shape), float64, local frame."""

    name = "brdf"

    def evaluate(self, view, light) -> np.ndarray:
        v = _unit(view, f"{self.name}: view")
        s = _unit(light, f"{self.name}: light")
        v, s = np.broadcast_arrays(v, s)
        above = (v[..., 2] > 0.0) & (s[..., 2] > 0.0)
        return np.where(above, self._eval(v, s), 0.0)

    def _eval(self, v: np.ndarray, s: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def describe(self) -> dict:
        return {"model": self.name, **{k: v for k, v in vars(self).items() if not k.startswith("_")}}

    def color_channels(self) -> tuple | None:
        """Three single-channel BRDFs (red, green, blue) when the BRDF's shape differs per colour
        channel (a coloured measured table), else None: one BRDF for all three channels, times
        the shader's RGB colour."""
        return None

    def lobe_exponent(self) -> float:
        """The Phong exponent of a lobe about the mirror direction as sharp as this BRDF's
        (0: no lobe), what :func:`brdf_matrix` compares with what its quadrature resolves."""
        return 0.0


def _check(model: str, **values) -> None:
    """Raise ValueError naming the first value that is not a finite number >= 0."""
    for name, value in values.items():
        if not (isinstance(value, (int, float, np.floating, np.integer)) and np.isfinite(value) and value >= 0.0):
            raise ValueError(f"{model}: {name} must be a finite number >= 0, got {value!r}")


@dataclass
class Lambert(BRDF):
    """``b = albedo / pi``."""

    albedo: float = 1.0
    name = "lambert"

    def __post_init__(self):
        _check("Lambert", albedo=self.albedo)

    def _eval(self, v, s):
        return np.full(v.shape[:-1], self.albedo / np.pi)


@dataclass
class Phong(BRDF):
    """Energy-normalised modified Phong: ``b = ks (p + 2) / (2 pi) max(0, r . s)^p``, r the mirror
    direction of the view (``(-v_x, -v_y, v_z)``); directional albedo <= ks."""

    exponent: float = 20.0
    specular: float = 1.0
    name = "phong"

    def __post_init__(self):
        _check("Phong", exponent=self.exponent, specular=self.specular)

    def lobe_exponent(self) -> float:
        return float(self.exponent)

    def _eval(self, v, s):
        r = v * np.array([-1.0, -1.0, 1.0])
        c = np.maximum(np.sum(r * s, axis=-1), 0.0)
        return self.specular * (self.exponent + 2.0) / (2.0 * np.pi) * c**self.exponent


@dataclass
class BlinnPhong(BRDF):
    """Normalised Blinn-Phong: ``b = ks (p + 8) / (8 pi) max(0, n . h)^p``, h the half vector."""

    exponent: float = 50.0
    specular: float = 1.0
    name = "blinn-phong"

    def __post_init__(self):
        _check("BlinnPhong", exponent=self.exponent, specular=self.specular)

    def lobe_exponent(self) -> float:
        return float(self.exponent) / 4.0  # about the half vector: half the angle of the mirror lobe

    def _eval(self, v, s):
        h = v + s
        h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
        return self.specular * (self.exponent + 8.0) / (8.0 * np.pi) * np.maximum(h[..., 2], 0.0) ** self.exponent


@dataclass
class Microfacet(BRDF):
    """Cook-Torrance microfacet BRDF ``b = D(h) F(v.h) G(v, s) / (4 (n.v) (n.s))``.

    Attributes:
        roughness: the distribution's slope parameter alpha (Beckmann m or GGX alpha), > 0.
        distribution: "beckmann" (Cook and Torrance 1982) or "ggx" (Walter et al. 2007).
        f0: Fresnel reflectance at normal incidence (Schlick's approximation).
        specular: overall scale.

    Shadowing-masking: Smith's separable form with each distribution's own Lambda.
    ``Microfacet.from_glossiness(g)`` sets ``roughness = 1 - g`` (g in [0, 1); this project's
    convention for "glossiness").
    """

    roughness: float = 0.3
    distribution: str = "ggx"
    f0: float = 0.04
    specular: float = 1.0
    name = "microfacet"

    def __post_init__(self):
        if self.distribution not in ("beckmann", "ggx"):
            raise ValueError(f"Microfacet: distribution must be 'beckmann' or 'ggx', got {self.distribution!r}")
        if not 0.0 < self.roughness <= 2.0:
            raise ValueError(f"Microfacet: roughness must be in (0, 2], got {self.roughness!r}")
        if not 0.0 <= self.f0 <= 1.0:
            raise ValueError(f"Microfacet: f0 must be in [0, 1], got {self.f0!r}")
        _check("Microfacet", specular=self.specular)

    def lobe_exponent(self) -> float:
        # D ~ exp(-theta_h^2 / alpha^2) about the half vector, theta_h half the mirror angle
        return 1.0 / (2.0 * float(self.roughness) ** 2)

    @classmethod
    def from_glossiness(cls, glossiness: float, **kwargs) -> Microfacet:
        if not 0.0 <= glossiness < 1.0:
            raise ValueError(f"Microfacet.from_glossiness: glossiness must be in [0, 1), got {glossiness!r}")
        return cls(roughness=1.0 - glossiness, **kwargs)

    def _d(self, cos_h):
        a2 = self.roughness**2
        c2 = np.clip(cos_h, 1e-12, 1.0) ** 2
        if self.distribution == "ggx":
            return a2 / (np.pi * (c2 * (a2 - 1.0) + 1.0) ** 2)
        tan2 = (1.0 - c2) / c2
        return np.exp(-tan2 / a2) / (np.pi * a2 * c2 * c2)

    def _lambda(self, cos_w):
        c = np.clip(cos_w, 1e-12, 1.0)
        tan2 = (1.0 - c * c) / (c * c)
        if self.distribution == "ggx":
            return 0.5 * (np.sqrt(1.0 + self.roughness**2 * tan2) - 1.0)
        a = 1.0 / (self.roughness * np.sqrt(np.maximum(tan2, 1e-300)))
        rational = (1.0 - 1.259 * a + 0.396 * a * a) / (3.535 * a + 2.181 * a * a)
        return np.where(a < 1.6, rational, 0.0)

    def _eval(self, v, s):
        h = v + s
        h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
        vh = np.clip(np.sum(v * h, axis=-1), 0.0, 1.0)
        fresnel = self.f0 + (1.0 - self.f0) * (1.0 - vh) ** 5
        g = 1.0 / ((1.0 + self._lambda(v[..., 2])) * (1.0 + self._lambda(s[..., 2])))
        denom = 4.0 * np.maximum(v[..., 2], 1e-12) * np.maximum(s[..., 2], 1e-12)
        return self.specular * self._d(h[..., 2]) * fresnel * g / denom


@dataclass
class AnisotropicMicrofacet(BRDF):
    """Anisotropic Beckmann microfacet BRDF ``b = D(h) F(v.h) G(v, s) / (4 (n.v) (n.s))`` in the
    local frame (+x the tangent):
    ``D(h) = exp(-(h_x^2 / a_x^2 + h_y^2 / a_y^2) / h_z^2) / (pi a_x a_y h_z^4)``, Schlick's
    Fresnel with ``f0``, and Smith's separable masking with the Beckmann rational Lambda of the
    direction's projected roughness ``alpha(w) = sqrt(w_x^2 a_x^2 + w_y^2 a_y^2) / sin(theta)``
    (what Mitsuba 3's ``roughconductor`` with ``alpha_u = a_x``, ``alpha_v = a_y`` evaluates).

    Attributes:
        roughness: ``a_x``, slope parameter along the tangent, in (0, 2].
        roughness_y: ``a_y``, along the bitangent, in (0, 2].
        f0: Fresnel reflectance at normal incidence; specular: overall scale.
    """

    roughness: float = 0.1
    roughness_y: float = 0.4
    f0: float = 0.04
    specular: float = 1.0
    name = "beckmann-anisotropic"

    def __post_init__(self):
        for key in ("roughness", "roughness_y"):
            value = getattr(self, key)
            if not (isinstance(value, (int, float, np.floating, np.integer)) and 0.0 < value <= 2.0):
                raise ValueError(f"AnisotropicMicrofacet: {key} must be in (0, 2], got {value!r}")
        if not 0.0 <= self.f0 <= 1.0:
            raise ValueError(f"AnisotropicMicrofacet: f0 must be in [0, 1], got {self.f0!r}")
        _check("AnisotropicMicrofacet", specular=self.specular)

    def lobe_exponent(self) -> float:
        return 1.0 / (2.0 * float(min(self.roughness, self.roughness_y)) ** 2)

    def _d(self, h):
        z2 = np.clip(h[..., 2], 1e-12, 1.0) ** 2
        q = (h[..., 0] ** 2 / self.roughness**2 + h[..., 1] ** 2 / self.roughness_y**2) / z2
        return np.where(h[..., 2] > 0.0, np.exp(-q) / (np.pi * self.roughness * self.roughness_y * z2 * z2), 0.0)

    def _lambda(self, w):
        c = np.clip(w[..., 2], 1e-12, 1.0)
        s2 = np.maximum(1.0 - c * c, 1e-300)
        alpha = np.sqrt((w[..., 0] ** 2 * self.roughness**2 + w[..., 1] ** 2 * self.roughness_y**2) / s2)
        a = c / (alpha * np.sqrt(s2))
        rational = (1.0 - 1.259 * a + 0.396 * a * a) / (3.535 * a + 2.181 * a * a)
        return np.where(a < 1.6, rational, 0.0)

    def _eval(self, v, s):
        h = v + s
        h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
        vh = np.clip(np.sum(v * h, axis=-1), 0.0, 1.0)
        fresnel = self.f0 + (1.0 - self.f0) * (1.0 - vh) ** 5
        g = 1.0 / ((1.0 + self._lambda(v)) * (1.0 + self._lambda(s)))
        denom = 4.0 * np.maximum(v[..., 2], 1e-12) * np.maximum(s[..., 2], 1e-12)
        return self.specular * self._d(h) * fresnel * g / denom


# ---- quadrature and the view parameterisation -------------------------------------------------


def hemisphere_quadrature(z_nodes: int = 48, phi_nodes: int = 96):
    """Gauss-Legendre in ``z = cos(theta)`` on [0, 1] times uniform azimuths: (dirs (K, 3), w (K,)),
    float64, weights sum to 2 pi. Exact for polynomials in z of degree < 2 z_nodes."""
    x, wx = np.polynomial.legendre.leggauss(int(z_nodes))
    z = 0.5 * (x + 1.0)
    wz = 0.5 * wx
    phi = (np.arange(phi_nodes) + 0.5) * (2.0 * np.pi / phi_nodes)
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    r = np.sqrt(np.maximum(0.0, 1.0 - zz * zz))
    dirs = np.stack([r * np.cos(pp), r * np.sin(pp), zz], -1).reshape(-1, 3)
    return dirs, np.repeat(wz * (2.0 * np.pi / phi_nodes), phi_nodes)


def concentric_to_hemisphere(ab) -> np.ndarray:
    """Square [-1, 1]^2 -> unit upper hemisphere: Shirley-Chiu concentric map to the disk, then the
    area-preserving lift ``z = 1 - r^2``, ``(x, y) = d sqrt(2 - r^2)``. Shape (..., 2) -> (..., 3)."""
    ab = np.asarray(ab, dtype=np.float64)
    a, b = ab[..., 0], ab[..., 1]
    use_a = np.abs(a) > np.abs(b)
    r = np.where(use_a, a, b)
    safe_a = np.where(a == 0.0, 1.0, a)
    safe_b = np.where(b == 0.0, 1.0, b)
    phi = np.where(use_a, (np.pi / 4.0) * (b / safe_a), (np.pi / 2.0) - (np.pi / 4.0) * (a / safe_b))
    phi = np.where((a == 0.0) & (b == 0.0), 0.0, phi)
    dx, dy = r * np.cos(phi), r * np.sin(phi)
    rr = dx * dx + dy * dy
    k = np.sqrt(np.maximum(2.0 - rr, 0.0))
    return np.stack([dx * k, dy * k, 1.0 - rr], axis=-1)


def hemisphere_to_concentric(dirs) -> np.ndarray:
    """Inverse of :func:`concentric_to_hemisphere` (directions below the horizon are clamped to
    it). Shape (..., 3) -> (..., 2) in [-1, 1]^2."""
    d = _unit(dirs, "hemisphere_to_concentric")
    z = np.clip(d[..., 2], 0.0, 1.0)
    r = np.sqrt(1.0 - z)
    phi = np.arctan2(d[..., 1], d[..., 0])
    phi = np.where(phi < -np.pi / 4.0, phi + 2.0 * np.pi, phi)  # into [-pi/4, 7pi/4)
    a = np.empty_like(r)
    b = np.empty_like(r)
    sec = [(-np.inf, np.pi / 4), (np.pi / 4, 3 * np.pi / 4), (3 * np.pi / 4, 5 * np.pi / 4), (5 * np.pi / 4, np.inf)]
    for k, (lo, hi) in enumerate(sec):
        m = (phi >= lo) & (phi < hi)
        if k == 0:
            a[m], b[m] = r[m], r[m] * phi[m] / (np.pi / 4)
        elif k == 1:
            b[m], a[m] = r[m], r[m] * (np.pi / 2 - phi[m]) / (np.pi / 4)
        elif k == 2:
            a[m], b[m] = -r[m], -r[m] * (phi[m] - np.pi) / (np.pi / 4)
        else:
            b[m], a[m] = -r[m], -r[m] * (3 * np.pi / 2 - phi[m]) / (np.pi / 4)
    return np.stack([a, b], axis=-1)


def view_grid(resolution: int) -> np.ndarray:
    """View directions at the texel centres of a ``resolution x resolution`` texture over
    [-1, 1]^2 (``(i + 0.5) / res * 2 - 1``; the boundary, which maps to the horizon, is never a
    sample), row-major (a first), mapped to the hemisphere, shape (res^2, 3)."""
    if resolution < 2:
        raise ValueError(f"view_grid: resolution must be >= 2, got {resolution}")
    g = (np.arange(resolution) + 0.5) / resolution * 2.0 - 1.0
    a, b = np.meshgrid(g, g, indexing="ij")
    return concentric_to_hemisphere(np.stack([a.ravel(), b.ravel()], -1))


def resolved_exponent(z_nodes: int, phi_nodes: int) -> float:
    """The sharpest lobe (as a Phong exponent, :meth:`BRDF.lobe_exponent`) the hemisphere
    quadrature of :func:`brdf_matrix` still integrates: the lobe's angular width ``1/sqrt(p)``
    against the node spacing. Measured at 48 x 96 nodes (limit 4096), a Phong lobe keeps 93 % of
    its directional albedo at normal view at p = 2000, 75 % at 3000, 36 % at 5000 and under 4 %
    at 10000: past the limit it shades nearly black."""
    return 4.0 * (min(2 * int(z_nodes), int(phi_nodes)) / 3.0) ** 2


def brdf_matrix(brdf: BRDF, order: int, views, z_nodes: int = 48, phi_nodes: int = 96, cosine: bool = True) -> np.ndarray:
    """The sampled B matrix of eq. 14, ``B_ij = integral_H b(v_i, s) y_j(s) s_z ds`` (float64).

    Args:
        brdf: a :class:`BRDF`. order: SH order n. views: (nv, 3) unit view directions.
        z_nodes, phi_nodes: the hemisphere quadrature (:func:`hemisphere_quadrature`).
        cosine: weight by ``s_z`` (default); False tabulates the BRDF alone (the cosine is then
            applied elsewhere, e.g. as a product matrix).

    Returns:
        shape (nv, n*n).

    Raises:
        ValueError: a lobe sharper than the quadrature resolves (:func:`resolved_exponent`):
            sampled, it would integrate to nearly nothing and shade black.
    """
    sharpest = resolved_exponent(z_nodes, phi_nodes)
    if brdf.lobe_exponent() > sharpest:
        values = {k: v for k, v in brdf.describe().items() if k in ("exponent", "roughness")}
        raise ValueError(f"{brdf.name} BRDF {values}: its lobe is sharper than the {z_nodes} x {phi_nodes} hemisphere "
                         f"quadrature resolves (at most a Phong exponent of {sharpest:.0f}, a Blinn-Phong exponent of "
                         f"{4 * sharpest:.0f}, a microfacet roughness of {np.sqrt(0.5 / sharpest):.3g}); it would "
                         "shade black")
    dirs, w = hemisphere_quadrature(z_nodes, phi_nodes)
    y = sh.basis(dirs, order) * (w * (dirs[:, 2] if cosine else 1.0))[:, None]
    v = _unit(views, "brdf_matrix: views")
    out = np.empty((v.shape[0], order * order))
    step = max(1, 4_000_000 // max(1, dirs.shape[0]))
    for i in range(0, v.shape[0], step):
        vals = brdf.evaluate(v[i : i + step, None, :], dirs[None, :, :])
        out[i : i + step] = vals @ y
    return out


@dataclass
class BRDFFactorization:
    """A BRDF's view/light factorisation ``B ~ U~ S~ V~`` (eq. 14-15), float64.

    Attributes:
        order: SH order n of the lighting.
        resolution: view grid size (res x res nodes on the concentric square).
        view_factors: ``U~ S~`` at the grid nodes, shape (res, res, n_b).
        rows: ``V~``, the BRDF-specialised rows, shape (n_b, n*n).
        singular_values: all singular values of B, descending, shape (min(nv, n*n),).
        brdf: description of the BRDF.
    """

    order: int
    resolution: int
    view_factors: np.ndarray
    rows: np.ndarray
    singular_values: np.ndarray
    brdf: dict

    @property
    def rank(self) -> int:
        return int(self.rows.shape[0])

    def truncation_error(self) -> float:
        """Relative Frobenius error of the truncated B: ``sqrt(sum_{k>n_b} s_k^2 / sum s_k^2)``."""
        s2 = self.singular_values**2
        return float(np.sqrt(s2[self.rank :].sum() / max(s2.sum(), 1e-300)))

    def view_factors_at(self, views) -> np.ndarray:
        """``u(v)`` by bilinear interpolation between texel centres on the concentric square
        (clamped to the outermost centres), (..., n_b); local-frame views below the horizon are
        clamped to it."""
        ab = hemisphere_to_concentric(views)
        res = self.resolution
        f = (ab + 1.0) * 0.5 * res - 0.5
        i0 = np.clip(np.floor(f).astype(np.int64), 0, res - 2)
        t = np.clip(f - i0, 0.0, 1.0)
        u = self.view_factors
        a0, b0 = i0[..., 0], i0[..., 1]
        ta, tb = t[..., 0:1], t[..., 1:2]
        return ((1 - ta) * (1 - tb) * u[a0, b0] + ta * (1 - tb) * u[a0 + 1, b0]
                + (1 - ta) * tb * u[a0, b0 + 1] + ta * tb * u[a0 + 1, b0 + 1])

    def shade(self, views, light_local) -> np.ndarray:
        """Unshadowed ``r(v) = u(v) . (V~ e)`` for local-frame lighting SH e (n*n,) or (C, n*n);
        returns (...,) or (..., C)."""
        e = np.asarray(light_local, dtype=np.float64)
        return self.view_factors_at(views) @ (self.rows @ e.T)


def factorize(brdf: BRDF, order: int, rank: int, resolution: int = 32, z_nodes: int = 48,
              phi_nodes: int = 96, matrix=None, cosine: bool = True) -> BRDFFactorization:
    """SVD of the sampled B matrix keeping ``rank`` (n_b) singular values (eq. 14-15).

    Args:
        brdf: the BRDF. order: SH order n. rank: n_b (1..n*n).
        resolution: view grid texels per side (the paper: 32).
        z_nodes, phi_nodes: hemisphere quadrature of the light integral.
        matrix: a B matrix already computed by :func:`brdf_matrix` on ``view_grid(resolution)``
            (to factorise one BRDF at several ranks without re-sampling it).
        cosine: factorise the cosine-weighted BRDF (default) or the BRDF alone (:func:`brdf_matrix`).
    """
    n2 = order * order
    if not 1 <= rank <= n2:
        raise ValueError(f"factorize: rank n_b must be in 1..{n2}, got {rank}")
    if matrix is None:
        b = brdf_matrix(brdf, order, view_grid(resolution), z_nodes, phi_nodes, cosine)
    else:
        b = np.asarray(matrix, dtype=np.float64)
        if b.shape != (resolution * resolution, n2):
            raise ValueError(f"factorize: matrix must have shape ({resolution * resolution}, {n2}), got {b.shape}")
    u, s, vt = np.linalg.svd(b, full_matrices=False)
    # fix the sign of each singular pair (largest |entry| of the row positive) for reproducibility
    sign = np.sign(vt[np.arange(vt.shape[0]), np.argmax(np.abs(vt), axis=1)])
    sign[sign == 0] = 1.0
    u, vt = u * sign, vt * sign[:, None]
    factors = (u[:, :rank] * s[:rank]).reshape(resolution, resolution, rank)
    return BRDFFactorization(order, resolution, factors, vt[:rank].copy(), s, brdf.describe())


def shade_unshadowed(brdf: BRDF, views, radiance_fn, z_nodes: int = 96, phi_nodes: int = 192) -> np.ndarray:
    """Brute-force reference ``r(v) = integral_H b(v, s) L(s) s_z ds`` by quadrature (float64).

    Args:
        views: (K, 3) local view directions. radiance_fn: callable (M, 3) -> (M,) or (M, C).

    Returns:
        (K,) or (K, C).
    """
    dirs, w = hemisphere_quadrature(z_nodes, phi_nodes)
    radiance = np.asarray(radiance_fn(dirs), dtype=np.float64)
    vals = brdf.evaluate(_unit(views, "shade_unshadowed: views")[:, None, :], dirs[None, :, :])
    return (vals * (w * dirs[:, 2])) @ radiance

