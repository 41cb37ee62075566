"""Local, deformable PRT (Sloan, Luna, Snyder 2005) as graph stages.

* ``ldprt.fit`` (precompute): ray-trace diffuse transfer in the per-vertex tangent frame at a
  bake frame and fit ZH lobes per vertex (a fixed count, or the fewest meeting a target error);
  artifacts ``axes`` (V, L, 3), ``coeffs`` (V, L, n), ``counts`` (V,), ``stored`` (V, 4) (DC +
  linear stored exactly), ``fit_error`` (V,).
* ``ldprt.transfer`` (precompute): the local-frame transfer vectors alone (V, n*n), for the
  full-SH-rotation baseline.
* ``ldprt.frames`` (per frame): tangent frames of the current (deformed) mesh on the device.
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
  a static ramp plus the local compression along the axis.

Radiance = albedo / pi * dot(L, t~), the convention of static PRT (:mod:`warpshade.methods.prt`).
LDPRT rotates transfer with the local surface; it does not model occlusion by distant parts
that move relative to a vertex (see :mod:`.model`).
"""

from __future__ import annotations

import numpy as np

from ..._wp import wp
from ...basis.zh import DEFAULT_RIDGE as _RIDGE
from ...basis.sh_warp import sh_kernels
from ..stage import Param, Port, Stage, register_stage
from ..upload import LightingUpload
from . import kernels
from .model import STORED_BANDS, fit_transfer, local_transfer

__all__ = [
    "FitStage",
    "FramesStage",
    "GlossyFitStage",
    "GlossyShadeStage",
    "LocalTransferStage",
    "MembraneStage",
    "RotatedShadeStage",
    "ShadeStage",
    "WrinkleShadeStage",
    "WrinkleTableStage",
    "groove_layout",
]

_ORDER = Param(4, int, "SH order n (n*n coefficients)", minimum=1, maximum=8)
_LOBES = Param(4, int, "lobes per vertex (the maximum when target_error is set)", minimum=1, maximum=8)
_SAMPLES = Param(256, int, "rays per vertex of the transfer simulation", minimum=16)
_FRAME = Param(None, float, "time code of the bake pose (default: the scene's first frame)")


def _bake_frame(ctx, frame):
    return float(ctx.scene.frames[0]) if frame is None else float(frame)


@register_stage
class FitStage(Stage):
    type_name = "ldprt.fit"
    kind = "precompute"
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
        "restarts": Param(2, int, "random multi-starts where the fit error stays high", minimum=0),
        "restart_error": Param(0.05, float, "relative error above which the multi-start engages", minimum=0.0),
        "ridge": Param(_RIDGE, float, "coefficient ridge mu of the fit (psi + mu |g*|^2; keeps lobes from "
                                      "cancelling with huge coefficients; 0: the paper's objective)", minimum=0.0),
    }

    def dims(self):
        n = self.params["order"]
        return {"L": self.params["lobes"], "K": n}

    def output_ports(self):
        return {
            "axes": Port("float32", ("V", "L", 3), "lobe axes, local tangent frame"),
            "coeffs": Port("float32", ("V", "L", "K"), "lobe convolution coefficients g*"),
            "counts": Port("int32", ("V",), "lobes used per vertex"),
            "stored": Port("float32", ("V", 4), "exactly stored DC + linear SH, local frame"),
            "fit_error": Port("float32", ("V",), "fit error relative to the RMS transfer norm"),
        }

    def precompute(self, ctx, inputs):
        p = self.params
        t = local_transfer(ctx.scene, _bake_frame(ctx, p["frame"]), p["order"], p["samples"], device=ctx.device,
                           seed=p["seed"])
        model = fit_transfer(t, p["lobes"], target_error=p["target_error"], stored_bands=p["stored_bands"],
                             restarts=p["restarts"], restart_error=p["restart_error"], seed=p["seed"],
                             ridge=p["ridge"])
        self.report = {"histogram": model.histogram, "total_error": model.total_error,
                       "restarted": int(model.restarted.sum()), "fit_seconds": model.seconds}
        return model.arrays()


@register_stage
class LocalTransferStage(Stage):
    type_name = "ldprt.transfer"
    kind = "precompute"
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
                           seed=p["seed"])
        return {"transfer": np.asarray(t, np.float32)}


@register_stage
class FramesStage(Stage):
    type_name = "ldprt.frames"
    kind = "frame"
    description = "per-vertex tangent frames of the current pose (rows t, b, n)"

    def input_ports(self):
        return {"points": Port("vec3", ("V",)), "normals": Port("vec3", ("V",))}

    def output_ports(self):
        return {"frames": Port("mat33", ("V",), "tangent frames, world space, rows (t, b, n)")}

    def setup(self, ctx, inputs):
        from ...geometry.frames import TangentFrames

        self._points, self._normals = inputs["points"], inputs["normals"]
        self._tf = TangentFrames.from_scene(ctx.scene, device=ctx.device)
        self._frames = wp.zeros(ctx.dims["V"], dtype=wp.mat33, device=ctx.device)
        return {"frames": self._frames}

    def launch(self, ctx):
        self._tf.compute(self._points, self._normals, out=self._frames)


class _Light:
    """The frame's world lighting SH in a fixed device buffer with a device ``changed`` flag
    (:class:`~warpshade.methods.upload.LightingUpload`)."""

    def _alloc_light(self, ctx, order):
        self._lighting = LightingUpload(order, ctx.device)
        self._light, self._changed = self._lighting.light, self._lighting.changed

    def _upload_light(self, ctx, order):
        self._lighting.upload(ctx.lighting_sh(order))


@register_stage
class ShadeStage(Stage, _Light):
    type_name = "ldprt.shade"
    kind = "frame"
    description = "shade by ZH lobes rotated with the surface (light-specialised table or direct SH)"
    parameters = {
        "order": _ORDER,
        "lobes": _LOBES,
        "evaluation": Param("table", str, "'table' (e^ look-ups, eq. 24-25) or 'direct' (SH at the axes)",
                            choices=("table", "direct")),
        "table_width": Param(128, int, "longitudes of the e^ table (latitudes: width / 2 + 1)", minimum=8),
    }

    def dims(self):
        return {"L": self.params["lobes"], "K": self.params["order"]}

    def input_ports(self):
        return {
            "frames": Port("mat33", ("V",)),
            "axes": Port("float32", ("V", "L", 3)),
            "coeffs": Port("float32", ("V", "L", "K")),
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
        self._alloc_light(ctx, order)
        width = self.params["table_width"]
        self._table = wp.zeros((width // 2 + 1, width, 3, order), dtype=wp.float32, device=ctx.device)
        self._table_kernel, self._shade_table, self._shade_direct, _ = kernels.shade_kernels(order)
        self._radiance = wp.zeros((v, 3), dtype=wp.float32, device=ctx.device)
        return {"radiance": self._radiance}

    def prepare(self, ctx, frame):
        self._upload_light(ctx, self.params["order"])

    def launch(self, ctx):
        i = self._in
        dev = ctx.device
        if self.params["evaluation"] == "table":
            wp.launch(self._table_kernel, dim=self._table.shape[:2], inputs=[self._light, self._changed, self._table],
                      device=dev)
            wp.launch(self._shade_table, dim=ctx.dims["V"],
                      inputs=[i["frames"], self._axes, i["coeffs"], i["counts"], i["stored"], self._table, self._light,
                              i["albedo"], self._radiance], device=dev)
        else:
            wp.launch(self._shade_direct, dim=ctx.dims["V"],
                      inputs=[i["frames"], self._axes, i["coeffs"], i["counts"], i["stored"], self._light, i["albedo"],
                              self._radiance], device=dev)

    def model_bytes(self) -> int:
        return int(self._table.size * 4) if hasattr(self, "_table") else 0


@register_stage
class RotatedShadeStage(Stage, _Light):
    type_name = "ldprt.shade_rotated"
    kind = "frame"
    description = "full local SH transfer rotated to world per vertex (zxzxz), then dotted with the lighting"
    parameters = {"order": _ORDER}

    def dims(self):
        return {"C": self.params["order"] ** 2}

    def input_ports(self):
        return {
            "frames": Port("mat33", ("V",)),
            "transfer": Port("float32", ("V", "C")),
            "albedo": Port("float32", ("V", 3)),
            "lighting": Port("lighting"),
        }

    def output_ports(self):
        return {"radiance": Port("float32", ("V", 3), "outgoing radiance, linear RGB")}

    def setup(self, ctx, inputs):
        order = self.params["order"]
        self._in = inputs
        self._alloc_light(ctx, order)
        self._kernel = kernels.shade_kernels(order)[3]
        self._tables = sh_kernels(order).tables(ctx.device)
        self._radiance = wp.zeros((ctx.dims["V"], 3), dtype=wp.float32, device=ctx.device)
        return {"radiance": self._radiance}

    def prepare(self, ctx, frame):
        self._upload_light(ctx, self.params["order"])

    def launch(self, ctx):
        i = self._in
        wp.launch(self._kernel, dim=ctx.dims["V"],
                  inputs=[i["frames"], i["transfer"], self._tables, self._light, i["albedo"], self._radiance],
                  device=ctx.device)


_BRDFS = ("microfacet", "beckmann", "phong", "blinn-phong", "lambert")


@register_stage
class GlossyFitStage(Stage):
    type_name = "ldprt.glossy_fit"
    kind = "precompute"
    version = 3  # 2: visibility open below the horizon by default; 3: coefficient ridge
    description = "glossy LDPRT: BRDF SVD rows times local visibility transfer, each row fitted with ZH lobes"
    parameters = {
        "order": _ORDER,
        "lobes": Param(3, int, "ZH lobes per BRDF row", minimum=1, maximum=8),
        "rank": Param(3, int, "BRDF rows kept by the SVD (n_b)", minimum=1),
        "brdf": Param("microfacet", str, "BRDF model", choices=_BRDFS),
        "roughness": Param(0.5, float, "microfacet roughness alpha", minimum=1e-3, maximum=2.0),
        "exponent": Param(30.0, float, "Phong / Blinn-Phong exponent", minimum=0.0),
        "f0": Param(0.04, float, "microfacet Fresnel reflectance at normal incidence", minimum=0.0, maximum=1.0),
        "view_resolution": Param(32, int, "view-factor texture size (res x res)", minimum=2),
        "samples": _SAMPLES,
        "frame": _FRAME,
        "seed": Param(0, int, "seed of the per-vertex sample rotations"),
        "restarts": Param(1, int, "random multi-starts where the fit error stays high", minimum=0),
        "below_horizon": Param("visible", str, "visibility below the tangent plane: 'visible' (the BRDF vanishes "
                               "there; avoids horizon ringing) or 'traced' (the paper's V)",
                               choices=("visible", "traced")),
        "ridge": Param(_RIDGE, float, "coefficient ridge mu of the fit (psi + mu |g*|^2; keeps lobes from "
                                      "cancelling with huge coefficients; 0: the paper's objective)", minimum=0.0),
    }

    def dims(self):
        p = self.params
        return {"R": p["rank"] * p["lobes"], "B": p["rank"], "K": p["order"], "Q": p["view_resolution"]}

    def output_ports(self):
        return {
            "glossy_axes": Port("float32", ("V", "R", 3), "lobe axes per BRDF row (row-major), local frame"),
            "glossy_coeffs": Port("float32", ("V", "R", "K"), "lobe convolution coefficients"),
            "glossy_stored": Port("float32", ("V", "B", 4), "stored DC + linear SH per BRDF row"),
            "view_factors": Port("float32", ("Q", "Q", "B"), "u(v) texture on the concentric square"),
        }

    def precompute(self, ctx, inputs):
        from ...scene.materials import factorize
        from ...transfer import compute
        from .glossy import brdf_from_params, fit_glossy

        p = self.params
        if p["rank"] > p["order"] ** 2:
            raise ValueError(f"stage {self.name!r}: rank {p['rank']} exceeds the {p['order'] ** 2} SH coefficients")
        brdf = brdf_from_params(p["brdf"], p["roughness"], p["exponent"], p["f0"])
        fac = factorize(brdf, p["order"], p["rank"], p["view_resolution"])
        vis = compute(ctx.scene, _bake_frame(ctx, p["frame"]), p["order"], p["samples"], space="local",
                      device=ctx.device, seed=p["seed"], below_horizon=p["below_horizon"]).visibility
        model = fit_glossy(vis, fac, p["lobes"], restarts=p["restarts"], seed=p["seed"], ridge=p["ridge"])
        v = vis.shape[0]
        self.report = {"svd_truncation_error": fac.truncation_error(), "fit_total_error": model.total_error,
                       "max_lobe_norm_ratio": model.max_lobe_norm_ratio}
        return {
            "glossy_axes": model.axes.reshape(v, -1, 3),
            "glossy_coeffs": model.coeffs.reshape(v, -1, p["order"]),
            "glossy_stored": model.stored,
            "view_factors": fac.view_factors.astype(np.float32),
        }


@register_stage
class GlossyShadeStage(Stage, _Light):
    type_name = "ldprt.glossy_shade"
    kind = "frame"
    description = "view-dependent glossy LDPRT shading (eq. 16) with the light-specialised table"
    parameters = {
        "order": _ORDER,
        "lobes": Param(3, int, "ZH lobes per BRDF row", minimum=1, maximum=8),
        "rank": Param(3, int, "BRDF rows (n_b)", minimum=1),
        "view_resolution": Param(32, int, "view-factor texture size", minimum=2),
        "table_width": Param(128, int, "longitudes of the e^ table", minimum=8),
        "specular": Param((1.0, 1.0, 1.0), tuple, "RGB specular colour multiplying r(v)"),
        "eye": Param(None, tuple, "viewer position, world (default: the scene camera)"),
    }

    def dims(self):
        p = self.params
        return {"R": p["rank"] * p["lobes"], "B": p["rank"], "K": p["order"], "Q": p["view_resolution"]}

    def input_ports(self):
        return {
            "frames": Port("mat33", ("V",)),
            "points": Port("vec3", ("V",)),
            "glossy_axes": Port("float32", ("V", "R", 3)),
            "glossy_coeffs": Port("float32", ("V", "R", "K")),
            "glossy_stored": Port("float32", ("V", "B", 4)),
            "view_factors": Port("float32", ("Q", "Q", "B")),
            "lighting": Port("lighting"),
        }

    def output_ports(self):
        return {"radiance": Port("float32", ("V", 3), "glossy exit radiance towards the eye, linear RGB")}

    def setup(self, ctx, inputs):
        p = self.params
        eye = p["eye"]
        if eye is None:
            if ctx.scene.camera is None:
                raise ValueError(f"stage {self.name!r}: the scene has no camera; set the 'eye' parameter")
            eye = ctx.scene.camera.position
        if len(eye) != 3 or len(p["specular"]) != 3:
            raise ValueError(f"stage {self.name!r}: 'eye' and 'specular' need three numbers")
        self._eye = wp.vec3(*[float(x) for x in eye])
        self._specular = wp.vec3(*[float(x) for x in p["specular"]])
        self._in = inputs
        v = ctx.dims["V"]
        self._axes = wp.array(inputs["glossy_axes"].numpy().reshape(v, -1, 3), dtype=wp.vec3, device=ctx.device)
        self._alloc_light(ctx, p["order"])
        width = p["table_width"]
        self._table = wp.zeros((width // 2 + 1, width, 3, p["order"]), dtype=wp.float32, device=ctx.device)
        self._table_kernel = kernels.shade_kernels(p["order"])[0]
        self._kernel = kernels.glossy_kernel(p["order"])
        self._radiance = wp.zeros((v, 3), dtype=wp.float32, device=ctx.device)
        return {"radiance": self._radiance}

    def prepare(self, ctx, frame):
        self._upload_light(ctx, self.params["order"])

    def reference_model(self, runtime):
        """Glossy ground truth with the fit stage's BRDF, this stage's eye and specular colour."""
        from .glossy import brdf_from_params

        provider = runtime.wiring[self.name]["view_factors"].provider
        fit = next(s for s in runtime.stages if s.name == provider)
        p = fit.params
        return {
            "brdf": brdf_from_params(p["brdf"], p["roughness"], p["exponent"], p["f0"]),
            "eye": np.array([self._eye[0], self._eye[1], self._eye[2]], np.float64),
            "color": np.array([self._specular[0], self._specular[1], self._specular[2]], np.float64),
        }

    def launch(self, ctx):
        i = self._in
        dev = ctx.device
        wp.launch(self._table_kernel, dim=self._table.shape[:2], inputs=[self._light, self._changed, self._table],
                  device=dev)
        wp.launch(self._kernel, dim=ctx.dims["V"],
                  inputs=[i["frames"], i["points"], self._eye, self._axes, i["glossy_coeffs"], i["glossy_stored"],
                          self.params["lobes"], i["view_factors"], self._table, self._light, self._specular,
                          self._radiance], device=dev)


@register_stage
class MembraneStage(Stage):
    type_name = "ldprt.membrane"
    kind = "precompute"
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
        return {"L": 1, "K": self.params["order"]}

    def output_ports(self):
        return FitStage.output_ports(self)

    def precompute(self, ctx, inputs):
        from .membrane import membrane_model, thickness

        p = self.params
        alpha = np.full(ctx.dims["V"], p["translucency"])
        if p["thickness_scale"] is not None:
            d = thickness(ctx.scene, _bake_frame(ctx, p["frame"]), device=ctx.device)
            alpha = p["translucency"] * np.where(np.isfinite(d), np.exp(-d / p["thickness_scale"]), 1.0)
        self.report = {"translucency_mean": float(alpha.mean()), "translucency_max": float(alpha.max())}
        return membrane_model(alpha, p["order"]).arrays()


@register_stage
class WrinkleTableStage(Stage):
    type_name = "ldprt.wrinkle_table"
    kind = "precompute"
    uses_scene = False
    description = "sinusoidal groove transfer ray traced over (phase, depth), fitted with 3 bilinear ZH lobes"
    parameters = {
        "order": Param(4, int, "SH order n", minimum=3, maximum=8),
        "samples": Param(512, int, "rays per groove sample", minimum=16),
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
        return {"PX": p["phase_controls"], "PD": p["depth_controls"], "K": p["order"]}

    def output_ports(self):
        return {
            "wrinkle_axes": Port("float32", ("PX", "PD", 3, 3), "lobe axes (groove frame), control grid"),
            "wrinkle_coeffs": Port("float32", ("PX", "PD", 3, "K"), "lobe coefficients, control grid"),
            "wrinkle_stored": Port("float32", ("PX", "PD", 4), "DC + linear SH, control grid"),
        }

    def precompute(self, ctx, inputs):
        from .wrinkle import fit_wrinkle_table, groove_transfer

        p = self.params
        depths = np.linspace(0.0, p["max_depth"], p["depth_samples"])
        t = groove_transfer(p["order"], p["phase_samples"], depths, p["samples"], device=ctx.device)
        table = fit_wrinkle_table(t, p["max_depth"], p["phase_controls"], p["depth_controls"], p["method"],
                                  p["iterations"])
        self.report = {"sample_error": table.sample_error, "independent_error": table.independent_error,
                       "initial_error": table.initial_error, "iterations": table.iterations}
        return {"wrinkle_axes": table.axes.astype(np.float32), "wrinkle_coeffs": table.coeffs.astype(np.float32),
                "wrinkle_stored": table.stored.astype(np.float32)}


def groove_layout(scene, axis, center, grooves: int, depth_range, cap_cosine: float = 0.7):
    """Per-vertex groove parameters on a rest pose around an axis (flutes along the axis).

    Returns dict of NumPy arrays (V,): ``phase`` (grooves * angle around the axis / 2 pi),
    ``groove_angle`` (angle from the rest tangent to the groove's cross-section direction, about
    the normal), ``base_depth`` (linear ramp ``depth_range`` along the axis; 0 where
    ``|n . axis| > cap_cosine``: end caps), ``axis_neighbour`` / ``rest_length`` (the one-ring
    neighbour most aligned with the axis, and the rest distance to it).
    """
    from ...geometry.frames import TangentFrames

    tf = TangentFrames.from_scene(scene, device="cpu")
    rule = tf.rule
    parts = [m.points @ m.transforms[0][:3, :3] + m.transforms[0][3, :3] for m in scene.meshes]
    p = np.concatenate(parts)
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    rel = p - np.asarray(center, np.float64)
    along = rel @ a
    radial = rel - along[:, None] * a
    ref = np.cross(a, [1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.cross(a, [0.0, 1.0, 0.0])
    ref /= np.linalg.norm(ref)
    angle = np.arctan2(radial @ np.cross(a, ref), radial @ ref)
    phase = np.mod(grooves * angle / (2.0 * np.pi), 1.0)
    n = rule.rest_normals
    across = np.cross(a, radial)
    across -= np.sum(across * n, axis=1, keepdims=True) * n
    length = np.linalg.norm(across, axis=1, keepdims=True)
    across = np.where(length > 1e-12, across / np.maximum(length, 1e-300), rule.rest_tangents)
    t = rule.rest_tangents
    b = np.cross(n, t)
    groove_angle = np.arctan2(np.sum(across * b, axis=1), np.sum(across * t, axis=1))
    lo, hi = along.min(), along.max()
    ramp = (along - lo) / max(hi - lo, 1e-12)
    base = depth_range[0] + (depth_range[1] - depth_range[0]) * ramp
    base = np.where(np.abs(n @ a) > cap_cosine, 0.0, base)
    owner = np.repeat(np.arange(p.shape[0]), np.diff(rule.offsets))
    e = p[rule.neighbours] - p[owner]
    score = np.abs(e @ a) / np.maximum(np.linalg.norm(e, axis=1), 1e-300)
    neighbour = np.full(p.shape[0], -1, np.int64)
    rest_len = np.zeros(p.shape[0])
    for v in range(p.shape[0]):
        s, t_ = rule.offsets[v], rule.offsets[v + 1]
        if t_ > s:
            k = s + int(np.argmax(score[s:t_]))
            neighbour[v] = rule.neighbours[k]
            rest_len[v] = np.linalg.norm(e[k])
    return {"phase": phase, "groove_angle": groove_angle, "base_depth": base, "axis_neighbour": neighbour,
            "rest_length": rest_len}


@register_stage
class WrinkleShadeStage(Stage, _Light):
    type_name = "ldprt.wrinkle_shade"
    kind = "frame"
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
        return {"PX": p["phase_controls"], "PD": p["depth_controls"], "K": p["order"]}

    def input_ports(self):
        return {
            "frames": Port("mat33", ("V",)),
            "points": Port("vec3", ("V",)),
            "wrinkle_axes": Port("float32", ("PX", "PD", 3, 3)),
            "wrinkle_coeffs": Port("float32", ("PX", "PD", 3, "K")),
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
        dev = ctx.device
        layout = groove_layout(ctx.scene, p["axis"], p["center"], p["grooves"], p["depth_range"])
        self._layout = {k: wp.array(v.astype(np.int32 if k == "axis_neighbour" else np.float32), device=dev)
                        for k, v in layout.items()}
        self._in = inputs
        axes = inputs["wrinkle_axes"].numpy()
        self._table_axes = wp.array(axes.reshape(axes.shape[0], axes.shape[1], 3, 3), dtype=wp.vec3, device=dev)
        self._alloc_light(ctx, p["order"])
        self._depth_kernel, self._shade = kernels.wrinkle_kernels(p["order"])
        v = ctx.dims["V"]
        self._depth = wp.zeros(v, dtype=wp.float32, device=dev)
        self._radiance = wp.zeros((v, 3), dtype=wp.float32, device=dev)
        return {"radiance": self._radiance, "depth": self._depth}

    def prepare(self, ctx, frame):
        self._upload_light(ctx, self.params["order"])

    def launch(self, ctx):
        p, i, lay = self.params, self._in, self._layout
        dev, v = ctx.device, ctx.dims["V"]
        wp.launch(self._depth_kernel, dim=v, inputs=[i["points"], lay["axis_neighbour"], lay["rest_length"],
                                                     lay["base_depth"], p["compression_gain"], p["max_depth"],
                                                     self._depth], device=dev)
        wp.launch(self._shade, dim=v, inputs=[i["frames"], lay["phase"], lay["groove_angle"], self._depth,
                                              self._table_axes, i["wrinkle_coeffs"], i["wrinkle_stored"],
                                              p["max_depth"], self._light, i["albedo"], self._radiance], device=dev)
