"""What ``sg.shade`` is measured against: which of its outputs have a ground truth, and the glossy
reference's model of its specular term (:class:`warpshade.measure._protocols.MeasuredStage`)."""

from __future__ import annotations

import numpy as np

from ...scene import _materials as materials
from ..stage import StageError
from ._shade_materials import BRDF_MODELS, exact_brdf

#: BRDF models the glossy reference can shade (what ``--validate`` accepts for the specular term).
VALIDATED_MODELS = ("beckmann", "blinn-phong", "ward") + BRDF_MODELS[-4:]
#: Models measured against their own file (a table, an anisotropic table, an SVBRDF).
FILE_MODELS = ("tabulated-ndf", "svbrdf", "tabulated-aniso")


def check_measurable(p: dict, stage: str, per_pixel: bool = False) -> None:
    """Refuse, from the parameters ``p`` alone (before any work), what has no ground truth:
    ``component = 'both'``, a BRDF the glossy reference does not shade, textured materials
    measured per vertex without Beckmann."""
    if p["component"] == "diffuse":
        return
    if p["component"] == "both":
        raise StageError(f"stage {stage!r}: component = 'both' has no single reference; validate 'specular' "
                         "and 'diffuse' separately")
    if p["brdf"] not in VALIDATED_MODELS:
        raise StageError(f"stage {stage!r}: the glossy reference shades {VALIDATED_MODELS}; brdf = {p['brdf']!r} "
                         "cannot be validated")
    if p["textures"] and not per_pixel and p["brdf"] != "beckmann":
        raise StageError(f"stage {stage!r}: per-vertex validation of textured materials needs brdf = 'beckmann' "
                         "(the reference takes a roughness per vertex); measure it per pixel")


def reference_table(brdf: str, path, stage: str):
    """The file itself: a table, an anisotropic table or an SVBRDF (:func:`._measured_aniso.stage_reference_table`)."""
    from ._measured_aniso import stage_reference_table

    if path is None:
        raise StageError(f"stage {stage!r}: brdf = {brdf!r} is read from its file at set-up")
    try:
        return stage_reference_table(brdf, path)
    except (OSError, ValueError) as exc:
        raise StageError(f"stage {stage!r}: {str(path)!r}: {exc}") from None


def reference_model(p: dict, per_pixel: bool, multi, file_path, eye: np.ndarray, color: np.ndarray, specular,
                    roughness, stage: str):
    """The glossy reference model of the specular term of a stage of parameters ``p``, which
    :func:`check_measurable` accepted (``component = 'specular'``).

    Args:
        per_pixel: textured materials are measured per pixel (per vertex only with brdf =
            'beckmann', whose reference takes a roughness per vertex).
        multi: the multi-lobe material (:func:`._shade_materials.multi_lobe_model`) or None.
        file_path: the material file read at set-up (FILE_MODELS), or None.
        eye: the eye, shape (3,), float64, world space.
        color: the specular RGB colour parameter, shape (3,).
        specular, roughness: the per-vertex specular colours (V,) vec3 and roughness (V,) float
            the vertices were shaded with (read when textured materials are measured per vertex).
    """
    textured = p["textures"] and not per_pixel
    if p["brdf"] in FILE_MODELS:
        brdf, multi = reference_table(p["brdf"], file_path, stage), (multi if p["brdf"] == "tabulated-aniso" else None)
    elif multi is not None:
        brdf = exact_brdf(*multi)
    elif p["brdf"] == "beckmann":
        brdf = materials.Microfacet(roughness=p["roughness"], distribution="beckmann", f0=p["f0"])
    elif p["brdf"] == "ward":
        brdf = exact_brdf("ward", {"alpha_x": float(p["roughness"])})
    else:
        brdf = materials.BlinnPhong(exponent=p["roughness"])
    model = {"brdf": brdf, "eye": eye, "color": color.copy()}
    if multi is not None:
        model["tangents"] = "uv" if p["tangent"] == "uv" else tuple(float(x) for x in p["tangent_direction"])
    if textured:
        # the materials the vertices were shaded with: roughness and specular colour per vertex
        model["color"] = specular.numpy().astype(np.float64)
        if p["brdf"] != "tabulated-ndf":
            model["roughness"] = roughness.numpy().astype(np.float64)
    return model
