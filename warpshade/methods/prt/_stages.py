"""Static PRT (Sloan, Kautz, Snyder 2002) and unshadowed irradiance as graph stages.

* ``prt.transfer`` (precompute): per-vertex diffuse transfer vectors ``t`` (world frame) ray
  traced at one frame (:func:`._model.bake_transfer`);
* ``prt.shade`` (per frame): ``albedo / pi * max(0, dot(L_c, t))`` per vertex and channel with
  the frame's SH lighting ``L`` (:mod:`._kernels`);
* ``prt.unshadowed`` (per frame): the cheapest baseline, irradiance indexed by the current
  normal, ``albedo / pi * sum_lm A_l L_lm y_lm(n)`` with the clamped-cosine factors ``A_l``.
  No visibility; valid for deforming meshes too.
* ``prt.trace`` (per frame): the brute-force baseline every dynamic method has to beat -- the
  transfer ray traced again at every frame against the frame's BVH (refit inside the recorded
  frame), then shaded like ``prt.shade``. Exact up to SH truncation and sampling on any
  animation; costs ``samples`` rays per vertex per frame.

Both clamp negative radiance (SH truncation rings below zero in deep shadow) to zero. The
stages only declare ports and parameters and bind buffers; the maths is in :mod:`._kernels`,
its float64 mirror in :mod:`._mirror`, the artifact in :mod:`._model`.
"""

from __future__ import annotations

from ..._wp import wp
from ...basis import sh
from .._common import WINDOW_PARAMS, ShLighting, order_param, rays_param
from ..stage import FrameStage, Param, Port, PrecomputeStage, register_stage
from . import _kernels as kernels
from ._model import TransferModel, bake_transfer

__all__ = [
    "PrtTraceStage",
]

_ORDER = order_param(4, minimum=1, maximum=10)
_RADIANCE = Port("float32", ("V", 3), "outgoing radiance, linear RGB")


@register_stage
class PrtTransferStage(PrecomputeStage):
    type_name = "prt.transfer"
    description = "ray-traced diffuse transfer vectors per vertex (world frame) at one frame"
    parameters = {
        "order": _ORDER,
        "samples": rays_param(256, "rays per vertex"),
        "frame": Param(None, float, "time code to bake (default: the scene's first frame)"),
        "seed": Param(0, int, "seed of the per-vertex sample rotations"),
    }

    def dims(self):
        return {"C": self.params["order"] ** 2}

    def output_ports(self):
        return {"transfer": Port("float32", ("V", "C"), "diffuse transfer vectors, world frame")}

    def precompute(self, ctx, inputs):
        p = self.params
        frame = float(ctx.scene.frames[0]) if p["frame"] is None else p["frame"]
        return bake_transfer(ctx.scene, frame, p["order"], p["samples"], p["seed"], ctx.device, ctx.progress).arrays()

    def check_artifact(self, outputs):
        TransferModel.from_arrays(outputs, order=self.params["order"])


@register_stage
class PrtShadeStage(FrameStage):
    type_name = "prt.shade"
    description = "shade by dot(lighting SH, transfer) per vertex and channel"
    parameters = {
        "order": _ORDER,
        "color": Param(False, bool, "per-channel transfer (V, 3, C) on input transfer_rgb (interreflected)"),
        "bounces": Param(0, int, "diffuse bounces in that transfer: what the run is measured against", minimum=0),
        **WINDOW_PARAMS,
    }

    def dims(self):
        return {"C": self.params["order"] ** 2}

    def input_ports(self):
        if self.params["color"]:
            transfer = {"transfer_rgb": Port("float32", ("V", 3, "C"), "per-channel transfer after bounces, world frame")}
        else:
            transfer = {"transfer": Port("float32", ("V", "C"), "diffuse transfer vectors, world frame")}
        return {**transfer, "albedo": Port("float32", ("V", 3)), "lighting": Port("lighting")}

    def reference_model(self, materials=None):
        """Interreflected transfer is measured against the reference with the same bounces
        (:class:`warpshade.measure._protocols.MeasuredStage`)."""
        return {"bounces": self.params["bounces"]} if self.params["bounces"] else None

    def output_ports(self):
        return {"radiance": _RADIANCE}

    def setup(self, ctx, inputs):
        self._transfer = inputs["transfer_rgb" if self.params["color"] else "transfer"]
        self._kernel = kernels.shade_transfer_rgb_kernel if self.params["color"] else kernels.shade_transfer_kernel
        self._albedo = inputs["albedo"]
        self._lighting = ShLighting.for_stage(inputs["lighting"], self.params["order"], self.params)
        self._radiance = wp.zeros((ctx.dims["V"], 3), dtype=wp.float32, device=ctx.device)
        return {"radiance": self._radiance}

    def launch(self, state):
        self._lighting.launch()
        wp.launch(self._kernel, dim=self._radiance.shape[0], device=self._radiance.device,
                  inputs=[self._transfer, self._lighting.light, self._albedo, self._radiance])


@register_stage
class PrtUnshadowedStage(FrameStage):
    type_name = "prt.unshadowed"
    description = "unshadowed irradiance indexed by the current normal"
    parameters = {"order": order_param(3, minimum=1, maximum=10), **WINDOW_PARAMS}

    def input_ports(self):
        return {"normals": Port("vec3", ("V",)), "albedo": Port("float32", ("V", 3)), "lighting": Port("lighting")}

    def output_ports(self):
        return {"radiance": _RADIANCE}

    def setup(self, ctx, inputs):
        order = self.params["order"]
        self._normals = inputs["normals"]
        self._albedo = inputs["albedo"]
        # the lighting convolved with the clamped cosine, A_l L_lm
        self._lighting = ShLighting.for_stage(inputs["lighting"], order, self.params, convolution=sh.clamped_cosine_zh(order))
        self._kernel = kernels.unshadowed_kernel(order)
        self._radiance = wp.zeros((ctx.dims["V"], 3), dtype=wp.float32, device=ctx.device)
        return {"radiance": self._radiance}

    def launch(self, state):
        self._lighting.launch()
        wp.launch(self._kernel, dim=self._radiance.shape[0], device=self._radiance.device,
                  inputs=[self._normals, self._lighting.light, self._albedo, self._radiance])


@register_stage
class PrtTraceStage(FrameStage):
    type_name = "prt.trace"
    needs_bvh = True
    description = "transfer ray traced at every frame against the frame's BVH, then shaded (brute-force baseline)"
    parameters = {
        "order": _ORDER,
        "samples": rays_param(256, "rays per vertex per frame"),
        "seed": Param(0, int, "seed of the per-vertex sample rotations (the same rays every frame)"),
        **WINDOW_PARAMS,
    }

    def input_ports(self):
        return {"points": Port("vec3", ("V",)), "normals": Port("vec3", ("V",)), "albedo": Port("float32", ("V", 3)),
                "lighting": Port("lighting")}

    def output_ports(self):
        return {"radiance": _RADIANCE}

    def setup(self, ctx, inputs):
        from ...transfer import TransferTracer

        p = self.params
        self._points, self._normals, self._albedo = inputs["points"], inputs["normals"], inputs["albedo"]
        self._tracer = TransferTracer(ctx.scene, p["order"], p["samples"], space="world", device=ctx.device, seed=p["seed"],
                                      bvh=ctx.state.bvh)
        self._lighting = ShLighting.for_stage(inputs["lighting"], p["order"], p)
        self._radiance = wp.zeros((ctx.dims["V"], 3), dtype=wp.float32, device=ctx.device)
        return {"radiance": self._radiance}

    def launch(self, state):
        self._tracer.launch(self._points, self._normals)
        self._lighting.launch()
        wp.launch(kernels.shade_transfer_kernel, dim=self._radiance.shape[0], device=self._radiance.device,
                  inputs=[self._tracer.transfer_sh, self._lighting.light, self._albedo, self._radiance])
