"""Static PRT (Sloan, Kautz, Snyder 2002) and unshadowed irradiance as graph stages.

* ``prt.transfer`` (precompute): per-vertex diffuse transfer vectors ``t`` (the SH projection
  of ``V(s) max(0, n.s)``, world frame) ray traced on the scene at one frame;
* ``prt.shade`` (per frame): rotate/project the frame's lighting to SH (host, float64, once per
  frame) and shade every vertex by ``albedo / pi * dot(L_c, t)`` per colour channel;
* ``prt.unshadowed`` (per frame): the cheapest baseline -- irradiance indexed by the current
  normal, ``albedo / pi * sum_lm A_l L_lm y_lm(n)`` with the clamped-cosine factors ``A_l``.
  No visibility; valid for deforming meshes too.

Both clamp negative radiance (SH truncation rings below zero in deep shadow) to zero.
Static PRT is exact up to SH truncation and sampling for meshes that do not move; on animated
scenes it keeps the transfer of the bake frame, which is the "undeformed PRT" baseline the
later methods are measured against.
"""

from __future__ import annotations

import numpy as np

from ..._wp import wp
from ...basis import sh
from ..stage import Param, Port, Stage, register_stage
from ..upload import LightingUpload
from . import kernels

__all__ = ["TransferStage", "ShadeTransferStage", "UnshadowedStage"]

_ORDER = Param(4, int, "SH order n (n*n coefficients)", minimum=1, maximum=10)
_WINDOW = Param(None, str, "SH window applied to the lighting (None, 'cosine', 'hanning', 'lanczos')",
                choices=(None, "cosine", "hanning", "lanczos"))


@register_stage
class TransferStage(Stage):
    type_name = "prt.transfer"
    kind = "precompute"
    description = "ray-traced diffuse transfer vectors per vertex (world frame) at one frame"
    parameters = {
        "order": _ORDER,
        "samples": Param(256, int, "rays per vertex", minimum=16),
        "frame": Param(None, float, "time code to bake (default: the scene's first frame)"),
        "seed": Param(0, int, "seed of the per-vertex sample rotations"),
    }

    def dims(self):
        return {"C": self.params["order"] ** 2}

    def output_ports(self):
        return {"transfer": Port("float32", ("V", "C"), "diffuse transfer vectors, world frame")}

    def precompute(self, ctx, inputs):
        from ...transfer import compute

        frame = self.params["frame"]
        if frame is None:
            frame = float(ctx.scene.frames[0])
        result = compute(
            ctx.scene, frame, self.params["order"], self.params["samples"], space="world",
            device=ctx.device, seed=self.params["seed"],
        )
        return {"transfer": np.asarray(result.transfer, dtype=np.float32)}


@register_stage
class ShadeTransferStage(Stage):
    type_name = "prt.shade"
    kind = "frame"
    description = "shade by dot(lighting SH, transfer) per vertex and channel"
    parameters = {"order": _ORDER, "window": _WINDOW, "window_size": Param(None, float, "window size h (default 2n)")}

    def dims(self):
        return {"C": self.params["order"] ** 2}

    def input_ports(self):
        return {
            "transfer": Port("float32", ("V", "C"), "diffuse transfer vectors, world frame"),
            "albedo": Port("float32", ("V", 3)),
            "lighting": Port("lighting"),
        }

    def output_ports(self):
        return {"radiance": Port("float32", ("V", 3), "outgoing radiance, linear RGB")}

    def setup(self, ctx, inputs):
        self._transfer = inputs["transfer"]
        self._albedo = inputs["albedo"]
        self._lighting = LightingUpload(self.params["order"], ctx.device)
        self._radiance = wp.zeros((ctx.dims["V"], 3), dtype=wp.float32, device=ctx.device)
        return {"radiance": self._radiance}

    def prepare(self, ctx, frame):
        self._lighting.upload(ctx.lighting_sh(self.params["order"], **_window_args(self.params)))

    def launch(self, ctx):
        wp.launch(
            kernels.shade_transfer_kernel, dim=ctx.dims["V"],
            inputs=[self._transfer, self._lighting.light, self._albedo, self._radiance], device=ctx.device,
        )


@register_stage
class UnshadowedStage(Stage):
    type_name = "prt.unshadowed"
    kind = "frame"
    description = "unshadowed irradiance indexed by the current normal"
    parameters = {"order": Param(3, int, "SH order n", minimum=1, maximum=10), "window": _WINDOW,
                  "window_size": Param(None, float, "window size h (default 2n)")}

    def input_ports(self):
        return {"normals": Port("vec3", ("V",)), "albedo": Port("float32", ("V", 3)), "lighting": Port("lighting")}

    def output_ports(self):
        return {"radiance": Port("float32", ("V", 3), "outgoing radiance, linear RGB")}

    def setup(self, ctx, inputs):
        order = self.params["order"]
        self._normals = inputs["normals"]
        self._albedo = inputs["albedo"]
        self._lighting = LightingUpload(order, ctx.device)
        self._conv = sh.clamped_cosine_zh(order)[sh.band_of(order)]
        self._kernel = kernels.unshadowed_kernel(order)
        self._radiance = wp.zeros((ctx.dims["V"], 3), dtype=wp.float32, device=ctx.device)
        return {"radiance": self._radiance}

    def prepare(self, ctx, frame):
        light = ctx.lighting_sh(self.params["order"], **_window_args(self.params))
        self._lighting.upload(light * self._conv[None, :])

    def launch(self, ctx):
        wp.launch(self._kernel, dim=ctx.dims["V"], inputs=[self._normals, self._lighting.light, self._albedo, self._radiance],
                  device=ctx.device)


def _window_args(params) -> dict:
    if params.get("window") is None:
        return {}
    args = {"window": params["window"]}
    if params.get("window_size") is not None:
        args["size"] = params["window_size"]
    return args
