"""Float64 mirror of the SG/SSDF shading kernels (:mod:`._kernels`): the tests' oracle.

:func:`shade_f64` evaluates eq. 39, 41, 42 and 43 at receivers with NumPy from the same
inputs the kernel reads (decoded SSDF maps, tangent frames, the environment's SG mixture and
prefiltered table, sphere lights and distant-light lobes), one receiver at a time. Visibility is
looked up per vertex in that vertex's frame and blended with the barycentric weights, as the
kernel does.
"""

from __future__ import annotations

import numpy as np

from ...basis import sg
from ...scene._materials import hemisphere_to_concentric
from ._brdf_warp import slice_parameters
from ._lights import point_light_lobe
from ._slices import duff_frame_f64, view_slice

__all__ = [
    "ssdf_value",
    "tangent_frame_f64",
    "warped_slices_f64",
]


def tangent_frame_f64(n, tangent) -> np.ndarray:
    """Rows (t, n x t, n): ``tangent`` projected on the tangent plane of the unit normal ``n`` and
    normalised (the orthonormal-basis tangent where it is parallel to ``n``), as
    :func:`warpshade.scene._materials_warp.tangent_frame`."""
    n = np.asarray(n, np.float64)
    t = np.asarray(tangent, np.float64)
    t = t - (t @ n) * n
    length = np.linalg.norm(t)
    t = t / length if length > 1e-6 else duff_frame_f64(n)[0]
    return np.stack([t, np.cross(n, t), n])


def warped_slices_f64(model: str, params: dict, views, frames):
    """Float64 mirror of :func:`._lobes_warp.warped_slices`: :func:`._slices.view_slice` of each world
    view in its tangent frame (rows t, b, n), lobes turned back to world.

    Returns:
        (axes (N, K, 3), sharpness (N, K), amplitude (N, K)); culled lobes as the kernel writes
        them (axis z+ of the frame, sharpness 1, amplitude 0).
    """
    views = np.asarray(views, np.float64).reshape(-1, 3)
    frames = np.asarray(frames, np.float64).reshape(-1, 3, 3)
    out = None
    for i, (v, f) in enumerate(zip(views, frames)):
        sl = view_slice(model, f @ (v / np.linalg.norm(v)), **params)
        axes = np.where(sl.culled[:, None], np.array([0.0, 0.0, 1.0]), sl.axes) @ f
        lam = np.where(sl.culled, 1.0, sl.sharpness)
        if out is None:
            out = (np.zeros((len(views), sl.lobe_count, 3)), np.zeros((len(views), sl.lobe_count)),
                   np.zeros((len(views), sl.lobe_count)))
        out[0][i], out[1][i], out[2][i] = axes, lam, np.asarray(sl.amplitude).reshape(-1)
    return out


def _exact_brdf(model: str, roughness: float, f0: float):
    """The exact BRDF of the narrow-light path (None for models without one)."""
    from ...scene._materials import BlinnPhong, Microfacet

    if model == "beckmann":
        return Microfacet(roughness=roughness, distribution="beckmann", f0=f0)
    if model == "blinn-phong":
        return BlinnPhong(exponent=roughness)
    return None


def _exact_lobe_brdf(model: str, params: dict):
    """The exact BRDF of a multi-lobe model's narrow-light path (Ward, Ashikhmin-Shirley; None for tabulated)."""
    from ._brdf import microfacet_brdf, split_params

    if model == "tabulated-ndf":
        return None
    return microfacet_brdf(model, **split_params(model, params, "shade_f64")[0])


def ssdf_value(maps: np.ndarray, v: int, frame: np.ndarray, d_world: np.ndarray) -> float:
    """Bilinear look-up of vertex ``v``'s map (R, R) at a world direction in its frame (rows t, b, n)."""
    r = maps.shape[1]
    d = frame @ d_world
    d = d / np.linalg.norm(d)
    if d[2] < 0.0:
        d = np.array([d[0], d[1], 0.0])
        d = d / max(np.linalg.norm(d), 1e-300) if np.linalg.norm(d) > 0 else np.array([0.0, 0.0, 1.0])
    ab = hemisphere_to_concentric(d)
    x = np.clip((ab[0] + 1.0) * 0.5 * r - 0.5, 0.0, r - 1)
    y = np.clip((ab[1] + 1.0) * 0.5 * r - 0.5, 0.0, r - 1)
    i0, j0 = int(np.floor(x)), int(np.floor(y))
    i1, j1 = min(i0 + 1, r - 1), min(j0 + 1, r - 1)
    fx, fy = x - i0, y - j0
    m = maps[v].astype(np.float64)
    top = (1 - fy) * m[i0, j0] + fy * m[i0, j1]
    bottom = (1 - fy) * m[i1, j0] + fy * m[i1, j1]
    return float((1 - fx) * top + fx * bottom)


def _texel_slice(texture, texel, o_local):
    """One texel's lobes warped to a local view (:func:`._svbrdf.svbrdf_slices_f64`), shaped as a
    :class:`._slices.view_slice` result; a lobe of amplitude 0 is culled, as the kernel skips it."""
    from types import SimpleNamespace

    from ._svbrdf import svbrdf_slices_f64

    axes, lam, amp = svbrdf_slices_f64(texture, np.asarray(texel).reshape(1, 2), np.asarray(o_local).reshape(1, 3))
    return SimpleNamespace(axes=axes[0], sharpness=lam[0], amplitude=amp[0], culled=~(amp[0] > 0.0),
                           lobe_count=int(lam.shape[1]))


def shade_f64(points, normals, eye, albedo, specular, roughness, maps, frames, model: str, f0: float,
                    env_mixture=None, table=None, env_to_world=np.eye(3), sphere_lights=(), distant_lobes=(),
                    component: str = "specular", cosine: str = "paper", corners=None, weights=None,
                    horizon: bool = True, narrow_lights: str = "brdf", narrow_ratio: float = 8.0,
                    lobe_model: str | None = None, lobe_params: dict | None = None, tangents=None,
                    svbrdf=None) -> np.ndarray:
    """Radiance (P, 3) float64 at P receivers, as :func:`._kernels.shade_point`.

    Args:
        points, normals: (P, 3) receivers; eye: (3,); albedo, specular: (P, 3); roughness: (P,).
        maps: decoded SSDFs (V, R, R); frames: (V, 3, 3) tangent frames (rows t, b, n).
        model, f0: the specular model (:data:`._brdf_warp.MODEL_IDS`) and Fresnel reflectance.
        env_mixture: the environment's SG mixture (map frame) or None; table: its
            :class:`~._prefilter.PrefilteredEnvironment` or None; env_to_world: (3, 3).
        sphere_lights: :class:`~warpshade.scene._lighting.SphereLight` posed at the frame.
        distant_lobes: (axis, sharpness, amplitude RGB) per distant light.
        component: "specular", "diffuse" or "both".
        corners, weights: (P, 3) vertex indices and barycentric weights (default: receiver i is vertex i).
        horizon: the tangent plane bounds the visibility too (``min(V^d, elevation)``).
        narrow_lights, narrow_ratio: as the kernel: with "brdf", the specular of a light lobe more
            than ``narrow_ratio`` times sharper than the slice is the exact BRDF at its direction
            (Beckmann, Blinn-Phong) times its irradiance, cosine and visible fraction.
        lobe_model, lobe_params: a fitted multi-lobe model of :mod:`._lobes_warp` (``ward``,
            ``ashikhmin-shirley``, ``tabulated-ndf``) and its :func:`._slices.view_slice`
            parameters, shaded in the tangent frame of ``tangents`` (P, 3) world directions
            (narrow lights: the exact Ward / Ashikhmin-Shirley BRDF); ``model`` is then unused.
        svbrdf: ``(texture, texels)``: a fitted :class:`._svbrdf.SVBRDFTexture` and each receiver's
            texel (P, 2) (row, column); its lobes are shaded about the normal (no narrow-light BRDF).
    """
    points = np.asarray(points, np.float64)
    count = points.shape[0]
    out = np.zeros((count, 3))
    cos_axis, cos_lam, cos_mu = sg.clamped_cosine(np.array([0.0, 0.0, 1.0]), cosine)
    cos_lam, cos_mu = float(cos_lam), float(cos_mu)
    want_d = component != "specular"
    want_s = component != "diffuse"
    env = []
    if env_mixture is not None:
        axes = sg.rotate(env_mixture.axes, env_to_world)
        env = [(axes[k], float(env_mixture.sharpness[k]), np.asarray(env_mixture.amplitude[k], np.float64))
               for k in range(env_mixture.lobe_count)]
    for i in range(count):
        x, n = points[i], np.asarray(normals[i], np.float64)
        o = np.asarray(eye, np.float64) - x
        o = o / np.linalg.norm(o)
        idx = (i, i, i) if corners is None else tuple(int(c) for c in corners[i])
        w = (1.0, 0.0, 0.0) if weights is None else tuple(float(c) for c in weights[i])

        def vis(d):
            theta = sum(w[k] * ssdf_value(maps, idx[k], frames[idx[k]], d) for k in range(3) if k == 0 or w[k] > 0)
            if horizon:
                theta = min(theta, float(np.arcsin(np.clip(d @ n, -1.0, 1.0))))
            return theta

        rd = np.zeros(3)
        rs = np.zeros(3)
        facing = float(o @ n) > 0.0
        slice_w = None
        slices = []
        if want_s and facing:
            if svbrdf is not None:
                frame = duff_frame_f64(n)
                lobes = _texel_slice(svbrdf[0], svbrdf[1][i], frame @ o)
            elif lobe_model is None:
                frame = duff_frame_f64(n)
                lobes = view_slice(model, frame @ o, **slice_parameters(model, float(roughness[i]), f0))
            else:
                frame = tangent_frame_f64(n, tangents[i])
                lobes = view_slice(lobe_model, frame @ o, **lobe_params)
            for k in range(lobes.lobe_count):
                if lobes.culled[k]:
                    continue
                axis_l, lam_l, mu_l = lobes.axes[k], float(lobes.sharpness[k]), float(np.asarray(lobes.amplitude).reshape(-1)[k])
                ax, lam, mu = sg.product(n, cos_lam, cos_mu, frame.T @ axis_l, lam_l, mu_l)
                slices.append((ax, float(lam), float(mu)))
                if table is not None:
                    f = sg.visible_fraction(vis(ax), lam)
                    rs += mu * f * table.lookup((env_to_world.T @ ax)[None], np.array([lam]))[0]
            slice_w = (None, max([g[1] for g in slices], default=0.0)) if (slices or lobe_model or svbrdf) else None
        if want_d:
            for axis_k, lam_k, amp_k in env:
                ax, lam, mu = sg.product(n, cos_lam, cos_mu, axis_k, lam_k, 1.0)
                rd += amp_k * mu * sg.hemisphere_integral(vis(ax), lam)
        local = []
        for light in sphere_lights:
            a, l, m = point_light_lobe(light, x[None])
            local.append((np.asarray(a).reshape(3), float(np.asarray(l).reshape(-1)[0]), np.asarray(m, np.float64).reshape(3)))
        local += [(np.asarray(a, np.float64).reshape(3), float(l), np.asarray(m, np.float64).reshape(3)) for a, l, m in distant_lobes]
        for axis_k, lam_k, amp_k in local:
            ax, lam, mu = sg.product(axis_k, lam_k, 1.0, n, cos_lam, cos_mu)
            if want_d:
                rd += amp_k * mu * sg.hemisphere_integral(vis(ax), lam)
            if slice_w is not None:
                if svbrdf is not None:
                    exact = None
                elif lobe_model is None:
                    exact = _exact_brdf(model, float(roughness[i]), f0) if narrow_lights == "brdf" else None
                else:
                    exact = _exact_lobe_brdf(lobe_model, lobe_params) if narrow_lights == "brdf" else None
                if exact is not None and lam_k > narrow_ratio * slice_w[1]:
                    cos_l = max(float(axis_k @ n), 0.0)
                    b = float(exact.evaluate(frame @ o, frame @ axis_k)) if cos_l > 0 else 0.0
                    rs += amp_k * float(sg.integral(lam_k)) * b * cos_l * float(sg.visible_fraction(vis(axis_k), lam_k))
                else:
                    for g in slices:
                        ax2, lam2, mu2 = sg.product(axis_k, lam_k, 1.0, g[0], g[1], g[2])
                        rs += amp_k * mu2 * sg.hemisphere_integral(vis(ax2), lam2)
        out[i] = np.asarray(albedo[i], np.float64) * rd / np.pi + np.asarray(specular[i], np.float64) * rs
    return out
