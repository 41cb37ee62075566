"""The materials of ``sg.shade``: measured tables and SVBRDF textures read at set-up, NDFs fitted
with SG lobes in per-point tangent frames, and the per-vertex albedo, specular colour and
roughness written into the stage's fixed buffers (parameters, textures, run-time BRDFs).

The stage (:class:`._stages.SgShadeStage`) calls these at set-up and when materials change; each
takes the stage's parameters and name (for its errors) rather than the stage.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ..._wp import wp
from ...scene import _materials as materials, _materials_warp as materials_warp
from ..stage import StageError
from ._brdf_warp import MODEL_IDS
from ._checks import TABLE_MODELS, TEXTURE_MODELS
from ._lobes_warp import LOBE_MODELS

#: BRDF models of the per-point kernels: isotropic single-lobe NDFs, and fitted NDF lobes in a
#: tangent frame (anisotropic Ward with ``roughness_y``, Ashikhmin-Shirley; :mod:`._lobes_warp`).
BRDF_MODELS = tuple(MODEL_IDS) + ("ashikhmin-shirley", "tabulated-ndf", "svbrdf", "tabulated-aniso")
#: Largest ``roughness`` per model (parameter, run-time BRDF or per-vertex surface): microfacet
#: slopes past 2 are no longer a lobe and overflow the float32 lobes (Beckmann alpha 100 shaded
#: inf, 1e30 NaN); Blinn-Phong exponents past 1e6 are a mirror (measured finite to 1e10, NaN at 1e30).
ROUGHNESS_MAX = {"beckmann": 2.0, "cook-torrance": 2.0, "ward": 2.0, "blinn-phong": 1e6, "ashikhmin-shirley": 2.0,
                 "tabulated-ndf": 2.0, "svbrdf": 2.0, "tabulated-aniso": 2.0}


def exact_brdf(model: str, params: dict):
    """The exact BRDF (``ks = 1``) of a multi-lobe model: :class:`._brdf.Ward` or :class:`._brdf.AshikhminShirley`."""
    from ._brdf import microfacet_brdf

    return microfacet_brdf(model, **params)


# ---- measured tables and textures -------------------------------------------------------------
def multi_lobe_model(p: dict, measured, stage: str):
    """``(model, parameters)`` of the material of parameters ``p`` when it is shaded as fitted NDF
    lobes in a tangent frame (anisotropic Ward, Ashikhmin-Shirley, a measured table read as
    ``measured``), else None (a single-lobe model of :data:`MODEL_IDS`)."""
    if p["brdf"] == "ward" and p["roughness_y"] is not None and p["roughness_y"] != p["roughness"]:
        if p["roughness"] > 1.0:
            raise StageError(f"stage {stage!r}: anisotropic Ward needs roughness (alpha_x) <= 1, got {p['roughness']!r}")
        return "ward", {"alpha_x": float(p["roughness"]), "alpha_y": float(p["roughness_y"])}
    if p["brdf"] == "ashikhmin-shirley":
        return "ashikhmin-shirley", {"nu": float(p["nu"]), "nv": float(p["nv"]), "rs": float(p["rs"])}
    if p["brdf"] in ("tabulated-ndf", "tabulated-aniso"):
        if measured is None:
            raise StageError(f"stage {stage!r}: brdf = 'tabulated-ndf' is read from its table at set-up")
        return "tabulated-ndf", measured.parameters()
    return None


def read_measured(p: dict, resolve_path, stage: str) -> tuple:
    """brdf = 'tabulated-ndf' or 'tabulated-aniso': eq. 13's D and S from ``table`` (:mod:`._measured`,
    :mod:`._measured_aniso`), as ``(material, path)``; ``(None, None)`` for other models."""
    from ._measured_aniso import stage_material

    if p["brdf"] not in TABLE_MODELS:
        return None, None
    path = resolve_path(p["table"])
    try:
        return stage_material(p["brdf"], path, p["eta"]), path
    except (OSError, ValueError) as exc:
        raise StageError(f"stage {stage!r}: table {str(path)!r}: {exc}") from None


def read_svbrdf(p: dict, resolve_path, stage: str) -> tuple:
    """brdf = 'svbrdf': the texture read and fitted (:func:`._svbrdf.read_and_fit`), as ``(texture,
    path)``; ``(None, None)`` for other models."""
    from ._svbrdf import read_and_fit

    if p["brdf"] not in TEXTURE_MODELS:
        return None, None
    path = resolve_path(p["texture"])
    try:
        return read_and_fit(path, p["lobes"], p["ndf_error_budget"], p["max_lobes"], p["shadow_error_budget"],
                            p["shadow_max_terms"]), path
    except (OSError, ValueError) as exc:
        raise StageError(f"stage {stage!r}: {exc}") from None


def svbrdf_on_device(svbrdf, scene, device, stage: str):
    """The fitted SVBRDF with the scene's per-vertex UVs on ``device`` (the empty placeholder for None)."""
    from ...scene._svbrdf import scene_uvs
    from ._svbrdf_warp import empty_svbrdf, upload_svbrdf

    if svbrdf is None:
        return empty_svbrdf(device)
    try:
        return upload_svbrdf(svbrdf, scene_uvs(scene), device)
    except ValueError as exc:
        raise StageError(f"stage {stage!r}: brdf = 'svbrdf': {exc}") from None


# ---- fitted NDF lobes -------------------------------------------------------------------------
def fit_lobes(p: dict, model: str, params: dict, measured, stage: str):
    """The NDF as SG lobes: ``lobes`` when given, else the fewest (up to ``max_lobes``) whose fit
    meets ``ndf_error_budget`` (the best fit, reported as over budget, when none does). Returns
    ``(mixture, report)``."""
    from ._brdf import microfacet_brdf
    from ._ndf import fit_model_ndf, ndf_lobes

    if p["brdf"] == "tabulated-aniso":  # a 2-D NDF extracted from the table (.measured_aniso)
        return measured.fit_lobes(p["lobes"], p["ndf_error_budget"], p["max_lobes"])
    if getattr(microfacet_brdf(model, **params), "isotropic", False):
        mix = ndf_lobes(model, **params)
        return mix, {"model": model, "lobes": 1, "fit_error": None, "closed_form": True}
    most = min(p["max_lobes"], 2) if model == "tabulated-ndf" else p["max_lobes"]  # lobes about z+: 1 or 2
    counts = [p["lobes"]] if p["lobes"] is not None else range(1, most + 1)
    best, tried = None, []
    for k in counts:
        fit = fit_model_ndf(model, **params, lobes=int(k))
        tried.append({"lobes": int(k), "fit_error": round(float(fit.relative_error), 5)})
        if best is None or fit.relative_error < best.relative_error:
            best = fit
        if p["lobes"] is None and fit.relative_error <= p["ndf_error_budget"]:
            best = fit
            break
    met = p["lobes"] is not None or best.relative_error <= p["ndf_error_budget"]
    report = {"model": model, "lobes": int(best.mixture.lobe_count), "fit_error": float(best.relative_error),
              "budget": float(p["ndf_error_budget"]), "budget_met": bool(met), "tried": tried}
    if not met:
        warnings.warn(f"stage {stage!r}: no fit of up to {p['max_lobes']} lobes meets ndf_error_budget "
                      f"{p['ndf_error_budget']} (best {best.relative_error:.3f} with {best.mixture.lobe_count})",
                      RuntimeWarning, stacklevel=2)
    return best.mixture, report


@dataclass
class ShadeLobes:
    """The fitted NDF lobes of a multi-lobe material and the per-vertex tangents they are shaded in.

    Attributes:
        lobes: :class:`~._lobes_warp.NDFLobes` (an empty one, ``count = 0``, for single-lobe models).
        exact_model: code of the exact BRDF of narrow lights (:data:`~._lobes_warp.LOBE_MODELS`, -1
            for none), or None to keep the single-lobe models' choice.
        tangents: per-vertex world tangents, shape (vertex_count,), vec3.
        uv_tangents: :class:`~warpshade.geometry._uv_tangents.UVTangents` recomputing ``tangents``
            every frame (``tangent = 'uv'``), or None when they are fixed.
        report: the lobe fit's report (``diagnostics()['ndf_lobes']``), None for single-lobe models.
    """

    lobes: object
    exact_model: int | None
    tangents: object
    uv_tangents: object = None
    report: dict | None = None

    def update_tangents(self, points, normals) -> None:
        """The frame's tangents from its points and normals (``tangent = 'uv'``; fixed otherwise)."""
        if self.uv_tangents is not None:
            self.uv_tangents.compute(points, normals, self.tangents)


def _empty_lobes(device):
    from ._lobes_warp import NDFLobes

    empty = NDFLobes()
    empty.axes = wp.zeros(1, dtype=wp.vec3, device=device)
    empty.sharpness = wp.zeros(1, dtype=float, device=device)
    empty.amplitude = wp.zeros(1, dtype=float, device=device)
    empty.shadow = wp.zeros(0, dtype=float, device=device)
    empty.count, empty.model = 0, 0
    empty.exact = materials_warp.BRDFParams()
    return empty


def setup_lobes(p: dict, multi, measured, scene, count: int, device, stage: str) -> ShadeLobes:
    """The fitted NDF lobes of ``multi`` (:func:`multi_lobe_model`; None: single-lobe) on ``device``
    and the tangents of the ``count`` vertices of ``scene`` they are shaded in."""
    from ._lobes_warp import upload_lobes

    tangents = wp.zeros(count, dtype=wp.vec3, device=device)
    if multi is None:
        return ShadeLobes(_empty_lobes(device), None, tangents)
    model, params = multi
    try:
        mixture, report = fit_lobes(p, model, params, measured, stage)
        # narrow lights: the exact BRDF (Ward, Ashikhmin-Shirley); a tabulated one has none on the device
        exact = None if model == "tabulated-ndf" else materials_warp.upload_brdf(exact_brdf(model, params))
    except ValueError as exc:
        raise StageError(f"stage {stage!r}: {exc}") from None
    lobes = upload_lobes(mixture, model, params, device, exact)
    exact_model = LOBE_MODELS[model] if (p["narrow_lights"] == "brdf" and exact is not None) else -1
    uv_tangents = None
    if p["tangent"] == "uv":  # UVs on every mesh: checked by checks.check_meshes
        from ...geometry._uv_tangents import UVTangents

        uv_tangents = UVTangents.from_scene(scene, device)
    else:  # a finite, non-zero tangent_direction: checked by checks.check_parameters
        arr = np.asarray(p["tangent_direction"], np.float64).reshape(3)
        tangents.assign(np.tile((arr / np.linalg.norm(arr)).astype(np.float32), (count, 1)))
    return ShadeLobes(lobes, exact_model, tangents, uv_tangents, report)


# ---- per-vertex materials ---------------------------------------------------------------------
def stage_values(p: dict, specular_rgb: np.ndarray, brdf, stage: str) -> tuple:
    """(roughness, specular RGB) of a run-time BRDF (None: the parameters') for the model of ``p``."""
    if brdf is None:
        return float(p["roughness"]), specular_rgb
    if isinstance(brdf, materials.Microfacet) and brdf.distribution == "beckmann" and p["brdf"] == "beckmann":
        return float(brdf.roughness), specular_rgb * float(brdf.specular)
    if isinstance(brdf, materials.BlinnPhong) and p["brdf"] == "blinn-phong":
        return float(brdf.exponent), specular_rgb * float(brdf.specular)
    raise StageError(f"stage {stage!r}: run-time BRDF {brdf.describe()} is not a {p['brdf']!r} model this stage "
                     "shades (set brdf = 'beckmann' for Beckmann microfacets, 'blinn-phong' for Blinn-Phong)")


def vertex_surface(p: dict, specular_rgb: np.ndarray, albedo_in, scene, scene_materials, count: int, stage: str) -> tuple:
    """The per-vertex materials the stage shades: ``(albedo (V, 3), specular (V, 3), roughness (V,))``
    float32 host arrays of the ``count`` vertices from the parameters, the meshes' textures
    (``textures = true``) and the run-time BRDFs of ``scene_materials`` (the frame state's material
    assignments), in that order."""
    albedo = albedo_in.numpy().reshape(count, 3).astype(np.float32)
    rough = np.full(count, p["roughness"], np.float32)
    spec = np.tile(specular_rgb.astype(np.float32), (count, 1))
    for m in scene.meshes:
        sl = slice(m.vertex_offset, m.vertex_offset + m.vertex_count)
        surface = getattr(m, "surface", None)
        if p["textures"] and surface is not None:
            if m.uvs is None:
                raise StageError(f"stage {stage!r}: mesh {m.path} has textures but no UVs")
            vals = surface.at_vertices(m.uvs)
            albedo[sl] = vals["diffuse"]
            rough[sl] = vals["roughness"]
            spec[sl] = vals["specular"] * specular_rgb[None]
        brdf = scene_materials.brdf_of(m.path, None)
        if brdf is not None:
            r, s = stage_values(p, specular_rgb, brdf, stage)
            rough[sl] = r
            spec[sl] = s
    return albedo, spec, rough


def checked_surface(brdf: str, count: int, stage: str, **arrays) -> dict:
    """The per-vertex arrays given (any of albedo (V, 3), specular (V, 3), roughness (V,)) as
    float32, each checked (finite, non-negative, shape; roughness positive and within
    :data:`ROUGHNESS_MAX` of model ``brdf``); None values are left out."""
    shapes = {"albedo": (count, 3), "specular": (count, 3), "roughness": (count,)}
    checked = {}
    for name, value in arrays.items():
        if value is None:
            continue
        shape = shapes[name]
        a = np.asarray(value, np.float32)
        if a.shape != shape or not np.all(np.isfinite(a)) or np.any(a < 0):
            raise StageError(f"stage {stage!r}: set_surface {name} must be finite, non-negative, shape {shape}; "
                             f"got {a.shape}")
        if name == "roughness" and np.any(a <= 0):
            raise StageError(f"stage {stage!r}: set_surface roughness must be > 0")
        if name == "roughness" and np.any(a > ROUGHNESS_MAX[brdf]):
            raise StageError(f"stage {stage!r}: roughness must be <= {ROUGHNESS_MAX[brdf]:g} for "
                             f"brdf = {brdf!r}, got up to {float(a.max()):g}")
        checked[name] = a
    return checked
