"""``svbrdf_rings.svbrdf`` -- a spatially varying measured material (Wang et al. 2009, sec. 4.2):
a texture of eq.-13 microfacet materials, written from analytic models (no measured SVBRDF can
be fetched here), for ``stages/dish_sg_svbrdf.toml`` (format: :mod:`warpshade.scene._svbrdf`).

Every texel is a blend of three eq.-13 materials (:data:`SVBRDF_MATERIALS`): a normalised Beckmann
NDF of slope ``m`` and the Smith shadowing factor of a Beckmann surface of slope ``s`` (the
rational Lambda), ``S = 1 / (1 + Lambda)``; the texel's ``D`` is the weighted sum of theirs
(:func:`svbrdf_weights`), its ``S`` the Smith factor of the weighted sum of their shadowing slopes
(so the curves are not a linear blend of three: the PCA has work to do). Over the dish's polar UVs (``u`` the azimuth, ``v`` the arc
length from the centre) the weights make concentric rings alternating between the polished and
the satin material (four per unit of ``v``), and a worn, strongly shadowing material in three
sectors of ``u`` that grows toward the rim. ``SVBRDF_SIZE`` texels, ``SVBRDF_SAMPLES`` polar angles
(one per degree), index 1.33: 745 kB. Written on request: ``python -m warpshade.usd_assets.generator
--scenes svbrdf``.

:func:`svbrdf_material` gives each texel's exact eq.-13 factors at any angles: the oracle of the
shading tests and benchmark (``benchmarks/bench_sg_svbrdf.py``).
"""

from __future__ import annotations

import os

import numpy as np

from ...scene._svbrdf import write_svbrdf

SVBRDF_FILE = "svbrdf_rings.svbrdf"
SVBRDF_SIZE = (32, 32)
SVBRDF_SAMPLES = 91
SVBRDF_ETA = 1.33
#: (Beckmann slope of the NDF, Beckmann slope of the Smith shadowing): polished, satin, worn.
SVBRDF_MATERIALS = ((0.08, 0.15), (0.22, 0.45), (0.38, 0.9))


def beckmann_ndf(theta_h, m: float) -> np.ndarray:
    """Normalised Beckmann NDF ``exp(-tan^2 / m^2) / (pi m^2 cos^4)`` at polar angles (radians)."""
    c = np.cos(np.minimum(np.asarray(theta_h, np.float64), 0.5 * np.pi - 1e-6))
    tan2 = (1.0 - c * c) / (c * c)
    return np.exp(-tan2 / m**2) / (np.pi * m**2 * c**4)


def smith_shadowing(theta, s: float) -> np.ndarray:
    """Smith shadowing ``1 / (1 + Lambda)`` of a Beckmann surface of slope ``s`` (rational Lambda), in [0, 1]."""
    tan = np.tan(np.minimum(np.asarray(theta, np.float64), 0.5 * np.pi - 1e-6))
    a = 1.0 / (s * np.maximum(tan, 1e-12))
    lam = np.where(a < 1.6, (1.0 - 1.259 * a + 0.396 * a * a) / (3.535 * a + 2.181 * a * a), 0.0)
    return np.clip(1.0 / (1.0 + np.maximum(lam, 0.0)), 0.0, 1.0)


def texel_uv(size=SVBRDF_SIZE) -> np.ndarray:
    """UV of every texel's centre, (H, W, 2): ``u = (c + 0.5) / W``, ``v = 1 - (r + 0.5) / H``."""
    h, w = size
    r, c = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    return np.stack([(c + 0.5) / w, 1.0 - (r + 0.5) / h], -1)


def svbrdf_weights(size=SVBRDF_SIZE) -> np.ndarray:
    """Blend weights of the three materials at every texel, (H, W, 3), summing to 1."""
    uv = texel_uv(size)
    u, v = uv[..., 0], uv[..., 1]
    ring = 0.5 + 0.5 * np.cos(2.0 * np.pi * 4.0 * v)  # 1: polished, 0: satin
    worn = np.clip(np.cos(2.0 * np.pi * 3.0 * u), 0.0, 1.0) ** 2 * np.clip(v, 0.0, 1.0) ** 2
    return np.stack([(1.0 - worn) * ring, (1.0 - worn) * (1.0 - ring), worn], -1)


def svbrdf_material(theta, size=SVBRDF_SIZE):
    """Exact ``D`` and ``S`` of every texel at polar angles ``theta`` (N,): two (H, W, N) arrays."""
    t = np.asarray(theta, np.float64).reshape(-1)
    wts = svbrdf_weights(size)
    d = sum(wts[..., j, None] * beckmann_ndf(t, m)[None, None] for j, (m, _) in enumerate(SVBRDF_MATERIALS))
    slope = sum(wts[..., j] * sh for j, (_, sh) in enumerate(SVBRDF_MATERIALS))
    s = smith_shadowing(t[None, None, :], slope[..., None])
    return d, np.clip(s, 0.0, 1.0)


def make_svbrdf(out_dir: str) -> str:
    theta = np.linspace(0.0, 0.5 * np.pi, SVBRDF_SAMPLES)
    d, s = svbrdf_material(theta)
    return str(write_svbrdf(os.path.join(out_dir, SVBRDF_FILE), d, s, SVBRDF_ETA))


def texel_material(row: int, col: int, size=SVBRDF_SIZE):
    """The exact ``(D, S)`` of one texel as callables of polar angles (radians)."""
    wts = svbrdf_weights(size)[int(row), int(col)]
    slope = float(sum(wts[j] * sh for j, (_, sh) in enumerate(SVBRDF_MATERIALS)))

    def ndf(theta):
        return sum(wts[j] * beckmann_ndf(theta, m) for j, (m, _) in enumerate(SVBRDF_MATERIALS))

    def shadow(theta):
        return np.clip(smith_shadowing(theta, slope), 0.0, 1.0)

    return ndf, shadow
