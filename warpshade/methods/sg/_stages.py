"""Spherical Gaussians with SSDF visibility (Wang et al. 2009) as graph stages.

* ``sg.ssdf`` (precompute): per-vertex spherical signed distance functions of ray-traced
  visibility over the upper hemisphere of each tangent frame (512^2 traced, 128^2 kept, as the
  paper), compressed by PCA with the term count chosen from an RMS budget in radians
  (:func:`._model.bake_ssdf_model`);
* ``sg.shade`` (per frame): eq. 39 + 41 (environment) and 42 + 43 (sphere and distant lights) per
  vertex toward the eye (:mod:`._kernels`): the BRDF's NDF as an SG (or, for anisotropic Ward,
  Ashikhmin-Shirley and measured tables, fitted SG lobes in per-point tangent frames,
  :mod:`._lobes_warp`) warped to the view slice, the
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
from ..stage import FrameStage, Param, Port, PrecomputeStage, StageError, register_stage
from .._viewer import EYE_PARAM, bind_viewer, check_viewer
from . import _kernels as kernels
from ._checks import TABLE_MODELS, check_files, check_meshes, check_parameters, rgb_param
from ._model import SUN_MODES, EnvironmentLighting, bake_ssdf_model, environment_hash, environment_lighting
from ._shade_inputs import (NARROW_LIGHT_MODES, interpolated_materials, materials_struct, override_pixels, pixel_hits,
                           settings_struct, ssdf_visibility, vertex_points)
from ._shade_lights import ENVIRONMENT_FITS, ENVIRONMENT_PARAMS, lights_inside_hull, setup_lights
from ._shade_materials import (BRDF_MODELS, ROUGHNESS_MAX, checked_surface, multi_lobe_model, read_measured,
                              read_svbrdf, setup_lobes, svbrdf_on_device, vertex_surface)
from ._shade_reference import check_measurable, reference_model

__all__ = ["SgEnvironmentStage"]

#: Receivers per CPU chunk below which a launch is not split over cores.
CPU_CHUNK_MIN = 2048


@register_stage
class SgSsdfStage(PrecomputeStage):
    type_name = "sg.ssdf"
    description = "per-vertex SSDF visibility (ray traced hemisphere, signed angular distance, PCA from an error budget)"
    quick = {"resolution": 16, "supersample": 2}  # a 512^2 bake per vertex takes minutes
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


def _run_environment(ctx, stage_name: str):
    envs = ctx.lighting.environments if ctx.lighting is not None else []
    if len(envs) > 1:
        raise StageError(f"stage {stage_name!r}: SG shading takes one environment; this run has {len(envs)}")
    return envs[0] if envs else None


@register_stage
class SgEnvironmentStage(PrecomputeStage):
    type_name = "sg.environment"
    description = "the run's environment as an SG mixture (diffuse) and a prefiltered table over sharpness (specular)"
    quick_sky = True  # its prefiltered table of a 256 x 512 sky takes minutes
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
    shades_sphere_lights = True
    description = "spherical-Gaussian shading (eq. 39, 41-43) with SSDF visibility, per vertex (and per pixel)"
    @classmethod
    def quick_params(cls, params):  # a fitted NDF's budget fits up to 8 lobes in turn (seconds each): 2 lobes
        return {"lobes": 2} if params.get("roughness_y") is not None or params.get("table") is not None else {}
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
        return {"ssdf": Port("arrays"), "environment": Port("arrays"), "tangents": Port("mat33", ("V",)),
                "points": Port("vec3", ("V",)),
                "normals": Port("vec3", ("V",)), "albedo": Port("float32", ("V", 3)), "lighting": Port("lighting")}

    def output_ports(self):
        return {"radiance": Port("float32", ("V", 3), "radiance toward the eye, linear RGB")}

    # ---- set-up -----------------------------------------------------------------------
    def setup(self, ctx, inputs):
        """Visibility, materials (:mod:`._shade_materials`) and lights (:mod:`._shade_lights`) into
        the kernels' fixed buffers (:mod:`._shade_inputs`)."""
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
        self._frames, self._points, self._normals = inputs["tangents"], inputs["points"], inputs["normals"]
        self._albedo_in = inputs["albedo"]
        self._frame_lighting = inputs["lighting"]
        self._environment_in = inputs["environment"]
        if self._frame_lighting is None:
            raise StageError(f"stage {self.name!r}: SG shading needs the frame's lighting")
        self._vis = ssdf_visibility(self.model, p["ssdf"], self._frames, dev)
        self.measured, self.measured_path = read_measured(p, ctx.resolve_path, self.name)
        self.svbrdf, svbrdf_path = read_svbrdf(p, ctx.resolve_path, self.name)
        if svbrdf_path is not None:
            self.measured_path = svbrdf_path  # the reference's material
        st = settings_struct(p, self.model.coeffs.shape[1], self.model.resolution)
        count = ctx.dims["V"]
        self._lobes = setup_lobes(p, self.multi_lobe_model(), self.measured, self._scene, count, dev, self.name)
        st.lobes = self._lobes.lobes
        if self._lobes.exact_model is not None:
            st.exact_model = self._lobes.exact_model
        self.lobe_report, self._tangents = self._lobes.report, self._lobes.tangents
        st.svbrdf = svbrdf_on_device(self.svbrdf, self._scene, dev, self.name)
        self._settings = st
        self._albedo = wp.zeros(count, dtype=wp.vec3, device=dev)
        self._spec = wp.zeros(count, dtype=wp.vec3, device=dev)
        self._rough = wp.zeros(count, dtype=float, device=dev)
        self._radiance = wp.zeros((count, 3), dtype=wp.float32, device=dev)
        # the vertex kernel's argument structs over the fixed buffers (materials are written in place)
        self._vertex_points = vertex_points(self._points, self._normals, self._eye, self._tangents)
        self._vertex_materials = materials_struct(self._albedo, self._spec, self._rough)
        self._upload_materials()
        self._setup_lights()
        return {"radiance": self._radiance}

    # ---- checks before any work ---------------------------------------------------------
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

    # ---- materials --------------------------------------------------------------------
    def multi_lobe_model(self):
        """``(model, parameters)`` of the material when it is shaded as fitted NDF lobes in a tangent
        frame (anisotropic Ward, Ashikhmin-Shirley), else None (:func:`._shade_materials.multi_lobe_model`)."""
        return multi_lobe_model(self.params, getattr(self, "measured", None), self.name)

    def _upload_materials(self) -> None:
        """The parameters', textures' and run-time BRDFs' materials into the per-vertex buffers."""
        albedo, spec, rough = vertex_surface(self.params, self._specular_rgb, self._albedo_in, self._scene,
                                             self._state.materials, self._radiance.shape[0], self.name)
        self.set_surface(albedo=albedo, specular=spec, roughness=rough)

    def set_surface(self, albedo=None, specular=None, roughness=None) -> None:
        """Write per-vertex material arrays (any of albedo (V, 3), specular (V, 3), roughness (V,))
        into the stage's buffers: the next frame uses them; nothing is recomputed. All are checked
        before any is written (a rejected call changes nothing)."""
        count = self._radiance.shape[0]
        checked = checked_surface(self.params["brdf"], count, self.name, albedo=albedo, specular=specular,
                                  roughness=roughness)
        buffers = {"albedo": self._albedo, "specular": self._spec, "roughness": self._rough}
        for name, a in checked.items():
            buffers[name].assign(a if a.ndim == 1 else a.reshape(count, 3))
        self.surface = buffers

    # ---- lights -----------------------------------------------------------------------
    def _setup_lights(self) -> None:
        """The frame's lights and the run's environment (:mod:`._shade_lights`); sphere lights inside
        a mesh's hull are reported in ``diagnostics()['lights_inside_hull']`` with a warning."""
        self.environment = None
        self._lights = setup_lights(self._frame_lighting, self._environment_in, self._device, self.name)
        self.environment = self._lights.environment
        self.lights_inside_hull = lights_inside_hull(self._ctx.lighting, self._scene, self.name)

    def notify_changed(self, flags, keys=frozenset()) -> bool:
        from ...scene._state import Change

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
    def launch(self, state):
        lights = self._lights.lights
        self._lights.turn()
        self._lobes.update_tangents(self._points, self._normals)

        def inputs(start, stop):
            return [self._vertex_points, self._vertex_materials, lights, self._vis, self._settings, start, self._radiance]

        launch_parallel(kernels.shade_vertices_kernel, self._radiance.shape[0], inputs, self._device,
                        min_count=CPU_CHUNK_MIN)

    def pixel_materials(self, gbuffer) -> dict:
        """The per-vertex materials interpolated at every ray of a G-buffer: ``albedo`` (N, 3),
        ``specular`` (N, 3), ``roughness`` (N,), float32 host arrays (0 for misses)."""
        hits = pixel_hits(gbuffer, gbuffer.normal, self._eye, self._tangents)
        px = interpolated_materials(hits, gbuffer.pixel_count, self._vertex_materials, self._device)
        return {"albedo": px.albedo.numpy(), "specular": px.specular.numpy(), "roughness": px.roughness.numpy()}

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
        hits = pixel_hits(gbuffer, gbuffer.normal, self._eye, self._tangents)
        px = interpolated_materials(hits, n, self._vertex_materials, dev)
        override_pixels(hits, px, gbuffer, dev, self.name, albedo=albedo, specular=specular, roughness=roughness,
                        normals=normals)
        lights = self._lights.lights
        self._lights.turn()
        out = wp.zeros(n, dtype=wp.vec3, device=dev)

        def inputs(start, stop):
            return [hits, px, lights, self._vis, self._settings, start, out]

        launch_parallel(kernels.shade_pixels_kernel, n, inputs, dev, min_count=CPU_CHUNK_MIN)
        return out

    # ---- measuring --------------------------------------------------------------------
    def reference_model(self, materials=None):
        """The ground truth this output is measured against: the glossy reference (specular
        term, Beckmann or Blinn-Phong BRDF, this stage's eye and colour), or the diffuse one
        (:class:`warpshade.measure._protocols.MeasuredStage`)."""
        return self._reference_model(per_pixel=False)

    def pixel_reference_model(self, materials=None):
        """:meth:`reference_model` for a per-pixel reference, which takes the textured roughness
        and colours per pixel (:class:`warpshade.measure._protocols.PixelStage`)."""
        return self._reference_model(per_pixel=True)

    def check_measurable(self, per_pixel: bool = False) -> None:
        """Refuse, from the parameters alone (before any work), what has no ground truth
        (:func:`._shade_reference.check_measurable`; :class:`warpshade.measure._protocols.MeasurableStage`)."""
        check_measurable(self.params, self.name, per_pixel)

    def _reference_model(self, per_pixel: bool):
        """The glossy reference model (:func:`._shade_reference.reference_model`), None for the diffuse component."""
        self.check_measurable(per_pixel)
        if self.params["component"] == "diffuse":
            return None
        eye = self._eye.numpy()[0].astype(np.float64)
        return reference_model(self.params, per_pixel, self.multi_lobe_model(), getattr(self, "measured_path", None),
                               eye, self._specular_rgb, self._spec, self._rough, self.name)

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
