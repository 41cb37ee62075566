"""What ``sg.shade`` checks before any work: its parameters (at construction and at every set-up:
a parameter may change at run time), its file's header and the meshes it shades (in
``check_scene``, before the SSDF bake and the environment's preparation)."""

from __future__ import annotations

import numpy as np

from ..stage import StageError
from .._viewer import check_eye

#: BRDF models read from a measured table (parameter 'table'), and from a texture ('texture').
TABLE_MODELS = ("tabulated-ndf", "tabulated-aniso")
TEXTURE_MODELS = ("svbrdf",)


def rgb_param(value, name: str, stage: str) -> np.ndarray:
    """Parameter ``name`` of stage ``stage`` as three non-negative numbers (StageError naming it)."""
    a = np.asarray(value, np.float64).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)) or np.any(a < 0):
        raise StageError(f"stage {stage!r}: parameter {name!r} needs three non-negative numbers, got {value!r}")
    return a


def multi_lobe(p: dict) -> bool:
    """Whether the parameters ``p`` choose a material shaded as fitted NDF lobes in a tangent frame."""
    return ((p["brdf"] == "ward" and p["roughness_y"] is not None and p["roughness_y"] != p["roughness"])
            or p["brdf"] in ("ashikhmin-shirley", *TABLE_MODELS))


def check_parameters(stage, roughness_max: dict) -> None:
    """What the parameters alone rule out (at construction, and again at every set-up: a
    parameter may have been changed at run time): the colour, the eye, the roughness of the
    model, which file parameter the BRDF reads ('table' for a measured table, 'texture' for an
    SVBRDF, neither otherwise), and the tangent of anisotropic materials."""
    p = stage.params
    brdf = p["brdf"]
    rgb_param(p["specular"], "specular", stage.name)
    check_eye(stage.name, p["eye"])
    if brdf == "blinn-phong" and p["roughness"] < 1.0:
        raise StageError(f"stage {stage.name!r}: for brdf = 'blinn-phong', 'roughness' carries the exponent (>= 1), "
                         f"got {p['roughness']}")
    if p["roughness"] > roughness_max[brdf]:
        raise StageError(f"stage {stage.name!r}: parameter 'roughness' must be <= {roughness_max[brdf]:g} for "
                         f"brdf = {brdf!r}, got {p['roughness']!r}")
    if brdf in TABLE_MODELS and p["table"] is None:
        raise StageError(f"stage {stage.name!r}: brdf = {brdf!r} needs 'table' (a MERL-layout or .anisobrdf file)")
    if brdf not in TABLE_MODELS and p["table"] is not None:
        raise StageError(f"stage {stage.name!r}: parameter 'table' is for brdf = 'tabulated-ndf' or "
                         f"'tabulated-aniso', not {brdf!r}")
    if brdf in TEXTURE_MODELS and p["texture"] is None:
        raise StageError(f"stage {stage.name!r}: brdf = 'svbrdf' needs 'texture' (a .svbrdf file)")
    if brdf not in TEXTURE_MODELS and p["texture"] is not None:
        raise StageError(f"stage {stage.name!r}: parameter 'texture' is for brdf = 'svbrdf', not {brdf!r}")
    if brdf == "ward" and multi_lobe(stage.params) and p["roughness"] > 1.0:
        raise StageError(f"stage {stage.name!r}: anisotropic Ward needs roughness (alpha_x) <= 1, got {p['roughness']!r}")
    if multi_lobe(stage.params) and p["tangent"] == "direction":
        d = p["tangent_direction"]
        arr = None if d is None else np.asarray(d, np.float64).reshape(-1)
        if arr is None or arr.shape != (3,) or not np.all(np.isfinite(arr)) or not np.linalg.norm(arr) > 0:
            raise StageError(f"stage {stage.name!r}: tangent = 'direction' needs tangent_direction, three finite "
                             f"numbers not all 0; got {d!r}")


def check_meshes(stage, scene) -> None:
    """What the meshes must carry: UVs for UV tangents of anisotropic materials, for an SVBRDF
    texture and for UsdPreviewSurface textures (``textures = true``)."""
    p = stage.params
    if multi_lobe(stage.params) and p["tangent"] == "uv":
        missing = [m.path for m in scene.meshes if m.uvs is None]
        if missing:
            raise StageError(f"stage {stage.name!r}: tangent = 'uv' needs UVs on every mesh; {missing[0]} has none "
                             "(set tangent = 'direction' and tangent_direction)")
    if p["brdf"] in TEXTURE_MODELS:
        missing = [m.path for m in scene.meshes if m.uvs is None]
        if missing:
            raise StageError(f"stage {stage.name!r}: brdf = 'svbrdf': the texture is looked up at the meshes' UVs; "
                             f"{missing[0]} has none")
    if p["textures"]:
        bare = [m.path for m in scene.meshes if getattr(m, "surface", None) is not None and m.uvs is None]
        if bare:
            raise StageError(f"stage {stage.name!r}: mesh {bare[0]} has textures but no UVs")


def check_files(stage, resolve) -> None:
    """The 'table' or 'texture' file read and checked (magic, version, dimensions, size,
    values: the readers of :mod:`warpshade.scene._tabulated_aniso`, :mod:`warpshade.scene._tabulated`
    and :mod:`warpshade.scene._svbrdf`), ``resolve`` making the parameter a path; nothing is fitted."""
    from ...scene._svbrdf import read_svbrdf
    from ...scene._tabulated import read_merl
    from ...scene._tabulated_aniso import read_anisotropic_table

    p = stage.params
    name = "table" if p["brdf"] in TABLE_MODELS else "texture"
    try:
        path = resolve(p[name])
    except ValueError as exc:
        raise StageError(f"stage {stage.name!r}: parameter {name!r}: {exc}") from None
    if p["brdf"] in TABLE_MODELS:
        try:
            (read_anisotropic_table if p["brdf"] == "tabulated-aniso" else read_merl)(path)
        except (OSError, ValueError) as exc:
            raise StageError(f"stage {stage.name!r}: table {str(path)!r}: {exc}") from None
    else:
        try:
            read_svbrdf(path)
        except (OSError, ValueError) as exc:
            raise StageError(f"stage {stage.name!r}: {exc}") from None
