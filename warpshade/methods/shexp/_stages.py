"""SHEXP (Ren et al. 2006) as graph stages.

Precompute (artifacts cached by the runtime):

* ``shexp.tables`` -- the per-order tables: log visibility of a blocking cap over its angular
  radius (ZH coefficients, ``quadrature`` = 512 samples) and the optimal-linear a/b coefficients over ``||f^||``;
* ``shexp.blockers`` -- sphere sets bounding the scene's closed occluder meshes (attached to
  their animation), optionally the sphere hierarchy and receiver clusters, as named arrays
  (:class:`.blockers.BlockerModel`);
* ``shexp.static_bake`` -- for receivers on static meshes, the cosine-weighted visibility of the
  static occluders (a ray-traced transfer ``T_p``, sec. 7); static spheres are then skipped for
  them and ``T_p`` replaces the clamped cosine.

Per frame:

* ``shexp.shade`` -- sphere centres from the frame state, hierarchy refit, per-cluster cuts and
  ratio vectors, then the per-receiver pass (:func:`._kernels.receiver_kernel`): log-space
  accumulation (or the product baseline), exponentiation, window, diffuse shading with the
  frame's distant lighting and sphere lights (read from the state's lighting). ``launch`` only
  launches kernels.
* ``shexp.sphere_trace`` -- ray tracing against the same (replaced) spheres instead of the mesh,
  the paper's Fig. 7b reference (Monte Carlo, a validation stage).
"""

from __future__ import annotations

import numpy as np

from ..._wp import wp
from ...basis import sh
from .._common import WINDOW, WINDOW_SIZE, ShLighting, band_weights, order_param, rays_param
from ..stage import FrameStage, Param, Port, PrecomputeStage, StageError, register_stage
from . import _kernels as kernels
from ._model import BlockerFrames, BlockerModel, build_blocker_model, static_mesh_mask
from ._pipeline import ShexpShader, SphereTracer

__all__ = [
    "ShexpVisibilityStage",
]

_ORDER = order_param(4, minimum=2, maximum=8)


@register_stage
class ShexpTablesStage(PrecomputeStage):
    type_name = "shexp.tables"
    uses_scene = False
    description = "per-order SH exp/log tables: blocking-cap log visibility and OL coefficients"
    parameters = {"order": _ORDER, "quadrature": Param(512, int, "table quadrature samples (the paper uses 256)", minimum=256,
                                                       maximum=8192)}

    def dims(self):
        return {"N": self.params["order"], "S": self.params["quadrature"]}  # N: SH bands (ZH coefficients)

    def output_ports(self):
        return {
            "log_cap": Port("float32", ("S", "N"), "ZH coefficients of log(blocking-cap visibility), theta in [0, pi/2]"),
            "ol_a": Port("float32", ("S",), "OL coefficient a over ||f^|| in [0, ol_norm_max]"),
            "ol_b": Port("float32", ("S",), "OL coefficient b over ||f^||"),
            "ol_norm_max": Port("float32", (1,), "end of the OL grid"),
        }

    def precompute(self, ctx, inputs):
        order, quadrature = self.params["order"], self.params["quadrature"]
        cap = sh.log_cap_table(order, quadrature)
        ol = sh.ol_table(order, quadrature)
        return {
            "log_cap": cap.zh.astype(np.float32),
            "ol_a": ol.a.astype(np.float32),
            "ol_b": ol.b.astype(np.float32),
            "ol_norm_max": np.array([ol.norm_max], np.float32),
        }


@register_stage
class ShexpBlockersStage(PrecomputeStage):
    type_name = "shexp.blockers"
    version = 2  # 2: static spheres, ground-plane discs and the fit summary in the model
    description = "sphere sets bounding the closed occluder meshes (+ hierarchy and receiver clusters)"
    parameters = {
        "budget": Param(48, int, "total leaf spheres over all occluder meshes", minimum=1),
        "hierarchy": Param(False, bool, "build the sphere tree and receiver clusters (sec. 6.3)"),
        "planes": Param(True, bool, "static planar open meshes (ground planes) block as discs (an extension)"),
        "branching": Param(4, int, "target children per tree node", minimum=2),
        "vertices_per_cluster": Param(300, int, "receiver cluster size", minimum=1),
        "split": Param("volume", str, "how the budget is split over meshes", choices=("volume", "error")),
        "target_error": Param(None, float, "per-mesh outside-volume target E (fewest spheres meeting it)"),
        "open_meshes": Param("skip", str, "open meshes: skip, or bound a thickened shell", choices=("skip", "shell")),
        "radius_scale": Param(1.0, float, "safety factor on the fit radii", minimum=1.0),
        "calibrate": Param(False, bool, "grow radii so animated spheres keep bounding their clusters over every frame"),
        "grid_cells": Param(60000, int, "cells of the outside-volume grid of the fit", minimum=1000),
        "teleports": Param(8, int, "cluster-teleportation attempts of the fit", minimum=0),
        "seed": Param(0, int, "seed of the fit and clusterings"),
    }

    def output_ports(self):
        return {"model": Port("arrays", (), "blocker model: sphere sets, hierarchy, clusters (BlockerModel.to_arrays)")}

    def precompute(self, ctx, inputs):
        p = self.params
        try:
            model = build_blocker_model(
                ctx.scene, p["budget"], hierarchy=p["hierarchy"], planes=p["planes"], branching=p["branching"],
                vertices_per_cluster=p["vertices_per_cluster"], split=p["split"], target_error=p["target_error"],
                open_meshes=p["open_meshes"], radius_scale=p["radius_scale"], calibrate=p["calibrate"], seed=p["seed"],
                grid_cells=p["grid_cells"], teleports=p["teleports"], device=ctx.device,
            )
        except ValueError as exc:
            raise StageError(f"stage {self.name!r} ({self.type_name}): {exc}") from None
        self.report = dict(model.summary)
        return {"model": model.to_arrays()}

    def check_artifact(self, outputs):
        BlockerModel.from_arrays(outputs["model"])


@register_stage
class ShexpStaticBakeStage(PrecomputeStage):
    type_name = "shexp.static_bake"
    description = "cosine-weighted visibility of static occluders for static receivers (sec. 7)"
    parameters = {"order": _ORDER, "samples": rays_param(256, "rays per receiver"),
                  "seed": Param(0, int, "seed of the per-vertex sample rotations")}

    def dims(self):
        return {"C": self.params["order"] ** 2}

    def output_ports(self):
        return {
            "bake": Port("float32", ("V", "C"), "transfer T_p of static occluders, world frame (0 for dynamic receivers)"),
            "baked": Port("int32", ("V",), "1 for static receivers (T_p valid)"),
        }

    def precompute(self, ctx, inputs):
        from dataclasses import replace

        from ...scene import Scene
        from ...transfer import compute

        scene = ctx.scene
        order = self.params["order"]
        static = static_mesh_mask(scene)
        bake = np.zeros((scene.vertex_count, order * order), np.float32)
        baked = np.zeros(scene.vertex_count, np.int32)
        if static.any():
            # a scene of copies of the static meshes only (Scene() renumbers vertex offsets)
            meshes = [replace(m) for m, s in zip(scene.meshes, static) if s]
            sub = Scene(meshes, frames=scene.frames[:1], lights=scene.lights, up_axis=scene.up_axis, source=scene.source)
            t = compute(sub, float(sub.frames[0]), order, self.params["samples"], space="world", device=ctx.device,
                        seed=self.params["seed"], progress=ctx.progress).transfer
            k = 0
            for m, s in zip(scene.meshes, static):
                if s:
                    sl = slice(m.vertex_offset, m.vertex_offset + m.vertex_count)
                    bake[sl] = t[k : k + m.vertex_count]
                    baked[sl] = 1
                    k += m.vertex_count
        return {"bake": bake, "baked": baked}


@register_stage
class ShexpShadeStage(FrameStage):
    type_name = "shexp.shade"
    #: also write the (windowed) per-vertex SH visibility (``shexp.visibility``)
    store_visibility = False
    shades_sphere_lights = True
    description = "SHEXP per frame: spheres, cuts, log accumulation, SH exp, diffuse shading"
    parameters = {
        "order": _ORDER,
        "method": Param("hyb", str, "SH exponential", choices=sh.EXP_METHODS),
        "degree": Param(None, int, "series degree of ps / ps_star (default 10 / 2)", minimum=1, maximum=40),
        "shade": Param("direct", str, "shading path", choices=kernels.SHADE_MODES),
        "accumulate": Param("log", str, "log (SHEXP) or product (Zhou et al. baseline)", choices=kernels.ACCUMULATE),
        "rule": Param("continuous", str, "self-shadowing rule (sec. 6.2)", choices=kernels.RULES),
        "window": Param(None, str, "window on the visibility (and, when shading, the lighting)",
                        choices=WINDOW.choices),
        "window_size": WINDOW_SIZE,
        "table_rows": Param(33, int, "L*H(N) table rows (table mode)", minimum=3),
        "table_cols": Param(64, int, "L*H(N) table columns (table mode)", minimum=4),
        "theta_max": Param(25.0, float, "hierarchy cut angle, degrees (eq. 36)", minimum=1.0, maximum=89.0),
        "theta_min": Param(0.0, float, "leaves below this angle are left out of ratio vectors, degrees", minimum=0.0),
        "ratio": Param(True, bool, "per-band ratio vectors for hierarchy cuts (eq. 37)"),
        "static_bake": Param(False, bool, "use the shexp.static_bake inputs (bake, baked)"),
        "shade_order": Param(None, int, "truncate visibility, lighting and cosine to this order for shading "
                             "(accumulate at 'order', shade at a lower one: paper Fig. 7e)", minimum=1),
    }

    def dims(self):
        return {"N": self.params["order"], "C": self.params["order"] ** 2}

    def input_ports(self):
        ports = {
            "model": Port("arrays"),
            "log_cap": Port("float32", ("S", "N")),
            "ol_a": Port("float32", ("S",)),
            "ol_b": Port("float32", ("S",)),
            "ol_norm_max": Port("float32", (1,)),
            "points": Port("vec3", ("V",)),
            "normals": Port("vec3", ("V",)),
            "albedo": Port("float32", ("V", 3)),
            "lighting": Port("lighting"),
        }
        if self.params["static_bake"]:
            ports["bake"] = Port("float32", ("V", "C"))
            ports["baked"] = Port("int32", ("V",))
        return ports

    def output_ports(self):
        return {"radiance": Port("float32", ("V", 3), "outgoing radiance, linear RGB")}

    def setup(self, ctx, inputs):
        p = self.params
        model = BlockerModel.from_arrays(inputs["model"])
        self.model = model
        lighting = inputs["lighting"]
        if lighting is None:
            raise StageError(f"stage {self.name!r}: SHEXP shading needs the frame's lighting")
        self.shader = ShexpShader(
            p["order"], ctx.dims["V"], model.node_count, clusters=1 if model.tree is None else model.clusters.cluster_count,
            cut_capacity=max(model.leaf_count, 1), method=p["method"], degree=p["degree"], shade=p["shade"],
            accumulate=p["accumulate"], rule=p["rule"], window=p["window"], window_size=p["window_size"],
            table_shape=(p["table_rows"], p["table_cols"]), sphere_light_count=lighting.sphere_light_count,
            shade_order=p["shade_order"], store_visibility=self.store_visibility, device=ctx.device,
        )
        self.shader.set_exp_tables(inputs["log_cap"], inputs["ol_a"], inputs["ol_b"], float(inputs["ol_norm_max"].numpy()[0]))
        self.frames = BlockerFrames(ctx.scene, model, p["order"], p["theta_max"], p["theta_min"], p["ratio"], ctx.device,
                                    exp_tables=self.shader.exp_tables)
        self.shader.bind_receivers(inputs["points"], inputs["normals"], inputs["albedo"])
        self.frames.bind(self.shader)
        if p["static_bake"]:
            self.shader.set_baked(inputs["baked"].numpy().astype(bool), inputs["bake"].numpy())
        # the frame's lighting, windowed and truncated to the shading order, read every launch
        keep = band_weights(p["order"], p, keep_bands=self.shader.shade_order)
        self._lighting = ShLighting(lighting, p["order"], keep)
        self.shader.bind_lighting(self._lighting.light)
        self.shader.bind_sphere_lights(lighting.sphere_position, lighting.sphere_radius, lighting.sphere_radiance)
        if self.store_visibility:
            return {"radiance": self.shader.radiance, "visibility": self.shader.visibility}
        return {"radiance": self.shader.radiance}

    def launch(self, state):
        self._lighting.launch()
        self.frames.launch(state)
        self.shader.launch()

    def diagnostics(self) -> dict:
        """Receivers of the last frame whose exponential left its domain (scalar fallback)."""
        return {"fallbacks": self.shader.fallback_count()}

    def model_bytes(self) -> int:
        return self.shader.model_bytes()


@register_stage
class ShexpSphereTraceStage(FrameStage):
    type_name = "shexp.sphere_trace"
    description = "ray tracing against the blocker spheres instead of the mesh (paper Fig. 7b)"
    parameters = {
        "samples": rays_param(512, "rays per receiver (MIS: half cosine, half environment)", minimum=4),
        "rule": Param("continuous", str, "self-shadowing rule applied to the spheres", choices=kernels.RULES),
        "seed": Param(0, int, "random seed"),
    }

    def input_ports(self):
        return {"model": Port("arrays"), "points": Port("vec3", ("V",)), "normals": Port("vec3", ("V",)),
                "albedo": Port("float32", ("V", 3)), "lighting": Port("lighting")}

    def output_ports(self):
        return {"radiance": Port("float32", ("V", 3), "outgoing radiance, linear RGB (Monte Carlo)")}

    def setup(self, ctx, inputs):
        model = BlockerModel.from_arrays(inputs["model"])
        lighting = inputs["lighting"]
        envs = 0 if lighting is None else len(lighting.environments)
        if envs != 1:
            raise StageError(f"stage {self.name!r}: sphere tracing needs exactly one environment light, the scene has {envs}")
        self.shader = ShexpShader(2, ctx.dims["V"], model.node_count, clusters=1 if model.tree is None else model.clusters.cluster_count,
                                  cut_capacity=max(model.leaf_count, 1), rule=self.params["rule"], device=ctx.device)
        self.frames = BlockerFrames(ctx.scene, model, 2, ratio=False, device=ctx.device)
        self.shader.bind_receivers(inputs["points"], inputs["normals"], inputs["albedo"])
        self.frames.bind(self.shader)
        # the environment turns with the frame: its rotation is read from the state every launch
        self.tracer = SphereTracer(self.shader, lighting.environment_map(0), self.params["samples"], self.params["seed"])
        self._radiance = wp.zeros((ctx.dims["V"], 3), dtype=wp.float32, device=ctx.device)
        return {"radiance": self._radiance}

    def launch(self, state):
        self.frames.launch(state)
        self.tracer.launch()
        wp.launch(kernels.vec3_to_rows_kernel, dim=self._radiance.shape[0], inputs=[self.tracer.radiance, self._radiance],
                  device=self._radiance.device)


@register_stage
class ShexpVisibilityStage(ShexpShadeStage):
    """SHEXP as a visibility generator: the same per-frame accumulation as ``shexp.shade``, with
    each receiver's accumulated (windowed) SH visibility as an output, world frame (for the
    reflectance product operators, ``rpo.shade`` with ``visibility_space = "world"``)."""

    type_name = "shexp.visibility"
    description = "SHEXP per frame: blocker-sphere SH visibility per vertex (world frame), and diffuse radiance"
    store_visibility = True

    def output_ports(self):
        return {"radiance": Port("float32", ("V", 3), "outgoing radiance, linear RGB"),
                "visibility": Port("float32", ("V", "C"), "accumulated SH visibility, world frame", space="world")}

