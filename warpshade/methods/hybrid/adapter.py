"""A visibility model as the hybrid tracer's control: local SH visibility turned into world-frame
diffuse transfer (``hybrid.visibility_transfer``, per frame).

A data-driven visibility model (``visibility.predict``) gives per vertex the SH visibility ``v``
(open below the horizon, no cosine) in its tangent frame ``F`` (rows t, b, n). The diffuse
transfer it implies is the clamped cosine re-applied in that frame and the result rotated to the
world, as ``visibility.diffuse`` shades it::

    T = R(F^T) (v * c),     c = SH of max(0, s_z),   v * c the order-n truncated SH product

so that ``hybrid.trace`` (``control = "model"``, world frame) can use it as control variate: the
rays then estimate only what the visibility model misses. :func:`visibility_transfer_f64` is the
float64 mirror.
"""

from __future__ import annotations

import functools

import numpy as np

from ..._wp import launch_parallel, wp
from ...basis import sh
from ...basis.sh_warp import SHTables, sh_kernels
from ..common import order_param
from ..rpo.model import cosine_sh
from ..stage import FrameStage, Port, register_stage

__all__: list[str] = []

_CHUNK_MIN_VERTICES = 256


@functools.lru_cache(maxsize=None)
def visibility_transfer_kernel(order: int):
    """``kernel(visibility, frames, cos_sh, tables, start, transfer)``: ``R(F^T)(v * cos)`` per vertex."""
    shk = sh_kernels(order)
    n2 = order * order
    vec_t = shk.vec
    sh_rotate, sh_product, sh_load, sh_store = shk.rotate, shk.product, shk.load, shk.store

    @wp.kernel(enable_backward=False, module="unique")
    def kernel(visibility: wp.array2d(dtype=wp.float32), frames: wp.array(dtype=wp.mat33),
               cos_sh: wp.array(dtype=wp.float32), tables: SHTables, start: int,
               transfer: wp.array2d(dtype=wp.float32)):
        v = wp.tid() + start
        c = vec_t()
        for i in range(n2):
            c[i] = cos_sh[i]
        t = sh_product(sh_load(visibility, v), c, tables)
        sh_store(transfer, v, sh_rotate(t, wp.transpose(frames[v]), tables))

    return kernel


def visibility_transfer_f64(visibility, frames, order: int) -> np.ndarray:
    """Float64 mirror of :func:`visibility_transfer_kernel`: (V, C) world-frame transfer from
    (V, C) local visibility and (V, 3, 3) tangent frames (rows t, b, n)."""
    local = sh.product(np.asarray(visibility, np.float64), np.broadcast_to(cosine_sh(order), np.shape(visibility)))
    return sh.rotate(local, np.swapaxes(np.asarray(frames, np.float64), 1, 2))


@register_stage
class VisibilityTransferStage(FrameStage):
    type_name = "hybrid.visibility_transfer"
    description = "world-frame diffuse transfer from local SH visibility (cosine re-applied, rotated): a control for hybrid.trace"
    parameters = {"order": order_param(6, minimum=1, maximum=8)}

    def dims(self):
        return {"C": self.params["order"] ** 2}

    def input_ports(self):
        return {"visibility": Port("float32", ("V", "C"), "SH visibility (no cosine, open below the horizon), tangent frame",
                                   space="local"),
                "frames": Port("mat33", ("V",), "the tangent frames of the visibility, rows (t, b, n)")}

    def output_ports(self):
        return {"transfer": Port("float32", ("V", "C"), "diffuse transfer implied by the visibility, world frame",
                                 space="world")}

    def setup(self, ctx, inputs):
        dev = ctx.device
        n = self.params["order"]
        self._vis, self._frames = inputs["visibility"], inputs["frames"]
        self._cos = wp.array(cosine_sh(n).astype(np.float32), dtype=wp.float32, device=dev)
        self._tables = sh_kernels(n).tables(dev)
        self._kernel = visibility_transfer_kernel(n)
        self._transfer = wp.zeros((ctx.dims["V"], n * n), dtype=wp.float32, device=dev)
        return {"transfer": self._transfer}

    def launch(self, state):
        launch_parallel(self._kernel, self._transfer.shape[0],
                        lambda a, b: [self._vis, self._frames, self._cos, self._tables, a, self._transfer],
                        self._transfer.device, min_count=_CHUNK_MIN_VERTICES)

    def model_bytes(self) -> int:
        return int(self._transfer.size * 4) if hasattr(self, "_transfer") else 0
