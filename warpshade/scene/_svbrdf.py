"""A texture of eq.-13 microfacet materials (Wang et al. 2009, sec. 4.2): the ``.svbrdf`` file,
the material it describes, and how a surface point finds its texel. Scene data, below both the
SG shading that fits it (:mod:`warpshade.methods.sg._svbrdf`) and the ray-traced reference that
shades it exactly (:mod:`warpshade.reference._svbrdf_warp`). Float64, but for the Warp texel
look-up :func:`nearest_texel`.

File (``.svbrdf``, little-endian; :func:`write_svbrdf`, :func:`read_svbrdf`): the 8 bytes
``WSSVBRDF``, then uint32 ``version`` (1), ``height``, ``width``, ``samples``, float32 ``eta``,
then float32 ``D`` (height, width, samples) and float32 ``S`` (height, width, samples), both
sampled at ``samples`` uniform polar angles over [0, pi/2] (ends included; the bundled texture
has 91, one per degree -- the paper's "90-D" shadowing vectors). Row 0 is the top of the texture
(``v = 1``), as the image textures of :mod:`warpshade.scene._textures`. ``D >= 0`` (1/sr, with
F, S and the cosines taken out), ``S`` in [0, 1].

Look-up: at a surface point the texel is the nearest one of the point's UV (``u`` repeats, ``v``
is clamped, row 0 at ``v = 1``): :func:`nearest_texel` on the device, :func:`nearest_texel_f64`
its float64 mirror; per-vertex UVs of the scene's meshes: :func:`scene_uvs`.

Material (:class:`SVBRDFMaterial`): the texel's BRDF is eq. 13 with the file's curves,
``rho(o, i) = F(|i.h|, eta) S(theta_o) S(theta_i) D(theta_h) / (pi max(n.i, c) max(n.o, c))``
(``c`` = :data:`SVBRDF_COS_FLOOR`), 0 below either horizon, ``F`` the unpolarised dielectric
Fresnel reflectance (:func:`fresnel_dielectric`), with the curves read between their samples
(uniform in theta over [0, pi/2]) as:

* ``S``: linearly in theta between the two samples around the angle;
* ``D``: geometrically in ``cos theta_h`` between the two samples around ``theta_h`` (``log D``
  linear in the cosine; linearly where either sample is 0). It is exact for one SG lobe about the
  normal, the shape the SG shading fits; on the bundled texture's sharpest Beckmann lobe (slope
  0.08, one sample per degree) it is within 1e-4 of the analytic NDF where linear
  interpolation in theta is 1e-2 off (relative to the peak).

Sampling (for unbiased Monte Carlo estimators): each texel gets a GGX lobe of half vectors, its
alpha the one of :data:`LOBE_ALPHAS` whose half-vector density is closest to the texel's
normalised ``D(h) cos theta_h`` in the chi-square sense (the variance of estimating ``integral D
cos`` with it), mixed with the cosine lobe with probability :data:`COSINE_WEIGHT`: the mixture of
:mod:`warpshade.scene._materials_warp`'s tabulated model, positive wherever the BRDF can be.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._fileio import atomic_path
from .._hashing import hash_arrays
from .._wp import wp
from ._materials import BRDF

wp.set_module_options({"enable_backward": False})

__all__ = [
    "COSINE_WEIGHT",
    "LOBE_ALPHAS",
    "MAGIC",
    "MAX_SAMPLES",
    "MAX_SIDE",
    "SVBRDF_COS_FLOOR",
    "SVBRDFMaterial",
    "SVBRDFTable",
    "fresnel_dielectric",
    "nearest_texel",
    "nearest_texel_f64",
    "read_svbrdf",
    "scene_uvs",
    "svbrdf_material",
    "write_svbrdf",
]

MAGIC = b"WSSVBRDF"
VERSION = 1
_HEADER = 8 + 4 * 4 + 4
#: Largest texture side and samples per curve a file may declare (a corrupt header is refused
#: before any allocation).
MAX_SIDE = 4096
MAX_SAMPLES = 4096
#: The floor of the cosines in eq. 13's denominator (a texel's BRDF stays finite at grazing angles).
SVBRDF_COS_FLOOR = 1e-6


@dataclass
class SVBRDFTable:
    """A texture of eq.-13 materials as stored: ``ndf`` and ``shadow`` (H, W, N) at ``theta``."""

    ndf: np.ndarray
    shadow: np.ndarray
    eta: float
    path: str = ""

    @property
    def theta(self) -> np.ndarray:
        return np.linspace(0.0, 0.5 * np.pi, self.ndf.shape[2])

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.ndf.shape[0]), int(self.ndf.shape[1])


def _check_table(ndf, shadow, eta, where: str):
    d = np.asarray(ndf, np.float64)
    s = np.asarray(shadow, np.float64)
    if d.ndim != 3 or s.shape != d.shape:
        raise ValueError(f"{where}: ndf and shadow must be (height, width, samples) of one shape, got {d.shape}, {s.shape}")
    h, w, n = d.shape
    if not (1 <= h <= MAX_SIDE and 1 <= w <= MAX_SIDE and 4 <= n <= MAX_SAMPLES):
        raise ValueError(f"{where}: size {h} x {w} with {n} samples is outside 1..{MAX_SIDE} texels, 4..{MAX_SAMPLES} samples")
    if not np.all(np.isfinite(d)) or np.any(d < 0.0):
        bad = np.argwhere(~np.isfinite(d) | (d < 0.0))[0]
        raise ValueError(f"{where}: NDF values must be finite and >= 0 (texel row {bad[0]}, column {bad[1]})")
    if not np.all(np.isfinite(s)) or np.any(s < 0.0) or np.any(s > 1.0):
        bad = np.argwhere(~np.isfinite(s) | (s < 0.0) | (s > 1.0))[0]
        raise ValueError(f"{where}: shadowing values must be finite and in [0, 1] (texel row {bad[0]}, column {bad[1]})")
    e = float(eta)
    if not (np.isfinite(e) and 1.0 < e <= 10.0):
        raise ValueError(f"{where}: eta must be in (1, 10], got {eta!r}")
    return d, s, e


def write_svbrdf(path, ndf, shadow, eta: float = 1.33) -> Path:
    """Write a texture of eq.-13 materials (module docstring), atomically; returns the path."""
    path = Path(path)
    d, s, e = _check_table(ndf, shadow, eta, f"write_svbrdf: {path}")
    h, w, n = d.shape
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(MAGIC)
            f.write(np.array([VERSION, h, w, n], "<u4").tobytes())
            f.write(np.array([e], "<f4").tobytes())
            f.write(np.ascontiguousarray(d, "<f4").tobytes())
            f.write(np.ascontiguousarray(s, "<f4").tobytes())
    return path


def read_svbrdf(path) -> SVBRDFTable:
    """Read a ``.svbrdf`` file (module docstring).

    Raises:
        ValueError: naming the file, when it is missing, not a file, not of this format or
            version, of a size other than its header says, or holds values out of range.
    """
    path = Path(path)
    where = f"SVBRDF texture {str(path)!r}"
    if not path.is_file():
        raise ValueError(f"{where}: no such file")
    raw = path.read_bytes()
    if len(raw) < _HEADER or raw[:8] != MAGIC:
        raise ValueError(f"{where}: not an SVBRDF texture (expected the {MAGIC.decode()} header)")
    version, h, w, n = (int(x) for x in np.frombuffer(raw, "<u4", 4, 8))
    if version != VERSION:
        raise ValueError(f"{where}: version {version}, this reader knows {VERSION}")
    if not (1 <= h <= MAX_SIDE and 1 <= w <= MAX_SIDE and 4 <= n <= MAX_SAMPLES):
        raise ValueError(f"{where}: header size {h} x {w} with {n} samples is outside 1..{MAX_SIDE}, 4..{MAX_SAMPLES}")
    eta = float(np.frombuffer(raw, "<f4", 1, 24)[0])
    count = h * w * n
    want = _HEADER + 2 * 4 * count
    if len(raw) != want:
        raise ValueError(f"{where}: {len(raw)} bytes, the header ({h} x {w} x {n}) needs {want}")
    d = np.frombuffer(raw, "<f4", count, _HEADER).reshape(h, w, n).astype(np.float64)
    s = np.frombuffer(raw, "<f4", count, _HEADER + 4 * count).reshape(h, w, n).astype(np.float64)
    d, s, eta = _check_table(d, s, eta, where)
    return SVBRDFTable(d, s, eta, str(path))


def scene_uvs(scene) -> np.ndarray:
    """The per-vertex UVs of all the scene's meshes, concatenated in scene order, (V, 2) float64;
    ValueError naming a mesh without UVs, or for non-finite UVs."""
    missing = [m.path for m in scene.meshes if m.uvs is None]
    if missing:
        raise ValueError(f"the texture is looked up at the meshes' UVs; {missing[0]} has none")
    uv = np.concatenate([np.asarray(m.uvs, np.float64).reshape(-1, 2) for m in scene.meshes])
    if not np.all(np.isfinite(uv)):
        raise ValueError("the meshes' UVs must be finite")
    return uv

def fresnel_dielectric(cos_theta, eta) -> np.ndarray:
    """Unpolarised Fresnel reflectance of a dielectric interface, from its s- and p-polarised
    amplitude ratios: with ``cos_t = sqrt(1 - (1 - c^2) / eta^2)`` (Snell's law),
    ``r_s = (c - eta cos_t) / (c + eta cos_t)``, ``r_p = (eta c - cos_t) / (eta c + cos_t)`` and
    ``F = (r_s^2 + r_p^2) / 2``; ``F(1) = ((eta - 1) / (eta + 1))^2``, ``F(0) = 1``.

    Args:
        cos_theta: cosine of the angle of incidence (its absolute value, clipped to [0, 1]).
        eta: relative index of refraction, > 1 (broadcast with ``cos_theta``).
    """
    c = np.clip(np.abs(np.asarray(cos_theta, np.float64)), 0.0, 1.0)
    eta = np.asarray(eta, np.float64)
    if np.any(~np.isfinite(eta)) or np.any(eta <= 1.0):
        raise ValueError(f"fresnel_dielectric: eta must be finite and > 1, got {eta!r}")
    cos_t = np.sqrt(1.0 - (1.0 - c * c) / (eta * eta))
    r_s = (c - eta * cos_t) / (c + eta * cos_t)
    r_p = (eta * c - cos_t) / (eta * c + cos_t)
    return 0.5 * (r_s * r_s + r_p * r_p)


@wp.func
def nearest_texel(uv: wp.vec2, height: int, width: int) -> wp.vec2i:
    """Nearest texel (row, column) of ``uv`` in a ``height`` x ``width`` texture: u repeats, v is clamped."""
    u = uv[0] - wp.floor(uv[0])
    x = wp.clamp(u * float(width), 0.0, float(width) - 1.0)
    y = wp.clamp((1.0 - uv[1]) * float(height), 0.0, float(height) - 1.0)
    return wp.vec2i(wp.clamp(int(wp.floor(y)), 0, height - 1), wp.clamp(int(wp.floor(x)), 0, width - 1))


def nearest_texel_f64(uv, shape) -> np.ndarray:
    """Float64 mirror of :func:`nearest_texel`: the texels (row, column) of UVs (..., 2) in a texture
    of ``shape`` (height, width), int64 (..., 2)."""
    uv = np.asarray(uv, np.float64)
    h, w = (int(n) for n in shape)
    u = uv[..., 0] - np.floor(uv[..., 0])
    col = np.clip(np.floor(u * w), 0, w - 1).astype(np.int64)
    row = np.clip(np.floor(np.clip((1.0 - uv[..., 1]) * h, 0.0, h - 1.0)), 0, h - 1).astype(np.int64)
    return np.stack([row, col], -1)


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
    :class:`~warpshade.scene._materials.BRDF` has no texel and refuses.
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
        val = (fresnel_dielectric(np.sum(i * h, axis=-1), self.eta) * self.shadow_at(texels, co)
               * self.shadow_at(texels, ci) * self.ndf_at(texels, h[..., 2])
               / (np.pi * np.maximum(co, SVBRDF_COS_FLOOR) * np.maximum(ci, SVBRDF_COS_FLOOR)))
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
    """The :class:`SVBRDFMaterial` of a ``.svbrdf`` file (:func:`read_svbrdf`) or of an
    :class:`SVBRDFTable`."""
    table = path_or_table if isinstance(path_or_table, SVBRDFTable) else read_svbrdf(path_or_table)
    return SVBRDFMaterial(table.ndf, table.shadow, table.eta, table.path or "<array>")
