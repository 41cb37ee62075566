"""The height-field stages (thin: the maths is in :mod:`._kernels`, the set-up tables in
:mod:`._model`): ``heightfield.visibility`` and ``heightfield.shade``."""

# No "from __future__ import annotations": Warp resolves closure types in annotations.

import math

import numpy as np

from ..._wp import launch_parallel, wp
from ...basis.sh_warp import sh_kernels
from .._common import ShLighting, order_param
from ..rpo import OPERATORS, SHADE_PARAMS, GlossyStage
from ..stage import FrameStage, Param, Port, StageError, register_stage
from ._kernels import (FLAG_BELOW_HORIZON, FLAG_NEGATIVE, SHADE_RUN, HorizonMarch, ShadeOutputs, ShadeTexels,
                      ShadeVertices, TexelVisibility, cosine_indices, heights_kernel, horizon_kernel, light_columns_kernel,
                      reduce_kernel, shade_kernels, table_is_even, visibility_kernels)
from ._model import (WEDGE_ENTRIES, GridLayout, grid_layout, march_plan, pyramid_levels, rotated_wedge_tables, view_table,
                    wedge_table)

__all__: list[str] = []

#: Items per CPU chunk below which a launch is not split over cores.
CPU_CHUNK_MIN = 2048
#: Modes of ``below``.
BELOW_MODES = ("open", "blocked")
#: Modes of ``factors``.
FACTOR_MODES = ("rpo", "exact")

_ORDER = order_param(4, minimum=2, maximum=6)


def shade_runs(size: int) -> int:
    """Threads of the shading kernel per grid row (runs of :data:`._kernels.SHADE_RUN` vertices)."""
    return (size + SHADE_RUN - 1) // SHADE_RUN


def _layout(stage, ctx) -> GridLayout:
    try:
        return grid_layout(ctx.scene, f"stage {stage.name!r} ({stage.type_name})")
    except ValueError as exc:
        raise StageError(str(exc)) from None


@register_stage
class HeightFieldVisibilityStage(FrameStage):
    type_name = "heightfield.visibility"
    description = ("world-frame SH visibility of a dynamic height field from horizon angles (eq. 4-5): max pyramid, "
                   "horizon march per azimuth, tabulated wedges z-rotated and summed, sub-sampled")
    parameters = {
        "order": _ORDER,
        "resolution": Param(128, int, "visibility texels per side (sub-sampled; bilinear to the vertices)", minimum=2,
                            maximum=4096),
        "azimuths": Param(16, int, "azimuthal directions (wedges) of the horizon", minimum=4, maximum=128),
        "samples_per_octave": Param(1, int, "horizon-march samples per doubling of the distance", minimum=1, maximum=8),
        "footprint": Param(0.5, float, "pyramid cell side relative to the step to the next sample (1: conservative)",
                           minimum=0.05, maximum=4.0),
        "below": Param("open", str, "directions below the local tangent plane: 'open' or as the horizon says ('blocked')",
                       choices=BELOW_MODES),
        "per_vertex": Param(True, bool, "also write the (V, n*n) per-vertex visibility (for rpo.shade)"),
        "table_entries": Param(WEDGE_ENTRIES, int, "entries of the wedge table over sin(horizon elevation)", minimum=16,
                               maximum=65536),
    }

    def dims(self):
        return {"C": self.params["order"] ** 2, "S": self.params["resolution"] ** 2}

    def input_ports(self):
        return {"points": Port("vec3", ("V",))}

    def output_ports(self):
        out = {"texel_visibility": Port("float32", ("S", "C"), "SH visibility at the R x R texels, world frame")}
        if self.params["per_vertex"]:
            out["visibility"] = Port("float32", ("V", "C"), "SH visibility at every grid vertex (bilinear), world frame",
                                      space="world")
        return out

    def setup(self, ctx, inputs):
        p = self.params
        dev = ctx.device
        lay = _layout(self, ctx)
        if p["resolution"] > lay.size:
            raise StageError(f"stage {self.name!r}: resolution {p['resolution']} exceeds the {lay.size} x {lay.size} grid")
        self.layout = lay
        n = p["order"]
        sizes = pyramid_levels(lay.size)
        offs = np.concatenate([[0], np.cumsum([s * s for s in sizes])]).astype(np.int64)
        self._sizes = sizes
        self._offs = offs
        self._pyr = wp.zeros(int(offs[-1]), dtype=wp.float32, device=dev)
        d, lev = march_plan(lay, p["samples_per_octave"], p["footprint"])
        self.march = (d, lev)
        steps = np.stack([d, 1.0 / d, 2.0 ** -lev.astype(np.float64), np.zeros_like(d)], 1)
        self._steps = wp.array(steps.astype(np.float32), dtype=wp.vec4, device=dev)
        self._step_level = wp.array(np.stack([offs[lev], np.asarray(sizes)[lev]], 1).astype(np.int32), dtype=wp.int32,
                                    device=dev)
        a = p["azimuths"]
        phi = 2.0 * np.pi * np.arange(a) / a
        az = np.stack([np.cos(phi), np.sin(phi), np.cos(phi) / lay.dx, np.sin(phi) / lay.dy], 1)
        self._azimuth = wp.array(az.astype(np.float32), dtype=wp.vec4, device=dev)
        self.table = wedge_table(n, a, p["table_entries"])
        _, full = rotated_wedge_tables(self.table, a)
        cos_t = wp.types.vector(length=len(cosine_indices(n)), dtype=wp.float32)
        self._table = wp.array(self.table[:, cosine_indices(n)].astype(np.float32), dtype=cos_t, device=dev)
        self._full = wp.array(full.astype(np.float32), dtype=wp.float32, device=dev)
        m = np.arange(n)
        harmonics = np.concatenate([np.cos(np.outer(phi, m)), np.sin(np.outer(phi, m))], 1)
        self._harmonics = wp.array(harmonics.astype(np.float32), dtype=wp.float32, device=dev)
        self._points = inputs["points"]
        r = p["resolution"]
        self._texels = wp.zeros((r * r, n * n), dtype=wp.float32, device=dev)
        self._texel_kernel, self._upsample_kernel = visibility_kernels(n)
        march = HorizonMarch()
        march.pyr, march.steps, march.step_level, march.azimuth = self._pyr, self._steps, self._step_level, self._azimuth
        march.size, march.dx, march.dy = lay.size, lay.dx, lay.dy
        texels = TexelVisibility()
        texels.harmonics, texels.res, texels.out = self._harmonics, r, self._texels
        texels.entries, texels.full = int(self.table.shape[0]), self._full
        texels.open_below = 1 if p["below"] == "open" else 0
        self._march, self._texel_args = march, texels
        out = {"texel_visibility": self._texels}
        self._vertex = None
        if p["per_vertex"]:
            self._vertex = wp.zeros((ctx.dims["V"], n * n), dtype=wp.float32, device=dev)
            out["visibility"] = self._vertex
        return out

    def launch(self, state):
        for name, fn in self.launch_parts().items():
            fn()

    def launch_parts(self) -> dict:
        """The frame's kernels in order, as ``{name: launch()}`` (the frame runs them all;
        ``benchmarks/bench_heightfield.py`` times them one by one)."""
        lay = self.layout
        dev = self._pyr.device
        g = lay.size
        r = self.params["resolution"]

        def pyramid():
            wp.launch(heights_kernel, dim=g * g, inputs=[self._points, self._pyr], device=dev)
            for k in range(1, len(self._sizes)):
                s = self._sizes[k]
                wp.launch(reduce_kernel, dim=s * s, inputs=[self._pyr, int(self._offs[k - 1]), self._sizes[k - 1],
                                                             int(self._offs[k]), s], device=dev)

        def texels():
            launch_parallel(self._texel_kernel, r * r, lambda a, b: [self._march, self._texel_args, self._table, a], dev,
                            min_count=CPU_CHUNK_MIN)

        parts = {"pyramid": pyramid, "texels": texels}
        if self._vertex is not None:
            def upsample():
                launch_parallel(self._upsample_kernel, g * g, lambda a, b: [self._texels, g, r, a, self._vertex], dev,
                                min_count=CPU_CHUNK_MIN)

            parts["upsample"] = upsample
        return parts

    def horizons(self, uv) -> np.ndarray:
        """The march's horizon slopes of the current pyramid at points ``uv`` (P, 2) (column,
        row in vertex units), (P, A) float32 (host; after a frame has run)."""
        uv = np.asarray(uv, np.float32).reshape(-1, 2)
        dev = self._pyr.device
        out = wp.zeros((uv.shape[0], self.params["azimuths"]), dtype=wp.float32, device=dev)
        wp.launch(horizon_kernel, dim=out.shape, inputs=[self._pyr, self._steps, self._step_level, self._azimuth,
                                                         self.layout.size, wp.array(uv, dtype=wp.vec2, device=dev), out],
                  device=dev)
        return out.numpy()

    def diagnostics(self) -> dict:
        d, lev = self.march
        return {"grid": self.layout.size, "levels": len(self._sizes), "march_samples": int(d.size),
                "march_levels": [int(x) for x in lev]}

    def model_bytes(self) -> int:
        return int(self._table.capacity + self._full.capacity + self._harmonics.capacity + self._steps.capacity +
                   self._step_level.capacity)


@register_stage
class HeightFieldShadeStage(GlossyStage):
    type_name = "heightfield.shade"
    description = ("RPO glossy shading of a height field at every vertex over sub-sampled visibility: lighting "
                   "products at the visibility texels, F(wo) from a per-BRDF table, one SH rotation per vertex")

    parameters = {
        **SHADE_PARAMS,
        "factors": Param("rpo", str, "F(wo) from the rank-k operators ('rpo') or the BRDF's own projection ('exact')",
                         choices=FACTOR_MODES),
        "view_table": Param(128, int, "entries of the F(wo) table over cos(theta_o)", minimum=8, maximum=65536),
    }

    def input_ports(self):
        return {"points": Port("vec3", ("V",)), "normals": Port("vec3", ("V",)),
                "texel_visibility": Port("float32", ("S", "C")), "lighting": Port("lighting")}

    def setup(self, ctx, inputs):
        p = self.params
        self._setup_common(ctx, inputs)
        dev = ctx.device
        lay = _layout(self, ctx)
        self.layout = lay
        texels = inputs["texel_visibility"]
        r = int(round(math.sqrt(texels.shape[0])))
        if r * r != texels.shape[0] or r < 2 or r > lay.size:
            raise StageError(f"stage {self.name!r}: texel_visibility has {texels.shape[0]} rows, not an R x R grid with "
                             f"2 <= R <= {lay.size}")
        self.resolution = r
        n = p["order"]
        self._points, self._normals, self._texels = inputs["points"], inputs["normals"], texels
        self._lighting = ShLighting(inputs["lighting"], n)
        vec_t = sh_kernels(n).vec
        self._cols = wp.zeros(3 * n * n, dtype=vec_t, device=dev)
        self._g = wp.zeros(3 * r * r, dtype=vec_t, device=dev)
        self._ftable = wp.zeros(p["view_table"], dtype=vec_t, device=dev)
        self._flags = wp.zeros(ctx.dims["V"], dtype=wp.int32, device=dev)
        self._radiance = wp.zeros((ctx.dims["V"], 3), dtype=wp.float32, device=dev)
        vertices = ShadeVertices()
        vertices.points, vertices.normals, vertices.eye, vertices.size = self._points, self._normals, self._eye, lay.size
        shade_texels = ShadeTexels()
        shade_texels.res = r
        shade_texels.specular = self._specular
        out = ShadeOutputs()
        out.radiance, out.flags = self._radiance, self._flags
        self._shade_args = (vertices, shade_texels, out)
        self._upload_material()
        # the view table decides the shading kernel (an isotropic lobe: the half first z-rotation)
        self._even = table_is_even(self.table)
        self._product, self._shade, _, _ = shade_kernels(n, self._even)
        self._light_columns = light_columns_kernel(n)
        return {"radiance": self._radiance}

    def _current_brdf(self):
        mats = self._state.materials
        brdfs = [mats.brdf_of(m.path, self._brdf) for m in self._scene.meshes]
        descs = [b.describe() for b in brdfs]
        if any(d != descs[0] for d in descs[1:]):
            raise StageError(f"stage {self.name!r}: a height field has one BRDF; the run assigns several")
        return brdfs[0]

    def _upload_material(self) -> None:
        p = self.params
        brdf = self._current_brdf()
        try:
            op = OPERATORS.get(brdf, p["order"], p["rank"], "brdf", p["view_resolution"], p["view_order"])
        except ValueError as exc:
            raise StageError(f"stage {self.name!r}: {exc}") from None
        self.operator = op
        self.brdf = brdf
        self.table = view_table(op, p["view_table"], p["factors"], brdf)
        self._ftable.assign(self.table.astype(np.float32))

    def notify_changed(self, flags, keys=frozenset()) -> bool:
        from ...scene._state import Change

        if flags & Change.PARAMETERS:
            return False
        if flags & Change.MATERIAL:
            self._upload_material()
            if table_is_even(self.table) != self._even:
                return False  # another shading kernel: set up (and record) anew
        return True

    def launch(self, state):
        self._lighting.launch()
        for name, fn in self.launch_parts().items():
            fn()

    def launch_parts(self) -> dict:
        """The frame's kernels after the lighting refresh, in order, as ``{name: launch()}``
        (the frame runs them all; ``benchmarks/bench_heightfield.py`` times them one by one)."""
        dev = self._radiance.device
        r, g = self.resolution, self.layout.size
        vertices, texels, out = self._shade_args

        def columns():
            wp.launch(self._light_columns, dim=3, inputs=[self._lighting.light, self._cols], device=dev)

        def products():
            launch_parallel(self._product, r * r, lambda a, b: [self._texels, self._cols, a, self._g], dev,
                            min_count=CPU_CHUNK_MIN)

        def shading():
            launch_parallel(self._shade, g * shade_runs(g), lambda a, b: [vertices, texels, self._g, self._ftable, a, out],
                            dev, min_count=CPU_CHUNK_MIN // SHADE_RUN)

        return {"light columns": columns, "products": products, "shading": shading}

    def diagnostics(self) -> dict:
        f = self._flags.numpy()
        return {"negative_clamped": int(np.count_nonzero(f & FLAG_NEGATIVE)),
                "below_horizon": int(np.count_nonzero(f & FLAG_BELOW_HORIZON)),
                "material": self.brdf.describe(), "factors": self.params["factors"],
                "operator_build_s": round(self.operator.build_s, 4)}

    def model_bytes(self) -> int:
        return int(self._ftable.capacity + self._cols.capacity)
