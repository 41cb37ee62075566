"""Spherical Gaussians with SSDF visibility (Wang et al. 2009) as graph stages.

* ``sg.ssdf`` (precompute): per-vertex spherical signed distance functions of ray-traced
  visibility over the upper hemisphere of each tangent frame (512^2 traced, 128^2 kept, as the
  paper), compressed by PCA with the term count chosen from an RMS budget in radians
  (:func:`.model.bake_ssdf_model`);
* ``sg.shade`` (per frame): eq. 39 + 41 (environment) and 42 + 43 (sphere and distant lights) per
  vertex toward the eye (:mod:`.kernels`): the BRDF's NDF as an SG (or, for anisotropic Ward,
  Ashikhmin-Shirley and measured tables, fitted SG lobes in per-point tangent frames,
  :mod:`.lobes_warp`) warped to the view slice, the
  clamped cosine as an SG, the environment as an SG mixture (diffuse) and a prefiltered table
  (specular), visibility from the SSDFs (eq. 30-31). Its BRDF parameters give every mesh's
  material, or, with ``textures = true``, the meshes' UsdPreviewSurface textures sampled at the
  vertices; the same stage shades per pixel (:meth:`SgShadeStage.render_pixels`).

Materials change at run time with no precompute: ``Runtime.set_material`` (a Beckmann
``Microfacet`` or ``BlinnPhong``) or :meth:`SgShadeStage.set_surface` (per-vertex arrays), both
written into the stage's fixed buffers.
"""

from __future__ import annotations

import numpy as np

from ..._wp import launch_parallel, wp
from ...basis import sg
from ...scene import materials, materials_warp
from ..stage import FrameStage, Param, Port, PrecomputeStage, StageError, register_stage
from ..viewer import EYE_PARAM, bind_viewer, check_eye, check_viewer
from . import kernels
from .checks import TABLE_MODELS, TEXTURE_MODELS, check_files, check_meshes, check_parameters, multi_lobe, rgb_param
from .brdf_warp import MODEL_IDS
from .lights import directional_light_lobe
from .lobes_warp import LOBE_MODELS
from .model import (SUN_MODES, EnvironmentLighting, bake_ssdf_model, decode_maps, empty_table, environment_hash,
                    environment_lighting, remember)

__all__ = ["SgEnvironmentStage"]

#: Receivers per CPU chunk below which a launch is not split over cores.
CPU_CHUNK_MIN = 2048
#: BRDF models of the per-point kernels: isotropic single-lobe NDFs, and fitted NDF lobes in a
#: tangent frame (anisotropic Ward with ``roughness_y``, Ashikhmin-Shirley; :mod:`.lobes_warp`).
BRDF_MODELS = tuple(MODEL_IDS) + ("ashikhmin-shirley", "tabulated-ndf", "svbrdf", "tabulated-aniso")
#: BRDF models the glossy reference can shade (what ``--validate`` accepts for the specular term).
VALIDATED_MODELS = ("beckmann", "blinn-phong", "ward") + BRDF_MODELS[-4:]
#: Specular of narrow lights: the exact BRDF at the light ("brdf") or the paper's SG product ("sg").
NARROW_LIGHT_MODES = ("brdf", "sg")
#: A light lobe this many times sharper than the BRDF slice counts as narrow.
NARROW_LIGHT_RATIO = 8.0
#: Largest ``roughness`` per model (parameter, run-time BRDF or per-vertex surface): microfacet
#: slopes past 2 are no longer a lobe and overflow the float32 lobes (Beckmann alpha 100 shaded
#: inf, 1e30 NaN); Blinn-Phong exponents past 1e6 are a mirror (measured finite to 1e10, NaN at 1e30).
ROUGHNESS_MAX = {"beckmann": 2.0, "cook-torrance": 2.0, "ward": 2.0, "blinn-phong": 1e6, "ashikhmin-shirley": 2.0,
                 "tabulated-ndf": 2.0, "svbrdf": 2.0, "tabulated-aniso": 2.0}
#: The exact models of the "brdf" mode: codes of warpshade.scene.materials_warp.BRDF_MODELS.
EXACT_MODEL_CODES = {"beckmann": 4, "blinn-phong": 2}


@register_stage
class SgSsdfStage(PrecomputeStage):
    type_name = "sg.ssdf"
    description = "per-vertex SSDF visibility (ray traced hemisphere, signed angular distance, PCA from an error budget)"
    parameters = {
        "resolution": Param(128, int, "SSDF map kept per vertex (res x res over the hemisphere)", minimum=4, maximum=512),
        "supersample": Param(4, int, "visibility traced at supersample x resolution per side", minimum=1, maximum=8),
        "error_budget": Param(0.02, float, "RMS error of the PCA reconstruction, radians", minimum=1e-6),
        "max_terms": Param(64, int, "most PCA terms", minimum=1, maximum=512),
        "frame": Param(None, float, "time code of the bake (default: the scene's first frame)"),
    }

    def output_ports(self):
        return {"ssdf": Port("arrays", (), "SSDF PCA: mean, basis, coefficients, error curve (local tangent frames)")}

    def precompute(self, ctx, inputs):
        p = self.params
        frame = float(ctx.scene.frames[0]) if p["frame"] is None else p["frame"]
        try:
            model = bake_ssdf_model(ctx.scene, frame, p["resolution"], p["supersample"], p["error_budget"], p["max_terms"],
                                    ctx.device, ctx.progress)
        except ValueError as exc:
            raise StageError(f"stage {self.name!r}: {exc}") from None
        return {"ssdf": model.arrays()}

    def check_artifact(self, outputs):
        from ...transfer import SSDFModel

        SSDFModel.from_arrays(outputs["ssdf"])


#: Parameters of the environment's preparation (``sg.environment``).
ENVIRONMENT_PARAMS = {
    "lobes": Param(8, int, "most SG lobes of the environment's diffuse mixture (fewer than 10)", minimum=1, maximum=9),
    "error_budget": Param(None, float, "irradiance error the fit may leave (the fewest lobes that meet it)"),
    "fit": Param("lbfgsb", str, "environment fit", choices=("nnls", "lbfgsb")),
    "sun": Param("separate", str, "a small, very bright sun: taken out and shaded as a narrow light (its "
                 "visibility at its own direction) or left in the sky ('keep', the paper)", choices=SUN_MODES),
}
ENVIRONMENT_FITS = ("nnls", "lbfgsb")


def _run_environment(ctx, stage_name: str):
    envs = ctx.lighting.environments if ctx.lighting is not None else []
    if len(envs) > 1:
        raise StageError(f"stage {stage_name!r}: SG shading takes one environment; this run has {len(envs)}")
    return envs[0] if envs else None


@register_stage
class SgEnvironmentStage(PrecomputeStage):
    type_name = "sg.environment"
    description = "the run's environment as an SG mixture (diffuse) and a prefiltered table over sharpness (specular)"
    parameters = dict(ENVIRONMENT_PARAMS)

    def output_ports(self):
        return {"environment": Port("arrays", (), "SG mixture and prefiltered table of the environment (map frame)")}

    def cache_key(self, ctx):
        env = _run_environment(ctx, self.name)
        return {"environment": None if env is None else environment_hash(env)}

    def precompute(self, ctx, inputs):
        p = self.params
        env = _run_environment(ctx, self.name)
        settings = np.array([p["lobes"], -1.0 if p["error_budget"] is None else p["error_budget"],
                             ENVIRONMENT_FITS.index(p["fit"]), SUN_MODES.index(p["sun"])], np.float64)
        if env is None:
            return {"environment": {"none": np.zeros(1), "settings": settings}}
        try:
            lighting = environment_lighting(env, p["lobes"], p["error_budget"], p["fit"], ctx.device, ctx.progress, p["sun"])
        except ValueError as exc:
            raise StageError(f"stage {self.name!r}: {exc}") from None
        return {"environment": {**lighting.arrays(), "settings": settings}}

    def check_artifact(self, outputs):
        arrays = outputs["environment"]
        if "none" not in arrays:
            EnvironmentLighting.from_arrays(arrays)


def _exact_brdf(model: str, params: dict):
    """The exact BRDF (``ks = 1``) of a multi-lobe model: :class:`.brdf.Ward` or :class:`.brdf.AshikhminShirley`."""
    from .brdf import microfacet_brdf

    return microfacet_brdf(model, **params)


#: Parameters of the multi-lobe (anisotropic) materials of ``sg.shade``.
MULTI_LOBE_PARAMS = {
    "roughness_y": Param(None, float, "Ward: alpha along the bitangent (anisotropic when it differs from 'roughness', "
                         "alpha along the tangent)", minimum=1e-3, maximum=1.0),
    "nu": Param(75.0, float, "Ashikhmin-Shirley exponent along the tangent", minimum=1e-3, maximum=1e5),
    "nv": Param(1200.0, float, "Ashikhmin-Shirley exponent along the bitangent", minimum=1e-3, maximum=1e5),
    "rs": Param(0.05, float, "Ashikhmin-Shirley normal-incidence reflectance", minimum=0.0, maximum=1.0),
    "lobes": Param(None, int, "SG lobes of a fitted NDF (default: the fewest whose fit meets ndf_error_budget)",
                   minimum=1, maximum=16),
    "ndf_error_budget": Param(0.15, float, "relative L2 error of the NDF fit the lobe count is chosen for",
                              minimum=1e-3, maximum=1.0),
    "max_lobes": Param(8, int, "most lobes the budget may choose", minimum=1, maximum=16),
    "tangent": Param("uv", str, "tangent of anisotropic materials: 'uv' (direction of increasing u of the meshes' "
                     "UVs, per frame) or 'direction' (tangent_direction projected on each tangent plane)",
                     choices=("uv", "direction")),
    "tangent_direction": Param(None, tuple, "world direction of tangent = 'direction'"),
    "table": Param(None, str, "a measured BRDF: MERL layout (tabulated-ndf), .anisobrdf (tabulated-aniso); relative to "
                   "the graph, or bundled:NAME; its NDF and shadowing are extracted by eq. 13 (sec. 4.2)"),
    "eta": Param(1.33, float, "tabulated-ndf: index of refraction of eq. 14's Fresnel factor", minimum=1.0001, maximum=10.0),
    "texture": Param(None, str, "svbrdf: a texture of eq.-13 materials (.svbrdf, methods/sg/svbrdf.py; relative to the "
                     "graph, or bundled:NAME), looked up at the meshes' UVs; per-texel NDFs fitted with SG lobes, "
                     "shadowing curves compressed by PCA (sec. 4.2)"),
    "shadow_error_budget": Param(1e-3, float, "svbrdf: RMS error of the shadowing PCA the term count is chosen for",
                                 minimum=1e-7, maximum=1.0),
    "shadow_max_terms": Param(8, int, "svbrdf: most PCA terms of the shadowing curves", minimum=1, maximum=64),
}


@register_stage
class SgShadeStage(FrameStage):
    type_name = "sg.shade"
    reads_materials = True
    description = "spherical-Gaussian shading (eq. 39, 41-43) with SSDF visibility, per vertex (and per pixel)"
    parameters = {
        "brdf": Param("beckmann", str, "specular model (NDF as one SG lobe)", choices=BRDF_MODELS),
        "roughness": Param(0.3, float, "microfacet roughness (Beckmann alpha / Cook-Torrance m / Ward alpha); "
                           "Blinn-Phong: the exponent", minimum=1e-3),
        "f0": Param(0.04, float, "Fresnel reflectance at normal incidence", minimum=0.0, maximum=1.0),
        "specular": Param((1.0, 1.0, 1.0), tuple, "RGB specular colour"),
        "component": Param("specular", str, "what the stage outputs", choices=kernels.COMPONENTS),
        "textures": Param(False, bool, "materials from the meshes' UsdPreviewSurface textures at the vertices"),
        "cosine": Param("paper", str, "clamped cosine lobe: the paper's (2.133, 1.170) or the L2 fit", choices=("paper", "l2")),
        "horizon": Param(True, bool, "the tangent plane bounds the reconstructed visibility too (theta_d = "
                         "min(V^d, elevation)); false: the paper's SSDF alone"),
        "narrow_lights": Param("brdf", str, "specular of lights much narrower than the BRDF slice: the BRDF at the "
                               "light's direction ('brdf'; Beckmann and Blinn-Phong) or the paper's SG product ('sg')",
                               choices=NARROW_LIGHT_MODES),
        "ssdf": Param("maps", str, "visibility look-up: decoded maps (bilinear) or PCA per look-up (the paper)",
                      choices=("maps", "pca")),
        "eye": EYE_PARAM,
        **MULTI_LOBE_PARAMS,
    }

    def __init__(self, name: str, params: dict | None = None):
        super().__init__(name, params)
        self._check_parameters()

    def input_ports(self):
        return {"ssdf": Port("arrays"), "environment": Port("arrays"), "frames": Port("mat33", ("V",)),
                "points": Port("vec3", ("V",)),
                "normals": Port("vec3", ("V",)), "albedo": Port("float32", ("V", 3)), "lighting": Port("lighting")}

    def output_ports(self):
        return {"radiance": Port("float32", ("V", 3), "radiance toward the eye, linear RGB")}

    # ---- set-up -----------------------------------------------------------------------
    def setup(self, ctx, inputs):
        from ...transfer import SSDFModel

        p = self.params
        dev = ctx.device
        self._ctx, self._scene, self._state, self._device = ctx, ctx.scene, ctx.state, dev
        self._check_parameters()
        check_meshes(self, ctx.scene)
        self._specular_rgb = rgb_param(p["specular"], "specular", self.name)
        self._viewer = bind_viewer(self.name, p["eye"], ctx)
        self._eye = self._viewer.eye
        self.follows_state_eye = self._viewer.follows_state_eye
        self.model = SSDFModel.from_arrays(inputs["ssdf"])
        if self.model.coeffs.shape[0] != ctx.dims["V"]:
            raise StageError(f"stage {self.name!r}: SSDFs of {self.model.coeffs.shape[0]} vertices for a scene of "
                             f"{ctx.dims['V']}")
        self._frames, self._points, self._normals = inputs["frames"], inputs["points"], inputs["normals"]
        self._albedo_in = inputs["albedo"]
        self._frame_lighting = inputs["lighting"]
        self._environment_in = inputs["environment"]
        if self._frame_lighting is None:
            raise StageError(f"stage {self.name!r}: SG shading needs the frame's lighting")
        self._vis = kernels.Visibility()
        r = int(self.model.resolution)
        if p["ssdf"] == "maps":
            self._vis.maps = wp.array(decode_maps(self.model), dtype=float, device=dev)
            self._vis.mean = wp.zeros(1, dtype=float, device=dev)
            self._vis.basis = wp.zeros((1, 1), dtype=float, device=dev)
            self._vis.coeffs = wp.zeros((1, 1), dtype=float, device=dev)
        else:
            self._vis.maps = wp.zeros((1, 1, 1), dtype=float, device=dev)
            self._vis.mean = wp.array(self.model.mean.astype(np.float32), dtype=float, device=dev)
            self._vis.basis = wp.array(self.model.basis.astype(np.float32), dtype=float, device=dev)
            self._vis.coeffs = wp.array(self.model.coeffs.astype(np.float32), dtype=float, device=dev)
        self._vis.frames = self._frames
        st = kernels.Settings()
        st.model = int(MODEL_IDS.get(p["brdf"], 0))  # multi-lobe models: unused (st.lobes)
        self._read_measured(ctx)
        self._read_svbrdf(ctx)
        st.f0 = float(p["f0"])
        cos_axis, cos_lam, cos_mu = sg.clamped_cosine(np.array([0.0, 0.0, 1.0]), p["cosine"])
        st.cos_sharpness, st.cos_amplitude = float(cos_lam), float(cos_mu)
        st.component = kernels.COMPONENTS.index(p["component"])
        st.pca = 0 if p["ssdf"] == "maps" else 1
        st.terms = int(self.model.coeffs.shape[1])
        st.resolution = r
        st.horizon = 1 if p["horizon"] else 0
        st.exact_model = int(EXACT_MODEL_CODES.get(p["brdf"], -1)) if p["narrow_lights"] == "brdf" else -1
        st.exact_ratio = float(NARROW_LIGHT_RATIO)
        self._settings = st
        count = ctx.dims["V"]
        self._setup_lobes(st, count)
        self._setup_svbrdf(st)
        self._albedo = wp.zeros(count, dtype=wp.vec3, device=dev)
        self._spec = wp.zeros(count, dtype=wp.vec3, device=dev)
        self._rough = wp.zeros(count, dtype=float, device=dev)
        self._radiance = wp.zeros((count, 3), dtype=wp.float32, device=dev)
        # the vertex kernel's argument structs over the fixed buffers (materials are written in place)
        self._vertex_points = kernels.VertexPoints()
        self._vertex_points.position, self._vertex_points.normal = self._points, self._normals
        self._vertex_points.eye = self._eye
        self._vertex_points.tangent = self._tangents
        self._vertex_materials = self._materials(self._albedo, self._spec, self._rough)
        self._upload_materials()
        self._setup_lights()
        return {"radiance": self._radiance}

    # ---- checks before any work ---------------------------------------------------------
    def _multi_lobe(self) -> bool:
        """Whether the parameters choose a material shaded as fitted NDF lobes in a tangent frame."""
        return multi_lobe(self.params)

    def _check_parameters(self) -> None:
        check_parameters(self, ROUGHNESS_MAX)

    def check_scene(self, scene, ctx) -> None:
        """Everything the parameters, the files' headers and the scene decide, before any
        precompute (the SSDF bake, the environment's preparation): the parameters, the viewer on
        this scene (a warning when an explicit 'eye' lies below it), the 'table' / 'texture' file
        (a relative path against the graph file's folder), and the meshes' UVs."""
        self._check_parameters()
        check_viewer(self.name, self.params["eye"], scene)
        file = self.params["table"] if self.params["brdf"] in TABLE_MODELS else self.params["texture"]
        if file is not None:
            check_files(self, ctx.resolve_path)
        check_meshes(self, scene)

    # ---- multi-lobe materials ---------------------------------------------------------
    def multi_lobe_model(self):
        """``(model, parameters)`` of the material when it is shaded as fitted NDF lobes in a tangent
        frame (anisotropic Ward, Ashikhmin-Shirley), else None (a single-lobe model of :data:`MODEL_IDS`)."""
        p = self.params
        if p["brdf"] == "ward" and p["roughness_y"] is not None and p["roughness_y"] != p["roughness"]:
            if p["roughness"] > 1.0:
                raise StageError(f"stage {self.name!r}: anisotropic Ward needs roughness (alpha_x) <= 1, got {p['roughness']!r}")
            return "ward", {"alpha_x": float(p["roughness"]), "alpha_y": float(p["roughness_y"])}
        if p["brdf"] == "ashikhmin-shirley":
            return "ashikhmin-shirley", {"nu": float(p["nu"]), "nv": float(p["nv"]), "rs": float(p["rs"])}
        if p["brdf"] in ("tabulated-ndf", "tabulated-aniso"):
            if getattr(self, "measured", None) is None:
                raise StageError(f"stage {self.name!r}: brdf = 'tabulated-ndf' is read from its table at set-up")
            return "tabulated-ndf", self.measured.parameters()
        return None

    def _read_measured(self, ctx) -> None:
        """brdf = 'tabulated-ndf' or 'tabulated-aniso': eq. 13's D and S from ``table`` (:mod:`.measured`, :mod:`.measured_aniso`)."""
        from .measured_aniso import stage_material

        p = self.params
        self.measured = None
        self.measured_path = None
        if p["brdf"] not in TABLE_MODELS:
            return
        path = ctx.resolve_path(p["table"])
        try:
            self.measured = stage_material(p["brdf"], path, p["eta"])
            self.measured_path = path
        except (OSError, ValueError) as exc:
            raise StageError(f"stage {self.name!r}: table {str(path)!r}: {exc}") from None

    def _read_svbrdf(self, ctx) -> None:
        """brdf = 'svbrdf': the texture read and fitted (:func:`.svbrdf.read_and_fit`) at set-up."""
        from .svbrdf import read_and_fit

        p = self.params
        self.svbrdf = None
        if p["brdf"] not in TEXTURE_MODELS:
            return
        path = ctx.resolve_path(p["texture"])
        try:
            self.svbrdf = read_and_fit(path, p["lobes"], p["ndf_error_budget"], p["max_lobes"], p["shadow_error_budget"],
                                       p["shadow_max_terms"])
            self.measured_path = path  # the reference's material (_reference_table)
        except (OSError, ValueError) as exc:
            raise StageError(f"stage {self.name!r}: {exc}") from None

    def _setup_svbrdf(self, st) -> None:
        """The fitted SVBRDF (or the empty placeholder) into ``st.svbrdf``, with the scene's per-vertex UVs."""
        from .svbrdf import scene_uvs
        from .svbrdf_warp import empty_svbrdf, upload_svbrdf

        if self.svbrdf is None:
            st.svbrdf = empty_svbrdf(self._device)
            return
        try:
            st.svbrdf = upload_svbrdf(self.svbrdf, scene_uvs(self._scene), self._device)
        except ValueError as exc:
            raise StageError(f"stage {self.name!r}: brdf = 'svbrdf': {exc}") from None

    def _fit_lobes(self, model: str, params: dict):
        """The NDF as SG lobes: ``lobes`` when given, else the fewest (up to ``max_lobes``) whose fit
        meets ``ndf_error_budget`` (the best fit, reported as over budget, when none does)."""
        from .brdf import microfacet_brdf
        from .ndf import fit_model_ndf, ndf_lobes

        p = self.params
        if p["brdf"] == "tabulated-aniso":  # a 2-D NDF extracted from the table (.measured_aniso)
            return self.measured.fit_lobes(p["lobes"], p["ndf_error_budget"], p["max_lobes"])
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
            import warnings

            warnings.warn(f"stage {self.name!r}: no fit of up to {p['max_lobes']} lobes meets ndf_error_budget "
                          f"{p['ndf_error_budget']} (best {best.relative_error:.3f} with {best.mixture.lobe_count})",
                          RuntimeWarning, stacklevel=2)
        return best.mixture, report

    def _setup_lobes(self, st, count: int) -> None:
        """The fitted NDF lobes into ``st.lobes`` and the per-vertex tangents they are shaded in."""
        from .lobes_warp import NDFLobes, upload_lobes

        p, dev = self.params, self._device
        self._tangents = wp.zeros(count, dtype=wp.vec3, device=dev)
        self._uv_tangents = None
        self.lobe_report = None
        multi = self.multi_lobe_model()
        if multi is None:
            empty = NDFLobes()
            empty.axes = wp.zeros(1, dtype=wp.vec3, device=dev)
            empty.sharpness = wp.zeros(1, dtype=float, device=dev)
            empty.amplitude = wp.zeros(1, dtype=float, device=dev)
            empty.shadow = wp.zeros(0, dtype=float, device=dev)
            empty.count, empty.model = 0, 0
            empty.exact = materials_warp.BRDFParams()
            st.lobes = empty
            return
        model, params = multi
        try:
            mixture, self.lobe_report = self._fit_lobes(model, params)
            # narrow lights: the exact BRDF (Ward, Ashikhmin-Shirley); a tabulated one has none on the device
            exact = None if model == "tabulated-ndf" else materials_warp.upload_brdf(_exact_brdf(model, params))
        except ValueError as exc:
            raise StageError(f"stage {self.name!r}: {exc}") from None
        st.lobes = upload_lobes(mixture, model, params, dev, exact)
        st.exact_model = LOBE_MODELS[model] if (p["narrow_lights"] == "brdf" and exact is not None) else -1
        if p["tangent"] == "uv":  # UVs on every mesh: checked by checks.check_meshes
            from ...geometry.uv_tangents import UVTangents

            self._uv_tangents = UVTangents.from_scene(self._scene, dev)
        else:  # a finite, non-zero tangent_direction: checked by _check_parameters
            arr = np.asarray(p["tangent_direction"], np.float64).reshape(3)
            self._tangents.assign(np.tile((arr / np.linalg.norm(arr)).astype(np.float32), (count, 1)))

    def _update_tangents(self) -> None:
        if self._uv_tangents is not None:
            self._uv_tangents.compute(self._points, self._normals, self._tangents)

    # ---- materials --------------------------------------------------------------------
    def _stage_values(self, brdf):
        """(roughness, specular RGB) of a run-time BRDF for this stage's model."""
        p = self.params
        if brdf is None:
            return float(p["roughness"]), self._specular_rgb
        if isinstance(brdf, materials.Microfacet) and brdf.distribution == "beckmann" and p["brdf"] == "beckmann":
            return float(brdf.roughness), self._specular_rgb * float(brdf.specular)
        if isinstance(brdf, materials.BlinnPhong) and p["brdf"] == "blinn-phong":
            return float(brdf.exponent), self._specular_rgb * float(brdf.specular)
        raise StageError(f"stage {self.name!r}: run-time BRDF {brdf.describe()} is not a {p['brdf']!r} model this stage "
                         "shades (set brdf = 'beckmann' for Beckmann microfacets, 'blinn-phong' for Blinn-Phong)")

    @staticmethod
    def _materials(albedo, specular, roughness):
        """A :class:`~.kernels.Materials` over per-point arrays (albedo, specular (P,) vec3; roughness (P,) float)."""
        m = kernels.Materials()
        m.albedo, m.specular, m.roughness = albedo, specular, roughness
        return m

    def _upload_materials(self) -> None:
        p = self.params
        count = self._radiance.shape[0]
        albedo = self._albedo_in.numpy().reshape(count, 3).astype(np.float32)
        rough = np.full(count, p["roughness"], np.float32)
        spec = np.tile(self._specular_rgb.astype(np.float32), (count, 1))
        mats = self._state.materials
        for m in self._scene.meshes:
            sl = slice(m.vertex_offset, m.vertex_offset + m.vertex_count)
            surface = getattr(m, "surface", None)
            if p["textures"] and surface is not None:
                if m.uvs is None:
                    raise StageError(f"stage {self.name!r}: mesh {m.path} has textures but no UVs")
                vals = surface.at_vertices(m.uvs)
                albedo[sl] = vals["diffuse"]
                rough[sl] = vals["roughness"]
                spec[sl] = vals["specular"] * self._specular_rgb[None]
            brdf = mats.brdf_of(m.path, None)
            if brdf is not None:
                r, s = self._stage_values(brdf)
                rough[sl] = r
                spec[sl] = s
        self.set_surface(albedo=albedo, specular=spec, roughness=rough)

    def set_surface(self, albedo=None, specular=None, roughness=None) -> None:
        """Write per-vertex material arrays (any of albedo (V, 3), specular (V, 3), roughness (V,))
        into the stage's buffers: the next frame uses them; nothing is recomputed. All are checked
        before any is written (a rejected call changes nothing)."""
        count = self._radiance.shape[0]
        checked = []
        for name, value, buf, shape in (("albedo", albedo, self._albedo, (count, 3)), ("specular", specular, self._spec, (count, 3)),
                                        ("roughness", roughness, self._rough, (count,))):
            if value is None:
                continue
            a = np.asarray(value, np.float32)
            if a.shape != shape or not np.all(np.isfinite(a)) or np.any(a < 0):
                raise StageError(f"stage {self.name!r}: set_surface {name} must be finite, non-negative, shape {shape}; "
                                 f"got {a.shape}")
            if name == "roughness" and np.any(a <= 0):
                raise StageError(f"stage {self.name!r}: set_surface roughness must be > 0")
            if name == "roughness" and np.any(a > ROUGHNESS_MAX[self.params["brdf"]]):
                raise StageError(f"stage {self.name!r}: roughness must be <= {ROUGHNESS_MAX[self.params['brdf']]:g} for "
                                 f"brdf = {self.params['brdf']!r}, got up to {float(a.max()):g}")
            checked.append((buf, a))
        for buf, a in checked:
            buf.assign(a if a.ndim == 1 else a.reshape(count, 3))
        self.surface = {"albedo": self._albedo, "specular": self._spec, "roughness": self._rough}

    # ---- lights -----------------------------------------------------------------------
    def _setup_lights(self) -> None:
        dev = self._device
        fl = self._frame_lighting
        lights = kernels.Lights()
        envs = fl.environments
        if len(envs) > 1:
            raise StageError(f"stage {self.name!r}: SG shading takes one environment; this run has {len(envs)}")
        self.environment = None
        if envs:
            self.environment = self._environment_for(envs[0])
            mix = self.environment.mixture
            self._env_axes0 = wp.array(mix.axes.astype(np.float32), dtype=wp.vec3, device=dev)
            lights.env_axes = wp.zeros(mix.lobe_count, dtype=wp.vec3, device=dev)
            lights.env_sharpness = wp.array(mix.sharpness.astype(np.float32), dtype=float, device=dev)
            lights.env_amplitude = wp.array(np.asarray(mix.amplitude, np.float32).reshape(-1, 3), dtype=wp.vec3, device=dev)
            lights.env_count = mix.lobe_count
            lights.table = self.environment.table.to_device(dev)
            lights.has_table = 1
        else:
            self._env_axes0 = wp.zeros(0, dtype=wp.vec3, device=dev)
            lights.env_axes = wp.zeros(0, dtype=wp.vec3, device=dev)
            lights.env_sharpness = wp.zeros(0, dtype=float, device=dev)
            lights.env_amplitude = wp.zeros(0, dtype=wp.vec3, device=dev)
            lights.env_count = 0
            lights.table = empty_table(dev)
            lights.has_table = 0
        lights.env_to_world = fl.environment_to_world if envs else wp.array(np.eye(3, dtype=np.float32)[None], dtype=wp.mat33, device=dev)
        lights.sphere_position = fl.sphere_position
        lights.sphere_radius = fl.sphere_radius
        lights.sphere_radiance = fl.sphere_radiance
        lights.sphere_count = fl.sphere_light_count
        distant = list(fl.distant_lights)
        sun_axes, sun_sharp, sun_amp = (self.environment.sun_lobes if self.environment is not None
                                        else (np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3))))
        count = len(distant) + len(sun_sharp)
        self._distant_directions = fl.distant_direction if distant else wp.zeros(1, dtype=wp.vec3, device=dev)
        self._sun_axes0 = wp.array(np.asarray(sun_axes, np.float32).reshape(-1, 3), dtype=wp.vec3, device=dev)
        self._distant_lights = len(distant)
        lights.distant_axes = wp.zeros(count, dtype=wp.vec3, device=dev)
        sharp = np.zeros(count, np.float32)
        amp = np.zeros((count, 3), np.float32)
        for k, light in enumerate(distant):
            _, lam, mu = directional_light_lobe(light)
            sharp[k] = float(np.asarray(lam).reshape(-1)[0])
            amp[k] = np.asarray(mu, np.float64).reshape(3)
        sharp[len(distant):] = sun_sharp
        amp[len(distant):] = sun_amp
        lights.distant_sharpness = wp.array(sharp, dtype=float, device=dev)
        lights.distant_amplitude = wp.array(amp, dtype=wp.vec3, device=dev)
        lights.distant_count = count
        self._lights = lights
        self._check_point_lights()

    def _environment_for(self, env) -> EnvironmentLighting:
        """The prepared environment: the ``sg.environment`` artifact when it was built from this
        image, else built now (a lighting set at run time) with that stage's settings."""
        arrays = self._environment_in
        image_hash = environment_hash(env)
        stored = None if arrays is None or "none" in arrays else EnvironmentLighting.from_arrays(arrays)
        settings = self._environment_settings()
        if stored is not None and stored.image_hash == image_hash:
            remember(stored, *settings)
            return stored
        lobes, budget, fit, sun = settings
        return environment_lighting(env, lobes, budget, fit, self._device, None, sun)

    def _environment_settings(self) -> tuple:
        """(lobes, error_budget, fit, sun) the ``sg.environment`` stage used (its defaults without one)."""
        arrays = self._environment_in
        if arrays is not None and "settings" in arrays and np.asarray(arrays["settings"]).size == 4:
            lobes, budget, fit, sun = np.asarray(arrays["settings"], np.float64).reshape(4)
            return int(lobes), (None if budget < 0 else float(budget)), ENVIRONMENT_FITS[int(fit)], SUN_MODES[int(sun)]
        d = ENVIRONMENT_PARAMS
        return d["lobes"].default, d["error_budget"].default, d["fit"].default, d["sun"].default

    def _check_point_lights(self) -> None:
        """Precomputed visibility is for distant light: a sphere light inside a mesh's convex hull
        (at the first frame's pose) at any frame is reported in ``diagnostics()['lights_inside_hull']``
        and by a warning; its shadows from that mesh are wrong on those frames."""
        from .lights import inside_hull

        self.lights_inside_hull = []
        spheres = self._ctx.lighting.sphere_lights() if self._ctx.lighting is not None else []
        if not spheres:
            return
        table = self._ctx.lighting.sphere_position_table(self._scene.frames)  # (T, S, 3)
        points = self._scene.points_at(float(self._scene.frames[0]))
        for m in self._scene.meshes:
            pts = points[m.vertex_offset : m.vertex_offset + m.vertex_count]
            if m.vertex_count < 4:
                continue
            hits = inside_hull(pts, table.reshape(-1, 3)).reshape(table.shape[:2])  # (T, S)
            for s in range(table.shape[1]):
                inside = [int(t) for t in np.flatnonzero(hits[:, s])]
                if inside:
                    self.lights_inside_hull.append({"mesh": m.path, "light": s, "frames": inside[:8], "count": len(inside)})
        if self.lights_inside_hull:
            import warnings

            first = self.lights_inside_hull[0]
            warnings.warn(f"stage {self.name!r}: sphere light {first['light']} is inside the convex hull of {first['mesh']} "
                          f"on {first['count']} frame(s) (from frame index {first['frames'][0]}): precomputed visibility is "
                          "for distant light, its shadows there are wrong", RuntimeWarning, stacklevel=2)

    def notify_changed(self, flags, keys=frozenset()) -> bool:
        from ...scene.state import Change

        if flags & Change.PARAMETERS:
            return False
        if flags & Change.VIEW:
            self._viewer.moved()
        if flags & Change.MATERIAL:
            self._upload_materials()
        if flags & Change.LIGHTING:
            self._setup_lights()
        return True

    # ---- per frame --------------------------------------------------------------------
    def _turn_lights(self) -> None:
        """The frame's lobe axes: the environment's lobes and suns turned with it, distant lights."""
        dev = self._device
        lights = self._lights
        if lights.env_count:
            wp.launch(kernels.turn_lobes_kernel, dim=lights.env_count, device=dev,
                      inputs=[self._env_axes0, lights.env_to_world, 0, lights.env_axes])
        if lights.distant_count:
            wp.launch(kernels.distant_axes_kernel, dim=lights.distant_count, device=dev,
                      inputs=[self._distant_directions, self._distant_lights, self._sun_axes0, lights.env_to_world,
                              lights.distant_axes])

    def launch(self, state):
        dev = self._device
        lights = self._lights
        self._turn_lights()
        self._update_tangents()

        def inputs(start, stop):
            return [self._vertex_points, self._vertex_materials, lights, self._vis, self._settings, start, self._radiance]

        launch_parallel(kernels.shade_vertices_kernel, self._radiance.shape[0], inputs, dev, min_count=CPU_CHUNK_MIN)

    def pixel_materials(self, gbuffer) -> dict:
        """The per-vertex materials interpolated at every ray of a G-buffer: ``albedo`` (N, 3),
        ``specular`` (N, 3), ``roughness`` (N,), float32 host arrays (0 for misses)."""
        px = self._interpolated_materials(self._pixel_hits(gbuffer, gbuffer.normal), gbuffer.pixel_count)
        return {"albedo": px.albedo.numpy(), "specular": px.specular.numpy(), "roughness": px.roughness.numpy()}

    def _pixel_hits(self, gbuffer, normals):
        """The G-buffer's rays as a :class:`~.kernels.PixelHits` with shading ``normals`` (N,) vec3."""
        hits = kernels.PixelHits()
        hits.hit, hits.position, hits.normal = gbuffer.hit, gbuffer.position, normals
        hits.face, hits.bary, hits.faces, hits.eye = gbuffer.face, gbuffer.bary, gbuffer.faces, self._eye
        hits.tangent = self._tangents
        return hits

    def _interpolated_materials(self, hits, n: int):
        """The per-vertex materials at each of the ``n`` rays of ``hits`` (0 for misses), new per-pixel arrays."""
        dev = self._device
        px = self._materials(wp.zeros(n, dtype=wp.vec3, device=dev), wp.zeros(n, dtype=wp.vec3, device=dev),
                             wp.zeros(n, dtype=float, device=dev))
        wp.launch(kernels.interpolate_materials_kernel, dim=n, device=dev, inputs=[hits, self._vertex_materials, px])
        return px

    def render_pixels(self, gbuffer, albedo=None, specular=None, roughness=None, normals=None):
        """Shade every pixel of a G-buffer of this frame (:func:`warpshade.render.render_gbuffer`:
        hit, position, normal, face, bary, faces) with the stage's current lights, eye and
        visibility. Per-pixel materials are arrays of ``gbuffer.pixel_count`` rows (textures
        sampled by the caller); each one left None is the per-vertex material interpolated.
        ``normals`` (unit world vectors at the hits, one row per pixel) replace the interpolated shading normals:
        a normal map, i.e. the per-pixel rotation of the clamped cosine and the BRDF slice of
        sec. 7 for these isotropic lobes (visibility stays the vertices' SSDFs).
        Returns wp.array(vec3) of linear radiance, 0 for misses."""
        dev = self._device
        n = gbuffer.pixel_count
        hits = self._pixel_hits(gbuffer, gbuffer.normal)
        px = self._interpolated_materials(hits, n)
        for name, value, buf, rgb in (("albedo", albedo, px.albedo, True), ("specular", specular, px.specular, True),
                                      ("roughness", roughness, px.roughness, False)):
            if value is None:
                continue
            a = np.asarray(value, np.float32)
            want = (n, 3) if rgb else (n,)
            if a.shape != want or not np.all(np.isfinite(a)) or np.any(a < 0):
                raise StageError(f"stage {self.name!r}: render_pixels {name} must be finite, non-negative, shape {want}; "
                                 f"got {a.shape}")
            buf.assign(a)
        if normals is not None:
            a = np.asarray(normals, np.float32)
            hit = gbuffer.hit.numpy().astype(bool)
            bad = a.shape != (n, 3) or not np.all(np.isfinite(a))
            if not bad and np.any(np.abs(np.linalg.norm(a[hit], axis=-1) - 1.0) > 1e-3):
                bad = True
            if bad:
                raise StageError(f"stage {self.name!r}: render_pixels normals must be finite unit vectors, shape {(n, 3)}; "
                                 f"got {a.shape}")
            hits.normal = wp.array(a, dtype=wp.vec3, device=dev)
        lights = self._lights
        self._turn_lights()
        out = wp.zeros(n, dtype=wp.vec3, device=dev)

        def inputs(start, stop):
            return [hits, px, lights, self._vis, self._settings, start, out]

        launch_parallel(kernels.shade_pixels_kernel, n, inputs, dev, min_count=CPU_CHUNK_MIN)
        return out

    # ---- measuring --------------------------------------------------------------------
    def reference_model(self, materials=None):
        """The ground truth this output is measured against: the glossy reference (specular
        term, Beckmann or Blinn-Phong BRDF, this stage's eye and colour), or the diffuse one
        (:class:`warpshade.measure.protocols.MeasuredStage`)."""
        return self._reference_model(per_pixel=False)

    def pixel_reference_model(self, materials=None):
        """:meth:`reference_model` for a per-pixel reference, which takes the textured roughness
        and colours per pixel (:class:`warpshade.measure.protocols.PixelStage`)."""
        return self._reference_model(per_pixel=True)

    def check_measurable(self, per_pixel: bool = False) -> None:
        """Refuse, from the parameters alone (before any work), what has no ground truth:
        ``component = 'both'``, a BRDF the glossy reference does not shade, textured materials
        measured per vertex without Beckmann (:class:`warpshade.measure.protocols.MeasurableStage`)."""
        p = self.params
        if p["component"] == "diffuse":
            return
        if p["component"] == "both":
            raise StageError(f"stage {self.name!r}: component = 'both' has no single reference; validate 'specular' "
                             "and 'diffuse' separately")
        if p["brdf"] not in VALIDATED_MODELS:
            raise StageError(f"stage {self.name!r}: the glossy reference shades {VALIDATED_MODELS}; brdf = {p['brdf']!r} "
                             "cannot be validated")
        if p["textures"] and not per_pixel and p["brdf"] != "beckmann":
            raise StageError(f"stage {self.name!r}: per-vertex validation of textured materials needs brdf = 'beckmann' "
                             "(the reference takes a roughness per vertex); measure it per pixel")

    def _reference_model(self, per_pixel: bool):
        """The glossy reference model; ``per_pixel``: textured materials are measured per pixel
        (per vertex only with brdf = 'beckmann', whose reference takes a roughness per vertex)."""
        p = self.params
        self.check_measurable(per_pixel)
        if p["component"] == "diffuse":
            return None
        textured = p["textures"] and not per_pixel
        multi = self.multi_lobe_model()
        if p["brdf"] in ("tabulated-ndf", "svbrdf", "tabulated-aniso"):
            brdf, multi = self._reference_table(), (multi if p["brdf"] == "tabulated-aniso" else None)
        elif multi is not None:
            brdf = _exact_brdf(*multi)
        elif p["brdf"] == "beckmann":
            brdf = materials.Microfacet(roughness=p["roughness"], distribution="beckmann", f0=p["f0"])
        elif p["brdf"] == "ward":
            brdf = _exact_brdf("ward", {"alpha_x": float(p["roughness"])})
        else:
            brdf = materials.BlinnPhong(exponent=p["roughness"])
        model = {"brdf": brdf, "eye": self._eye.numpy()[0].astype(np.float64), "color": self._specular_rgb.copy()}
        if multi is not None:
            model["tangents"] = "uv" if p["tangent"] == "uv" else tuple(float(x) for x in p["tangent_direction"])
        if textured:
            # the materials the vertices were shaded with: roughness and specular colour per vertex
            model["color"] = self._spec.numpy().astype(np.float64)
            if p["brdf"] != "tabulated-ndf":
                model["roughness"] = self._rough.numpy().astype(np.float64)
        return model

    def _reference_table(self):
        """The file itself: a table, an anisotropic table or an SVBRDF (:func:`.measured_aniso.stage_reference_table`)."""
        from .measured_aniso import stage_reference_table

        if self.measured_path is None:
            raise StageError(f"stage {self.name!r}: brdf = {self.params['brdf']!r} is read from its file at set-up")
        try:
            return stage_reference_table(self.params["brdf"], self.measured_path)
        except (OSError, ValueError) as exc:
            raise StageError(f"stage {self.name!r}: {str(self.measured_path)!r}: {exc}") from None

    def diagnostics(self) -> dict:
        out = {"ssdf_terms": int(self.model.coeffs.shape[1]), "ssdf_resolution": int(self.model.resolution),
               "lights_inside_hull": self.lights_inside_hull, "viewer": self._viewer.describe()}
        if self.lobe_report is not None:
            out["ndf_lobes"] = self.lobe_report
        if getattr(self, "svbrdf", None) is not None:
            out["svbrdf"] = self.svbrdf.report
        if self.environment is not None:
            out["environment_lobes"] = int(self.environment.mixture.lobe_count)
            out["environment_build_s"] = round(self.environment.build_s, 3)
            out["environment_suns"] = int(len(self.environment.sun_lobes[1]))
        return out

    def model_bytes(self) -> int:
        return int(self.model.mean.nbytes + self.model.basis.nbytes + self.model.coeffs.nbytes)
