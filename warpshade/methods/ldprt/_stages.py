"""Local, deformable PRT (Sloan, Luna, Snyder 2005) as graph stages.

* ``ldprt.fit`` (precompute): ray-trace diffuse transfer in the per-vertex tangent frame at a
  bake frame and fit ZH lobes per vertex (a fixed count, or the fewest meeting a target error);
  artifacts ``axes`` (V, L, 3), ``coeffs`` (V, L, n), ``counts`` (V,), ``stored`` (V, 4) (DC +
  linear stored exactly), ``fit_error`` (V,).
* ``ldprt.transfer`` (precompute): the local-frame transfer vectors alone (V, n*n), for the
  full-SH-rotation baseline.
* ``ldprt.tangents`` (per frame): tangent frames of the current (deformed) mesh on the device (port
  ``tangents``).
* ``ldprt.shade`` (per frame): rotate each vertex's lobe axes by its frame and shade, either with
  the light-specialised table ``e^(s)`` built from the frame's lighting SH (``evaluation =
  "table"``, eq. 24-25, O(nN) per vertex; the table kernel is launched every frame and rebuilds
  the table whenever the lighting differs from the previous frame's) or by direct SH evaluation
  at the rotated axes (``"direct"``, O(n^2 N)).
* ``ldprt.shade_rotated`` (per frame): the full local SH transfer vector rotated to world per
  vertex (zxzxz SH rotation, O(n^3)), i.e. LDPRT without the ZH approximation.
* ``ldprt.glossy_fit`` / ``ldprt.glossy_shade``: glossy LDPRT (eq. 14-16), BRDF SVD rows times
  the local visibility transfer, fitted with lobes; view-dependent shading toward the camera.
* ``ldprt.membrane`` (precompute): the translucent thin-membrane single lobe (eq. 22-23), shaded
  by ``ldprt.shade`` with ``lobes = 1``.
* ``ldprt.wrinkle_table`` / ``ldprt.wrinkle_shade``: the sinusoidal wrinkle model, fitted over
  (phase, depth) and applied as flutes around an axis of a deforming mesh, the depth driven by
  a static ramp plus the local compression along the axis (groove geometry: :mod:`._wrinkle`).

Radiance = albedo / pi * dot(L, t~), the convention of static PRT (:mod:`warpshade.methods.prt`).
LDPRT rotates transfer with the local surface; it does not model occlusion by distant parts
that move relative to a vertex (see :mod:`._model`).
"""

from __future__ import annotations

import numpy as np

from ..._limits import MAX_FIT_RESTARTS, MAX_LOOKUP_TABLE_WIDTH, MAX_VIEW_RESOLUTION
from ..._wp import launch_parallel, wp
from ...basis.zh import DEFAULT_RIDGE as _RIDGE
from ...basis.sh_warp import sh_kernels
from .._common import ShLighting, order_param, rays_param
from ..stage import FrameStage, Param, Port, PrecomputeStage, StageError, register_stage
from .._viewer import EYE_PARAM, bind_viewer, check_eye, check_viewer
from . import _kernels as kernels
from ._glossy import BRDF_KINDS
from . import _patch_warp as patch_warp
from ._model import STORED_BANDS, fit_transfer, local_transfer
from ._patch import (PATCH_SHAPES, PatchGeometry, PatchModel, bake_patch, interpolate_at_hits, patch_albedo, patch_heights,
                    patch_prims)

#: The ZH fit's search (:func:`warpshade.basis.zh.fit` ``strategy``).
_FIT_STRATEGY = Param("global", str, "ZH fit search: 'global' (variable projection over scanned axis sets, restarts) "
                                     "or 'greedy' (lobe by lobe, then joint BFGS)", choices=("global", "greedy"))

__all__ = [
    "LdprtGlossyFitStage",
    "LdprtGlossyShadeStage",
    "LdprtMembraneStage",
    "LdprtPatchShadeStage",
    "LdprtPatchStage",
    "LdprtWrinkleShadeStage",
    "LdprtWrinkleTableStage",
]

_ORDER = order_param(4, minimum=1, maximum=8)
#: Pixels per CPU chunk below which a per-pixel patch launch is not split over cores.
PIXEL_CHUNK_MIN = 4096
_LOBES = Param(4, int, "lobes per vertex (the maximum when target_error is set)", minimum=1, maximum=8)
_SAMPLES = rays_param(256, "rays per vertex of the transfer simulation")
_FRAME = Param(None, float, "time code of the bake pose (default: the scene's first frame)")


def _bake_frame(ctx, frame):
    return float(ctx.scene.frames[0]) if frame is None else float(frame)


@register_stage
class LdprtFitStage(PrecomputeStage):
    type_name = "ldprt.fit"
    version = 2  # 2: coefficient ridge
    description = "local-frame transfer fitted with ZH lobes per vertex (error-budgeted lobe count)"
    parameters = {
        "order": _ORDER,
        "lobes": _LOBES,
        "samples": _SAMPLES,
        "frame": _FRAME,
        "seed": Param(0, int, "seed of the per-vertex sample rotations"),
        "target_error": Param(None, float, "per-vertex fit error target relative to the RMS transfer norm "
                                           "(None: 'lobes' lobes everywhere)", minimum=0.0),
        "stored_bands": Param("paper", str, "bands stored exactly", choices=tuple(STORED_BANDS)),
        "restarts": Param(2, int, "random multi-starts where the fit error stays high", minimum=0,
                          maximum=MAX_FIT_RESTARTS),
        "restart_error": Param(0.05, float, "relative error above which the multi-start engages", minimum=0.0),
        "ridge": Param(_RIDGE, float, "coefficient ridge mu of the fit (psi + mu |g*|^2; keeps lobes from "
                                      "cancelling with huge coefficients; 0: the paper's objective)", minimum=0.0),
        "fit_strategy": _FIT_STRATEGY,
    }

    def dims(self):
        return {"L": self.params["lobes"], "N": self.params["order"]}

    def output_ports(self):
        return {
            "axes": Port("float32", ("V", "L", 3), "lobe axes, local tangent frame"),
            "coeffs": Port("float32", ("V", "L", "N"), "lobe convolution coefficients g* (one per band)"),
            "counts": Port("int32", ("V",), "lobes used per vertex"),
            "stored": Port("float32", ("V", 4), "exactly stored DC + linear SH, local frame"),
            "fit_error": Port("float32", ("V",), "fit error relative to the RMS transfer norm"),
        }

    def precompute(self, ctx, inputs):
        p = self.params
        t = local_transfer(ctx.scene, _bake_frame(ctx, p["frame"]), p["order"], p["samples"], device=ctx.device,
                           seed=p["seed"], progress=ctx.progress)
        model = fit_transfer(t, p["lobes"], target_error=p["target_error"], stored_bands=p["stored_bands"],
                             restarts=p["restarts"], restart_error=p["restart_error"], seed=p["seed"],
                             ridge=p["ridge"], strategy=p["fit_strategy"])
        self.report = {"histogram": model.histogram, "total_error": model.total_error,
                       "restarted": int(model.restarted.sum()), "fit_seconds": model.seconds}
        return model.arrays()


@register_stage
class LdprtTransferStage(PrecomputeStage):
    type_name = "ldprt.transfer"
    description = "ray-traced diffuse transfer in the per-vertex tangent frame at a bake frame"
    parameters = {"order": _ORDER, "samples": _SAMPLES, "frame": _FRAME,
                  "seed": Param(0, int, "seed of the per-vertex sample rotations")}

    def dims(self):
        return {"C": self.params["order"] ** 2}

    def output_ports(self):
        return {"transfer": Port("float32", ("V", "C"), "diffuse transfer vectors, local tangent frame")}

    def precompute(self, ctx, inputs):
        p = self.params
        t = local_transfer(ctx.scene, _bake_frame(ctx, p["frame"]), p["order"], p["samples"], device=ctx.device,
                           seed=p["seed"], progress=ctx.progress)
        return {"transfer": np.asarray(t, np.float32)}


@register_stage
class LdprtTangentsStage(FrameStage):
    type_name = "ldprt.tangents"
    description = "per-vertex tangent frames of the current pose (rows t, b, n)"

    def input_ports(self):
        return {"points": Port("vec3", ("V",)), "normals": Port("vec3", ("V",))}

    def output_ports(self):
        return {"tangents": Port("mat33", ("V",), "tangent frames, world space, rows (t, b, n)")}

    def setup(self, ctx, inputs):
        from ...geometry._frames import TangentFrames

        self._points, self._normals = inputs["points"], inputs["normals"]
        self._tf = TangentFrames.from_scene(ctx.scene, device=ctx.device)
        self._frames = wp.zeros(ctx.dims["V"], dtype=wp.mat33, device=ctx.device)
        return {"tangents": self._frames}

    def launch(self, state):
        self._tf.compute(self._points, self._normals, out=self._frames)


@register_stage
class LdprtShadeStage(FrameStage):
    type_name = "ldprt.shade"
    description = "shade by ZH lobes rotated with the surface (light-specialised table or direct SH)"
    parameters = {
        "order": _ORDER,
        "lobes": _LOBES,
        "evaluation": Param("table", str, "'table' (e^ look-ups, eq. 24-25) or 'direct' (SH at the axes)",
                            choices=("table", "direct")),
        "table_width": Param(128, int, "longitudes of the e^ table (latitudes: width / 2 + 1)", minimum=8,
                             maximum=MAX_LOOKUP_TABLE_WIDTH),
    }

    def dims(self):
        return {"L": self.params["lobes"], "N": self.params["order"]}

    def input_ports(self):
        return {
            "tangents": Port("mat33", ("V",)),
            "axes": Port("float32", ("V", "L", 3)),
            "coeffs": Port("float32", ("V", "L", "N")),
            "counts": Port("int32", ("V",)),
            "stored": Port("float32", ("V", 4)),
            "albedo": Port("float32", ("V", 3)),
            "lighting": Port("lighting"),
        }

    def output_ports(self):
        return {"radiance": Port("float32", ("V", 3), "outgoing radiance, linear RGB")}

    def setup(self, ctx, inputs):
        order = self.params["order"]
        self._in = inputs
        v = ctx.dims["V"]
        self._axes = wp.array(inputs["axes"].numpy().reshape(v, -1, 3), dtype=wp.vec3, device=ctx.device)
        self._lighting = ShLighting(inputs["lighting"], order)
        width = self.params["table_width"]
        self._table = wp.zeros((width // 2 + 1, width, 3, order), dtype=wp.float32, device=ctx.device)
        self._table_kernel, self._shade_table, self._shade_direct, _ = kernels.shade_kernels(order)
        self._radiance = wp.zeros((v, 3), dtype=wp.float32, device=ctx.device)
        return {"radiance": self._radiance}

    def launch(self, state):
        i, light = self._in, self._lighting
        dev, count = self._radiance.device, self._radiance.shape[0]
        light.launch()
        if self.params["evaluation"] == "table":
            wp.launch(self._table_kernel, dim=self._table.shape[:2], inputs=[light.light, light.changed, self._table],
                      device=dev)
            wp.launch(self._shade_table, dim=count,
                      inputs=[i["tangents"], self._axes, i["coeffs"], i["counts"], i["stored"], self._table, light.light,
                              i["albedo"], self._radiance], device=dev)
        else:
            wp.launch(self._shade_direct, dim=count,
                      inputs=[i["tangents"], self._axes, i["coeffs"], i["counts"], i["stored"], light.light, i["albedo"],
                              self._radiance], device=dev)

    def model_bytes(self) -> int:
        return int(self._table.size * 4) if hasattr(self, "_table") else 0


@register_stage
class LdprtShadeRotatedStage(FrameStage):
    type_name = "ldprt.shade_rotated"
    description = "full local SH transfer rotated to world per vertex (zxzxz), then dotted with the lighting"
    parameters = {"order": _ORDER}

    def dims(self):
        return {"C": self.params["order"] ** 2}

    def input_ports(self):
        return {
            "tangents": Port("mat33", ("V",)),
            "transfer": Port("float32", ("V", "C")),
            "albedo": Port("float32", ("V", 3)),
            "lighting": Port("lighting"),
        }

    def output_ports(self):
        return {"radiance": Port("float32", ("V", 3), "outgoing radiance, linear RGB")}

    def setup(self, ctx, inputs):
        order = self.params["order"]
        self._in = inputs
        self._lighting = ShLighting(inputs["lighting"], order)
        self._kernel = kernels.shade_kernels(order)[3]
        self._tables = sh_kernels(order).tables(ctx.device)
        self._radiance = wp.zeros((ctx.dims["V"], 3), dtype=wp.float32, device=ctx.device)
        return {"radiance": self._radiance}

    def launch(self, state):
        i = self._in
        self._lighting.launch()
        wp.launch(self._kernel, dim=self._radiance.shape[0],
                  inputs=[i["tangents"], i["transfer"], self._tables, self._lighting.light, i["albedo"], self._radiance],
                  device=self._radiance.device)


@register_stage
class LdprtGlossyFitStage(PrecomputeStage):
    type_name = "ldprt.glossy_fit"
    version = 3  # 2: visibility open below the horizon by default; 3: coefficient ridge
    description = "glossy LDPRT: BRDF SVD rows times local visibility transfer, each row fitted with ZH lobes"
    parameters = {
        "order": _ORDER,
        "lobes": Param(3, int, "ZH lobes per BRDF row", minimum=1, maximum=8),
        "rank": Param(3, int, "BRDF rows kept by the SVD (n_b)", minimum=1),
        "brdf": Param("microfacet", str, "BRDF model", choices=BRDF_KINDS),
        "roughness": Param(0.5, float, "microfacet roughness alpha", minimum=1e-3, maximum=2.0),
        "exponent": Param(30.0, float, "Phong / Blinn-Phong exponent", minimum=0.0),
        "f0": Param(0.04, float, "microfacet Fresnel reflectance at normal incidence", minimum=0.0, maximum=1.0),
        "view_resolution": Param(32, int, "view-factor texture size (res x res)", minimum=2, maximum=MAX_VIEW_RESOLUTION),
        "samples": _SAMPLES,
        "frame": _FRAME,
        "seed": Param(0, int, "seed of the per-vertex sample rotations"),
        "restarts": Param(1, int, "random multi-starts where the fit error stays high", minimum=0,
                          maximum=MAX_FIT_RESTARTS),
        "below_horizon": Param("visible", str, "visibility below the tangent plane: 'visible' (the BRDF vanishes "
                               "there; avoids horizon ringing) or 'traced' (the paper's V)",
                               choices=("visible", "traced")),
        "ridge": Param(_RIDGE, float, "coefficient ridge mu of the fit (psi + mu |g*|^2; keeps lobes from "
                                      "cancelling with huge coefficients; 0: the paper's objective)", minimum=0.0),
        "fit_strategy": _FIT_STRATEGY,
    }

    def dims(self):
        p = self.params
        return {"R": p["rank"] * p["lobes"], "B": p["rank"], "N": p["order"], "Q": p["view_resolution"]}

    def output_ports(self):
        return {
            "glossy_axes": Port("float32", ("V", "R", 3), "lobe axes per BRDF row (row-major), local frame"),
            "glossy_coeffs": Port("float32", ("V", "R", "N"), "lobe convolution coefficients"),
            "glossy_stored": Port("float32", ("V", "B", 4), "stored DC + linear SH per BRDF row"),
            "view_factors": Port("float32", ("Q", "Q", "B"), "u(v) texture on the concentric square"),
            "brdf": Port("arrays", (), "the BRDF the rows were made from (glossy.brdf_arrays)"),
        }

    def precompute(self, ctx, inputs):
        from ...scene._materials import factorize
        from ...transfer import compute
        from ._glossy import brdf_arrays, brdf_from_params, fit_glossy

        p = self.params
        if p["rank"] > p["order"] ** 2:
            raise ValueError(f"stage {self.name!r}: rank {p['rank']} exceeds the {p['order'] ** 2} SH coefficients")
        brdf = brdf_from_params(p["brdf"], p["roughness"], p["exponent"], p["f0"])
        fac = factorize(brdf, p["order"], p["rank"], p["view_resolution"])
        vis = compute(ctx.scene, _bake_frame(ctx, p["frame"]), p["order"], p["samples"], space="local",
                      device=ctx.device, seed=p["seed"], below_horizon=p["below_horizon"], progress=ctx.progress).visibility
        model = fit_glossy(vis, fac, p["lobes"], restarts=p["restarts"], seed=p["seed"], ridge=p["ridge"],
                           strategy=p["fit_strategy"])
        v = vis.shape[0]
        self.report = {"svd_truncation_error": fac.truncation_error(), "fit_total_error": model.total_error,
                       "max_lobe_norm_ratio": model.max_lobe_norm_ratio}
        return {
            "glossy_axes": model.axes.reshape(v, -1, 3),
            "glossy_coeffs": model.coeffs.reshape(v, -1, p["order"]),
            "glossy_stored": model.stored,
            "view_factors": fac.view_factors.astype(np.float32),
            "brdf": brdf_arrays(p["brdf"], p["roughness"], p["exponent"], p["f0"]),
        }


@register_stage
class LdprtGlossyShadeStage(FrameStage):
    type_name = "ldprt.glossy_shade"
    description = "view-dependent glossy LDPRT shading (eq. 16) with the light-specialised table"
    parameters = {
        "order": _ORDER,
        "lobes": Param(3, int, "ZH lobes per BRDF row", minimum=1, maximum=8),
        "rank": Param(3, int, "BRDF rows (n_b)", minimum=1),
        "view_resolution": Param(32, int, "view-factor texture size", minimum=2, maximum=MAX_VIEW_RESOLUTION),
        "table_width": Param(128, int, "longitudes of the e^ table", minimum=8, maximum=MAX_LOOKUP_TABLE_WIDTH),
        "specular": Param((1.0, 1.0, 1.0), tuple, "RGB specular colour multiplying r(v)"),
        "eye": EYE_PARAM,
    }

    def __init__(self, name: str, params: dict | None = None):
        super().__init__(name, params)
        self._check_parameters()

    def _check_parameters(self) -> None:
        """What the parameters alone rule out (at construction and at every set-up)."""
        p = self.params
        if len(p["specular"]) != 3:
            raise StageError(f"stage {self.name!r}: parameter 'specular' needs three numbers, got {p['specular']!r}")
        check_eye(self.name, p["eye"])

    def check_scene(self, scene, ctx) -> None:
        """Before any precompute: the parameters and the viewer on this scene (a warning when an
        explicit 'eye' lies below it; :mod:`warpshade.methods._viewer`)."""
        self._check_parameters()
        check_viewer(self.name, self.params["eye"], scene)

    def dims(self):
        p = self.params
        return {"R": p["rank"] * p["lobes"], "B": p["rank"], "N": p["order"], "Q": p["view_resolution"]}

    def input_ports(self):
        return {
            "tangents": Port("mat33", ("V",)),
            "points": Port("vec3", ("V",)),
            "glossy_axes": Port("float32", ("V", "R", 3)),
            "glossy_coeffs": Port("float32", ("V", "R", "N")),
            "glossy_stored": Port("float32", ("V", "B", 4)),
            "view_factors": Port("float32", ("Q", "Q", "B")),
            "brdf": Port("arrays"),
            "lighting": Port("lighting"),
        }

    def output_ports(self):
        return {"radiance": Port("float32", ("V", 3), "glossy exit radiance towards the eye, linear RGB")}

    def setup(self, ctx, inputs):
        p = self.params
        self._check_parameters()
        self._viewer = bind_viewer(self.name, p["eye"], ctx)
        self._eye = self._viewer.eye
        self.follows_state_eye = self._viewer.follows_state_eye
        self._specular = wp.vec3(*[float(x) for x in p["specular"]])
        self._brdf = inputs["brdf"]
        v = ctx.dims["V"]
        self._axes = wp.array(inputs["glossy_axes"].numpy().reshape(v, -1, 3), dtype=wp.vec3, device=ctx.device)
        self._lighting = ShLighting(inputs["lighting"], p["order"])
        width = p["table_width"]
        self._table = wp.zeros((width // 2 + 1, width, 3, p["order"]), dtype=wp.float32, device=ctx.device)
        self._table_kernel = kernels.shade_kernels(p["order"])[0]
        self._kernel = kernels.glossy_kernel(p["order"])
        self._radiance = wp.zeros((v, 3), dtype=wp.float32, device=ctx.device)
        vertices = kernels.GlossyVertices()
        vertices.frames, vertices.points, vertices.axes = inputs["tangents"], inputs["points"], self._axes
        vertices.coeffs, vertices.stored, vertices.lobes = inputs["glossy_coeffs"], inputs["glossy_stored"], p["lobes"]
        shading = kernels.GlossyShading()
        shading.eye, shading.factors, shading.table = self._eye, inputs["view_factors"], self._table
        shading.light, shading.specular = self._lighting.light, self._specular
        self._vertices, self._shading = vertices, shading
        return {"radiance": self._radiance}

    def reference_model(self, materials=None):
        """Glossy ground truth with the fit's BRDF (its ``brdf`` input), the current eye and
        this stage's specular colour (:class:`warpshade.measure._protocols.MeasuredStage`)."""
        from ._glossy import brdf_from_arrays

        return {
            "brdf": brdf_from_arrays(self._brdf),
            "eye": self._eye.numpy()[0].astype(np.float64),
            "color": np.array([self._specular[0], self._specular[1], self._specular[2]], np.float64),
        }

    def notify_changed(self, flags, keys=frozenset()) -> bool:
        from ...scene._state import Change

        if flags & Change.VIEW:
            self._viewer.moved()
        return super().notify_changed(flags, keys)

    def diagnostics(self) -> dict:
        """The viewer (:mod:`warpshade.methods._viewer`: which one, where)."""
        return {"viewer": self._viewer.describe()}

    def launch(self, state):
        light = self._lighting
        dev = self._radiance.device
        light.launch()
        wp.launch(self._table_kernel, dim=self._table.shape[:2], inputs=[light.light, light.changed, self._table],
                  device=dev)
        wp.launch(self._kernel, dim=self._radiance.shape[0], inputs=[self._vertices, self._shading, self._radiance],
                  device=dev)


@register_stage
class LdprtMembraneStage(PrecomputeStage):
    type_name = "ldprt.membrane"
    description = "translucent thin-membrane single lobe about the normal (eq. 22-23), per-vertex translucency"
    parameters = {
        "order": _ORDER,
        "translucency": Param(0.4, float, "translucency alpha (the maximum when thickness_scale is set)",
                              minimum=0.0, maximum=1.0),
        "thickness_scale": Param(None, float, "alpha = translucency * exp(-thickness / scale), thickness ray "
                                              "cast along -n at the bake frame (None: constant alpha)", minimum=1e-9),
        "frame": _FRAME,
    }

    def dims(self):
        return {"L": 1, "N": self.params["order"]}

    def output_ports(self):
        return LdprtFitStage.output_ports(self)

    def precompute(self, ctx, inputs):
        from ._membrane import membrane_model, thickness

        p = self.params
        alpha = np.full(ctx.dims["V"], p["translucency"])
        if p["thickness_scale"] is not None:
            d = thickness(ctx.scene, _bake_frame(ctx, p["frame"]), device=ctx.device)
            alpha = p["translucency"] * np.where(np.isfinite(d), np.exp(-d / p["thickness_scale"]), 1.0)
        self.report = {"translucency_mean": float(alpha.mean()), "translucency_max": float(alpha.max())}
        return membrane_model(alpha, p["order"]).arrays()


@register_stage
class LdprtWrinkleTableStage(PrecomputeStage):
    type_name = "ldprt.wrinkle_table"
    uses_scene = False
    description = "sinusoidal groove transfer ray traced over (phase, depth), fitted with 3 bilinear ZH lobes"
    parameters = {
        "order": Param(4, int, "SH order n", minimum=3, maximum=8),
        "samples": rays_param(512, "rays per groove sample"),
        "phase_samples": Param(32, int, "phases traced per groove period", minimum=4),
        "depth_samples": Param(10, int, "depths traced from 0 to max_depth", minimum=2),
        "phase_controls": Param(16, int, "control points of the bilinear model in phase (periodic)", minimum=2),
        "depth_controls": Param(6, int, "control points in depth", minimum=2),
        "max_depth": Param(0.5, float, "deepest groove, in groove periods", minimum=1e-3),
        "method": Param("CG", str, "optimiser of the joint fit", choices=("CG", "L-BFGS-B")),
        "iterations": Param(300, int, "optimiser iterations", minimum=1),
    }

    def dims(self):
        p = self.params
        return {"PX": p["phase_controls"], "PD": p["depth_controls"], "N": p["order"]}

    def output_ports(self):
        return {
            "wrinkle_axes": Port("float32", ("PX", "PD", 3, 3), "lobe axes (groove frame), control grid"),
            "wrinkle_coeffs": Port("float32", ("PX", "PD", 3, "N"), "lobe coefficients, control grid"),
            "wrinkle_stored": Port("float32", ("PX", "PD", 4), "DC + linear SH, control grid"),
        }

    def precompute(self, ctx, inputs):
        from ._wrinkle import fit_wrinkle_table, groove_transfer

        p = self.params
        depths = np.linspace(0.0, p["max_depth"], p["depth_samples"])
        t = groove_transfer(p["order"], p["phase_samples"], depths, p["samples"], device=ctx.device)
        table = fit_wrinkle_table(t, p["max_depth"], p["phase_controls"], p["depth_controls"], p["method"],
                                  p["iterations"])
        self.report = {"sample_error": table.sample_error, "independent_error": table.independent_error,
                       "initial_error": table.initial_error, "iterations": table.iterations}
        return {"wrinkle_axes": table.axes.astype(np.float32), "wrinkle_coeffs": table.coeffs.astype(np.float32),
                "wrinkle_stored": table.stored.astype(np.float32)}


@register_stage
class LdprtWrinkleShadeStage(FrameStage):
    type_name = "ldprt.wrinkle_shade"
    description = "shade a smooth deforming surface with sinusoidal wrinkle transfer (flutes along an axis)"
    parameters = {
        "order": Param(4, int, "SH order n (the wrinkle table's)", minimum=3, maximum=8),
        "phase_controls": Param(16, int, "the wrinkle table's phase controls", minimum=2),
        "depth_controls": Param(6, int, "the wrinkle table's depth controls", minimum=2),
        "max_depth": Param(0.5, float, "the wrinkle table's deepest groove (groove periods)", minimum=1e-3),
        "grooves": Param(6, int, "grooves around the axis", minimum=1),
        "axis": Param((0.0, 0.0, 1.0), tuple, "groove (flute) direction at rest, world"),
        "center": Param((0.0, 0.0, 0.0), tuple, "a point on the groove axis at rest, world"),
        "depth_range": Param((0.0, 0.5), tuple, "static depth at the two ends of the axis (groove periods)"),
        "compression_gain": Param(2.0, float, "extra depth per unit of compression along the axis", minimum=0.0),
    }

    def dims(self):
        p = self.params
        return {"PX": p["phase_controls"], "PD": p["depth_controls"], "N": p["order"]}

    def input_ports(self):
        return {
            "tangents": Port("mat33", ("V",)),
            "points": Port("vec3", ("V",)),
            "wrinkle_axes": Port("float32", ("PX", "PD", 3, 3)),
            "wrinkle_coeffs": Port("float32", ("PX", "PD", 3, "N")),
            "wrinkle_stored": Port("float32", ("PX", "PD", 4)),
            "albedo": Port("float32", ("V", 3)),
            "lighting": Port("lighting"),
        }

    def output_ports(self):
        return {"radiance": Port("float32", ("V", 3), "outgoing radiance, linear RGB"),
                "depth": Port("float32", ("V",), "wrinkle depth per vertex (groove periods)")}

    def setup(self, ctx, inputs):
        p = self.params
        for key in ("axis", "center", "depth_range"):
            if len(p[key]) != (2 if key == "depth_range" else 3):
                raise ValueError(f"stage {self.name!r}: parameter {key!r} has the wrong length: {p[key]!r}")
        from ._wrinkle import groove_layout

        dev = ctx.device
        layout = groove_layout(ctx.scene, p["axis"], p["center"], p["grooves"], p["depth_range"])
        self._layout = {k: wp.array(v.astype(np.int32 if k == "axis_neighbour" else np.float32), device=dev)
                        for k, v in layout.items()}
        self._in = inputs
        axes = inputs["wrinkle_axes"].numpy()
        self._table_axes = wp.array(axes.reshape(axes.shape[0], axes.shape[1], 3, 3), dtype=wp.vec3, device=dev)
        self._lighting = ShLighting(inputs["lighting"], p["order"])
        self._depth_kernel, self._shade = kernels.wrinkle_kernels(p["order"])
        v = ctx.dims["V"]
        self._depth = wp.zeros(v, dtype=wp.float32, device=dev)
        self._radiance = wp.zeros((v, 3), dtype=wp.float32, device=dev)
        vertices = kernels.WrinkleVertices()
        vertices.frames, vertices.phase = inputs["tangents"], self._layout["phase"]
        vertices.groove_angle, vertices.depth, vertices.albedo = self._layout["groove_angle"], self._depth, inputs["albedo"]
        table = kernels.WrinkleTable()
        table.axes, table.coeffs, table.stored = self._table_axes, inputs["wrinkle_coeffs"], inputs["wrinkle_stored"]
        table.max_depth = p["max_depth"]
        self._vertices, self._wrinkle_table = vertices, table
        return {"radiance": self._radiance, "depth": self._depth}

    def launch(self, state):
        p, i, lay = self.params, self._in, self._layout
        dev, v = self._radiance.device, self._radiance.shape[0]
        self._lighting.launch()
        wp.launch(self._depth_kernel, dim=v, inputs=[i["points"], lay["axis_neighbour"], lay["rest_length"],
                                                     lay["base_depth"], p["compression_gain"], p["max_depth"],
                                                     self._depth], device=dev)
        wp.launch(self._shade, dim=v, inputs=[self._vertices, self._wrinkle_table, self._lighting.light, self._radiance],
                  device=dev)


@register_stage
class LdprtPatchStage(PrecomputeStage):
    type_name = "ldprt.patch"
    version = 2  # 2: per-texel albedo
    description = "tileable height-field patch: transfer ray traced per texel over its tiled copies, ZH lobes per texel"
    #: A 32^2 patch traced at 256 rays and fitted per texel takes ~20 s: an 8^2 patch with 32 rays
    #: runs the same stages.
    quick = {"resolution": 8, "samples": 32}
    parameters = {
        "shape": Param("bumps", str, "height field", choices=PATCH_SHAPES),
        "texture": Param(None, str, "albedo image (relative to the graph) whose luminance is the height, for "
                         "shape = 'texture' (dark = low)"),
        "texture_albedo": Param(True, bool, "shape = 'texture': the image is also the patch's albedo (multiplying "
                                "the surface's), as the paper's patches"),
        "resolution": Param(32, int, "texels per side", minimum=4, maximum=256),
        "height": Param(0.15, float, "peak-to-valley relief in patch widths", minimum=0.0, maximum=4.0),
        "tiles": Param(3, int, "copies per side the transfer is traced over (odd)", minimum=1, maximum=9),
        "order": _ORDER,
        "lobes": _LOBES,
        "samples": _SAMPLES,
        "target_error": Param(0.05, float, "per-texel fit error target relative to the RMS transfer norm (None: "
                              "'lobes' lobes everywhere)", minimum=0.0),
        "seed": Param(0, int, "seed of the per-texel sample rotations and the fit's restarts"),
    }

    def __init__(self, name, params=None):
        super().__init__(name, params)
        self.uses_scene = False  # the patch is the same on every surface

    def output_ports(self):
        return {"patch": Port("arrays", (), "per-texel heights and ZH lobes (patch frame: x along u, y along v, z up)")}

    def cache_params(self):
        return {k: v for k, v in self.params.items() if k != "texture"}

    def _image(self, ctx):
        """The ``texture`` file's pixels (any texture format, or a .npy height array), float64."""
        from ...io._textures import read_texture_file

        path = self.params["texture"]
        if path is None:
            return None
        p = ctx.resolve_path(path)
        if not p.exists():
            raise StageError(f"stage {self.name!r}: parameter 'texture': no such file {p}")
        try:
            img, eight_bit = (np.load(p), False) if p.suffix == ".npy" else read_texture_file(p)
            img = np.asarray(img, np.float64)
        except (OSError, ValueError) as exc:
            raise StageError(f"stage {self.name!r}: parameter 'texture': {exc}") from None
        self._eight_bit = bool(eight_bit)
        if not np.all(np.isfinite(img)):
            raise StageError(f"stage {self.name!r}: parameter 'texture' ({p}) holds {int(np.sum(~np.isfinite(img)))} "
                             "non-finite values (NaN or inf): no height can be derived from them")
        return img

    def cache_key(self, ctx):
        import hashlib

        path = self.params["texture"]
        return {} if path is None else {"texture": hashlib.sha256(ctx.resolve_path(path).read_bytes()).hexdigest()}

    def precompute(self, ctx, inputs):
        p = self.params
        try:
            image = self._image(ctx)
            heights = patch_heights(p["shape"], p["resolution"], p["height"], image)
            albedo = (patch_albedo(image, p["resolution"], self._eight_bit)
                      if p["shape"] == "texture" and p["texture_albedo"] else None)
            model, self.report = bake_patch(heights, p["order"], p["samples"], p["lobes"], p["target_error"], p["tiles"],
                                            ctx.device, p["seed"], albedo=albedo)
        except ValueError as exc:
            raise StageError(f"stage {self.name!r}: {exc}") from None
        return {"patch": model.arrays()}

    def check_artifact(self, outputs):
        PatchModel.from_arrays(outputs["patch"])


@register_stage
class LdprtPatchShadeStage(FrameStage):
    type_name = "ldprt.patch_shade"
    description = "an LDPRT patch mapped by UV onto the deforming surface, lobes in the UV tangent frame (per pixel)"
    parameters = {
        "tiling": Param(4.0, float, "patch repeats per unit of UV", minimum=1e-3, maximum=1e4),
        "prims": Param("", str, "meshes carrying the patch, comma-separated paths (default: every mesh with UVs)"),
        "detail": Param("patch", str, "'patch', or 'none': the surface without the relief (unshadowed, the patch's "
                        "albedo kept), to compare",
                        choices=("patch", "none")),
        "parallax": Param(True, bool, "per pixel, march the view ray through the heights and shade the texel it "
                          "meets (false: the texel at the UV, the paper's look-up, no parallax or masking)"),
        "reference_levels": Param(None, int, "midpoint subdivisions of the displaced surface the per-pixel ground "
                                  "truth is traced on (default: a fine edge per patch texel)", minimum=0, maximum=6),
    }

    def input_ports(self):
        return {"patch": Port("arrays"), "points": Port("vec3", ("V",)), "normals": Port("vec3", ("V",)),
                "albedo": Port("float32", ("V", 3)), "lighting": Port("lighting")}

    def output_ports(self):
        return {"radiance": Port("float32", ("V", 3), "outgoing radiance, linear RGB")}

    def setup(self, ctx, inputs):
        dev = ctx.device
        try:
            self.patch = PatchModel.from_arrays(inputs["patch"])
            self.prims = patch_prims(ctx.scene, self.params["prims"])
        except ValueError as exc:
            raise StageError(f"stage {self.name!r}: {exc}") from None
        self._scene, self._device, self._geometry = ctx.scene, dev, None
        order = self.patch.order
        self._lighting = ShLighting(inputs["lighting"], order)
        uvs, patched = np.zeros((ctx.dims["V"], 2), np.float32), np.zeros(ctx.dims["V"], np.int32)
        for m in ctx.scene.meshes:
            if m.path in self.prims:
                uvs[m.vertex_offset:m.vertex_offset + m.vertex_count] = m.uvs
                patched[m.vertex_offset:m.vertex_offset + m.vertex_count] = 1
        self._surface = patch_warp.patch_surface(ctx.scene.faces, uvs, patched, inputs["albedo"], dev)
        shaded = self.patch if self.params["detail"] == "patch" else self.patch.flattened()
        self._texture = patch_warp.patch_texture(shaded, self.params["tiling"], dev, self.params["parallax"])
        self._points, self._normals = inputs["points"], inputs["normals"]
        self._shade_vertices, self._shade_pixels = patch_warp.patch_kernels(order)
        self._radiance = wp.zeros((ctx.dims["V"], 3), dtype=wp.float32, device=dev)
        return {"radiance": self._radiance}

    def launch(self, state):
        dev, s = self._device, self._surface
        self._lighting.launch()
        patch_warp.update_tangents(self._points, s, dev)
        wp.launch(self._shade_vertices, dim=s.tangents.shape[0],
                  inputs=[self._normals, s, self._texture, self._lighting.light, self._radiance], device=dev)

    def pixel_materials(self, gbuffer) -> dict:
        """The per-vertex albedo interpolated at every ray of a G-buffer: ``{"albedo": (N, 3) float32}``."""
        return {"albedo": interpolate_at_hits(gbuffer, self._surface.albedo.numpy())}

    def render_pixels(self, gbuffer, albedo=None, specular=None, roughness=None, normals=None):
        """Shade every ray of a G-buffer of the current frame (:mod:`._patch_warp`); ``albedo``
        (N, 3) and ``normals`` (N, 3) unit vectors replace the interpolated ones (``specular`` and
        ``roughness`` have no meaning for this diffuse stage and are refused). Returns wp.array(vec3)."""
        dev, n = self._device, gbuffer.pixel_count
        if specular is not None or roughness is not None:
            raise StageError(f"stage {self.name!r}: render_pixels takes no specular or roughness (diffuse patch shading)")
        normal = gbuffer.normal
        if normals is not None:
            a = np.asarray(normals, np.float32)
            if a.shape != (n, 3) or not np.all(np.isfinite(a)):
                raise StageError(f"stage {self.name!r}: render_pixels normals must be finite, shape {(n, 3)}; got {a.shape}")
            normal = wp.array(a, dtype=wp.vec3, device=dev)
        use = albedo is not None
        px = np.zeros((n, 3), np.float32) if albedo is None else np.asarray(albedo, np.float32)
        if px.shape != (n, 3) or not np.all(np.isfinite(px)) or np.any(px < 0):
            raise StageError(f"stage {self.name!r}: render_pixels albedo must be finite, non-negative, shape {(n, 3)}")
        out = wp.zeros(n, dtype=wp.vec3, device=dev)
        pixel_albedo = wp.array(px, dtype=wp.vec3, device=dev)

        def chunk(start, stop):
            return [gbuffer.hit, normal, gbuffer.face, gbuffer.bary, gbuffer.direction, self._surface, self._texture,
                    self._lighting.light, pixel_albedo, int(use), start, out]

        launch_parallel(self._shade_pixels, n, chunk, dev, min_count=PIXEL_CHUNK_MIN)
        return out

    def pixel_reference_model(self, materials=None) -> dict:
        """The per-pixel ground truth: the diffuse reference traced on the displaced fine mesh
        (:class:`._patch.PatchGeometry`: ``geometry(frame)`` is its scene at a frame), measured
        over the pixels of the patched ``prims``."""
        if self._geometry is None:
            self._geometry = PatchGeometry(self._scene, self.patch.heights, self.params["tiling"], self.prims,
                                           self.params["reference_levels"], albedo=self.patch.albedo)
        return {"include": ("diffuse",), "geometry": self._geometry.scene_at, "prims": list(self.prims)}

    def diagnostics(self) -> dict:
        counts = np.bincount(self.patch.counts)
        out = {"texels": int(self.patch.counts.size), "lobes": {int(k): int(c) for k, c in enumerate(counts) if c},
               "prims": list(self.prims)}
        if self._geometry is not None:
            out["reference_levels"], out["patch_size"] = self._geometry.levels, self._geometry.patch_size
        return out

    def model_bytes(self) -> int:
        p = self.patch
        return int(p.axes.nbytes + p.coeffs.nbytes + p.counts.nbytes + p.stored.nbytes)
