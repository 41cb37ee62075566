"""Reflectance product operators as graph stages: BRDFs chosen at run time over any SH visibility.

* ``rpo.shade`` (per frame): eq. 11 per vertex toward the eye (:mod:`._kernels`), with the
  operators of each material slot (:mod:`._model`), the visibility of any generator below and the
  frame's lighting turned into the tangent frames (full rotation, or the 3-lobe ZH approximation
  of :mod:`._lighting`). Its BRDF parameters give the material of every mesh until
  ``Runtime.set_material`` or the graph's ``[[material]]`` track choose others; those reach it as
  :data:`~warpshade.scene._state.Change.MATERIAL` and are written into its fixed buffers (no
  precompute, no new recording).
* Visibility generators, each (V, n*n) SH visibility (1 where a direction is open or below the
  tangent plane, the paper's eq. 1):

  - ``rpo.visibility_traced`` (per frame): ray traced against the frame's BVH in the tangent
    frames (the exact input; the brute-force cost);
  - ``rpo.visibility_static`` (precompute): the same, once, at a bake frame (local frame, so it
    follows the surface but knows nothing of the deformation);
  - ``shexp.visibility`` (per frame, :mod:`warpshade.methods.shexp`): SHEXP's blocker-sphere
    visibility, world frame (``visibility_space = "world"`` here).
"""

from __future__ import annotations

import time

import numpy as np

from ..._wp import launch_parallel, wp
from ...basis import sh
from ...basis.sh_warp import sh_kernels
from ...scene import _brdfs as brdfs, _materials as materials
from .._common import ShLighting, order_param, rays_param
from ..stage import FrameStage, Param, Port, PrecomputeStage, StageError, register_stage
from .._viewer import EYE_PARAM, bind_viewer, check_eye, check_viewer
from . import _kernels as kernels
from ._model import COSINE_MODES, VIEW_ORDER, OperatorCache

__all__: list[str] = []

_ORDER = order_param(4, minimum=2, maximum=6)
_FRAME = Param(None, float, "time code of the bake pose (default: the scene's first frame)")
#: Receivers below which a shading launch is not split over cores: a chunked launch breaks the
#: recorded frame and waits on the pool (~0.5 ms), more than half the kernel's time below this
#: (order 4, k = 8: ~0.3 us per receiver on this CPU).
CPU_CHUNK_MIN = 8192

#: BRDF parameters of ``rpo.shade`` (the material of every mesh until one is set at run time).
BRDF_PARAMS = {
    "brdf": Param("ggx", str, "BRDF of every mesh (warpshade.scene._brdfs.make_brdf kinds)",
                  choices=brdfs.BRDF_KINDS),
    "roughness": Param(0.5, float, "microfacet roughness alpha", minimum=1e-3, maximum=2.0),
    "exponent": Param(30.0, float, "Phong / Blinn-Phong exponent", minimum=0.0),
    "f0": Param(0.04, float, "microfacet Fresnel reflectance at normal incidence", minimum=0.0, maximum=1.0),
    "file": Param(None, str, "tabulated BRDF file (MERL binary layout), relative to the graph"),
}

#: One operator cache per process: swapping back to a BRDF costs a lookup and gives the same floats.
OPERATORS = OperatorCache()


def _stage_brdf(stage, ctx) -> materials.BRDF:
    p = stage.params
    file = p["file"]
    if file is not None and hasattr(ctx, "resolve_path"):
        try:
            file = str(ctx.resolve_path(file))
        except ValueError as exc:
            raise StageError(f"stage {stage.name!r}: parameter 'file': {exc}") from None
    try:
        values = {k: p[k] for k in brdfs.BRDF_USES.get(p["brdf"], ()) if k in BRDF_PARAMS and k != "file"}
        return brdfs.make_brdf(p["brdf"], file=file, where=f"stage {stage.name!r}", **values)
    except ValueError as exc:
        raise StageError(str(exc)) from None


#: Parameters every RPO shading stage has (its order, factors, default BRDF, colour and eye).
SHADE_PARAMS = {
    "order": _ORDER,
    "rank": Param(8, int, "BRDF factors k kept by the SVD", minimum=1),
    "view_order": Param(VIEW_ORDER, int, "SH order of the view factors", minimum=1, maximum=8),
    "view_resolution": Param(32, int, "view grid of the BRDF table (res x res)", minimum=4, maximum=128),
    **BRDF_PARAMS,
    "specular": Param((1.0, 1.0, 1.0), tuple, "RGB colour multiplying the BRDF's radiance"),
    "eye": EYE_PARAM,
}


class GlossyStage(FrameStage):
    """What RPO shading stages share: checks of the common parameters, the eye, the colour, the
    default BRDF, and the glossy reference of each frame (per mesh when BRDFs differ)."""

    reads_materials = True

    def __init__(self, name: str, params: dict | None = None):
        super().__init__(name, params)
        self._check_parameters()

    def dims(self):
        return {"C": self.params["order"] ** 2}

    def output_ports(self):
        return {"radiance": Port("float32", ("V", 3), "radiance toward the eye, linear RGB")}

    # ---- checks before any work ---------------------------------------------------------
    def _check_parameters(self) -> None:
        """What the parameters alone rule out (at construction, and again at every set-up: a
        parameter may have been changed at run time)."""
        p = self.params
        if p["rank"] > p["order"] ** 2:
            raise StageError(f"stage {self.name!r}: rank {p['rank']} exceeds the {p['order'] ** 2} SH coefficients "
                             f"of order {p['order']}")
        if len(p["specular"]) != 3 or not all(np.isfinite(float(x)) and float(x) >= 0 for x in p["specular"]):
            raise StageError(f"stage {self.name!r}: parameter 'specular' needs three non-negative numbers, got {p['specular']!r}")
        check_eye(self.name, p["eye"])

    def check_scene(self, scene, ctx) -> None:
        """Before any precompute: the parameters, the viewer on this scene (a warning when an
        explicit 'eye' lies below it) and the BRDF, its 'file' read (a relative path against the
        graph file's folder)."""
        self._check_parameters()
        check_viewer(self.name, self.params["eye"], scene)
        _stage_brdf(self, ctx)

    # ---- set-up -------------------------------------------------------------------------
    def _setup_common(self, ctx, inputs) -> None:
        p = self.params
        self._check_parameters()
        lighting = inputs["lighting"]
        if lighting is None:
            raise StageError(f"stage {self.name!r}: RPO shading needs the frame's lighting")
        if lighting.sphere_light_count:
            raise StageError(f"stage {self.name!r}: RPOs shade distant lighting (environment and distant lights, as "
                             f"SH); this run has {lighting.sphere_light_count} sphere light(s)")
        dev = ctx.device
        self._ctx, self._scene, self._state = ctx, ctx.scene, ctx.state
        self._viewer = bind_viewer(self.name, p["eye"], ctx)
        self._eye = self._viewer.eye
        self.follows_state_eye = self._viewer.follows_state_eye
        self._specular = wp.vec3(*[float(x) for x in p["specular"]])
        self._brdf = _stage_brdf(self, ctx)

    def reference_model(self, materials=None):
        """Glossy ground truth with the BRDF of the meshes (of ``materials``, a
        :class:`~warpshade.scene._state.MaterialAssignment`; default the run's current one), the
        stage's eye and the specular colour (:class:`warpshade.measure._protocols.MeasuredStage`)."""
        materials = self._state.materials if materials is None else materials
        per_mesh = [materials.brdf_of(m.path, self._brdf) for m in self._scene.meshes]
        eye = self._eye.numpy()[0]
        model = {"brdf": per_mesh[0], "eye": np.asarray(eye, np.float64),
                 "color": np.array([self._specular[0], self._specular[1], self._specular[2]], np.float64)}
        descs = [b.describe() for b in per_mesh]
        if any(d != descs[0] for d in descs[1:]):
            model["groups"] = [{"brdf": b, "vertices": np.arange(m.vertex_offset, m.vertex_offset + m.vertex_count)}
                               for m, b in zip(self._scene.meshes, per_mesh)]
        return model


@register_stage
class RpoShadeStage(GlossyStage):
    type_name = "rpo.shade"
    description = "reflectance product operators (eq. 11): run-time BRDFs over per-vertex SH visibility, toward the eye"
    parameters = {
        **SHADE_PARAMS,
        "cosine": Param("brdf", str, "cosine in the BRDF table ('brdf', the paper) or applied by eq. 14 ('product')",
                        choices=COSINE_MODES),
        "lighting": Param("rotate", str, "lighting into the tangent frame: full SH rotation or ZH lobes (sec. 5.4)",
                          choices=kernels.LIGHTING_MODES),
        "zh_lobes": Param(3, int, "ZH lobes of the lighting approximation", minimum=1, maximum=16),
        "evaluation": Param("gaunt", str, "F(wo) * v (one SH product) or sum_b u_b M_b v (the dense operators)",
                            choices=kernels.EVALUATIONS),
        "visibility_space": Param("local", str, "frame of the visibility input", choices=("local", "world")),
        "materials": Param(4, int, "material slots (distinct BRDFs at once)", minimum=1, maximum=64),
    }

    def input_ports(self):
        return {"tangents": Port("mat33", ("V",)), "points": Port("vec3", ("V",)),
                "visibility": Port("float32", ("V", "C"), space=self.params["visibility_space"]),
                "lighting": Port("lighting")}

    # ---- set-up -----------------------------------------------------------------------
    def setup(self, ctx, inputs):
        p = self.params
        self._setup_common(ctx, inputs)
        dev = ctx.device
        n, k, slots = p["order"], p["rank"], p["materials"]
        n2, nv2 = n * n, p["view_order"] ** 2
        self._light_sh = wp.zeros((slots, k, n2), dtype=wp.float32, device=dev)
        self._view_sh = wp.zeros((slots, k, nv2), dtype=wp.float32, device=dev)
        self._rank = wp.zeros(slots, dtype=wp.int32, device=dev)
        self._channels = wp.ones(slots, dtype=wp.int32, device=dev)
        msize = (slots, k, n2, n2) if p["evaluation"] == "matrices" else (1, 1, 1, 1)
        self._matrices = wp.zeros(msize, dtype=wp.float32, device=dev)
        self._material = wp.zeros(ctx.dims["V"], dtype=wp.int32, device=dev)
        self._cos = wp.array(sh.clamped_cosine_sh(n).astype(np.float32), dtype=wp.float32, device=dev)
        self._zh_axes = wp.zeros(p["zh_lobes"] if p["lighting"] == "zh" else 0, dtype=wp.vec3, device=dev)
        self._zh_axes0 = wp.zeros_like(self._zh_axes)
        self._zh_turn = wp.array(np.eye(3, dtype=np.float32)[None], dtype=wp.mat33, device=dev)
        self._zh_coeffs = wp.zeros((max(self._zh_axes.shape[0], 1), 3, n), dtype=wp.float32, device=dev)
        self._flags = wp.zeros(ctx.dims["V"], dtype=wp.int32, device=dev)
        self._frames, self._points, self._visibility = inputs["tangents"], inputs["points"], inputs["visibility"]
        self._lighting = ShLighting(inputs["lighting"], n)
        self._frame_lighting = inputs["lighting"]
        self._tables = sh_kernels(n).tables(dev)
        self._kernel = kernels.shade_kernel(n, p["view_order"], p["lighting"], p["cosine"], p["visibility_space"],
                                            p["evaluation"])
        self._radiance = wp.zeros((ctx.dims["V"], 3), dtype=wp.float32, device=dev)
        self._bind_kernel_inputs()
        self.slot_brdfs: list = []
        self.build_s: list = []
        self.zh = None
        self._upload_materials()
        if p["lighting"] == "zh":
            self._fit_lighting()
        return {"radiance": self._radiance}

    def _bind_kernel_inputs(self) -> None:
        """The shading kernel's argument structs over the stage's fixed buffers (built once: the
        buffers are written in place when materials or lighting change)."""
        surface = kernels.Receivers()
        surface.frames, surface.points = self._frames, self._points
        surface.visibility, surface.material = self._visibility, self._material
        ops = kernels.Operators()
        ops.light_sh, ops.view_sh, ops.rank, ops.matrices = self._light_sh, self._view_sh, self._rank, self._matrices
        ops.channels = self._channels
        ops.cos_sh, ops.specular = self._cos, self._specular
        light = kernels.ViewLighting()
        light.eye, light.sh = self._eye, self._lighting.light
        light.zh_axes, light.zh_coeffs = self._zh_axes, self._zh_coeffs
        out = kernels.ShadeOutputs()
        out.radiance, out.flags = self._radiance, self._flags
        self._surface, self._ops, self._view_lighting, self._outputs = surface, ops, light, out

    def _operator(self, brdf):
        p = self.params
        try:
            return OPERATORS.get(brdf, p["order"], p["rank"], p["cosine"], p["view_resolution"], p["view_order"])
        except ValueError as exc:
            raise StageError(f"stage {self.name!r}: {exc}") from None

    def _upload_materials(self) -> None:
        """Resolve every mesh's BRDF (the run's assignment, else this stage's), build or fetch
        the operators and write them, and the per-vertex slots, into the fixed buffers."""
        p = self.params
        mats = self._state.materials
        per_mesh = [mats.brdf_of(m.path, self._brdf) for m in self._scene.meshes]
        distinct, keys, mesh_brdf = [], [], []
        for b in per_mesh:
            key = repr(sorted(b.describe().items(), key=lambda kv: kv[0]))
            if key not in keys:
                keys.append(key)
                distinct.append(b)
            mesh_brdf.append(keys.index(key))
        # a colour BRDF (a coloured measured table) takes three consecutive slots, one per channel
        first_slot, slot_brdfs, channels = [], [], []
        for b in distinct:
            parts = b.color_channels() or (b,)
            first_slot.append(len(slot_brdfs))
            slot_brdfs.extend(parts)
            channels.extend([len(parts)] + [1] * (len(parts) - 1))
        if len(slot_brdfs) > p["materials"]:
            raise StageError(f"stage {self.name!r}: {len(distinct)} distinct BRDFs need {len(slot_brdfs)} material slots "
                             f"(a colour table takes three), more than its {p['materials']} (parameter 'materials')")
        t0 = time.perf_counter()
        ops = [self._operator(b) for b in slot_brdfs]
        self.build_s.append(time.perf_counter() - t0)
        light = np.zeros(self._light_sh.shape, np.float32)
        view = np.zeros(self._view_sh.shape, np.float32)
        rank = np.zeros(self._rank.shape, np.int32)
        nch = np.ones(self._channels.shape, np.int32)
        nch[: len(channels)] = channels
        mat = np.zeros(self._matrices.shape, np.float32) if p["evaluation"] == "matrices" else None
        for s, op in enumerate(ops):
            light[s, : op.rank] = op.light_sh
            view[s, : op.rank] = op.view_sh
            rank[s] = op.rank
            if mat is not None:
                mat[s, : op.rank] = op.matrices()
        slots = np.zeros(self._material.shape[0], np.int32)
        for m, d in zip(self._scene.meshes, mesh_brdf):
            slots[m.vertex_offset : m.vertex_offset + m.vertex_count] = first_slot[d]
        self._light_sh.assign(light)
        self._view_sh.assign(view)
        self._rank.assign(rank)
        self._channels.assign(nch)
        if mat is not None:
            self._matrices.assign(mat)
        self._material.assign(slots)
        self.slot_brdfs = slot_brdfs
        self.slot_channels = nch[: len(slot_brdfs)].copy()
        self.operators = ops
        self.material_of_vertex = slots

    def _fit_lighting(self) -> None:
        """Fit the ZH lobes to the current frame's SH lighting (host work, outside any recorded
        frame) and tabulate how they turn with the lighting over the frames: the lobes of frame
        t are ``R_t R_now^T a_j`` (every distant light must turn alike)."""
        from ._lighting import fit_zh_lighting

        fl = self._frame_lighting
        fl.launch()  # refresh the SH of the current frame
        light = fl.sh(self.params["order"]).numpy().astype(np.float64)
        table = self._ctx.lighting.rotation_table(self._scene.frames)  # (T', K, 3, 3)
        if table.shape[1] > 1 and not np.allclose(table, table[:, :1], atol=1e-9):
            raise StageError(f"stage {self.name!r}: lighting = 'zh' needs the distant lights to turn together "
                             "(use lighting = 'rotate')")
        rot = table[:, 0] if table.shape[1] else np.eye(3)[None]
        now = rot[min(self._state.frame_index, rot.shape[0] - 1)]
        rel = np.einsum("tij,kj->tik", rot, now)  # R_t R_now^T
        self._zh_turn = wp.array(rel.astype(np.float32), dtype=wp.mat33, device=self._radiance.device)
        self.zh = fit_zh_lighting(light, self.params["zh_lobes"])
        self._zh_axes0.assign(self.zh.axes.astype(np.float32))
        self._zh_coeffs.assign(self.zh.coeffs.astype(np.float32))

    def notify_changed(self, flags, keys=frozenset()) -> bool:
        from ...scene._state import Change

        if flags & Change.PARAMETERS:
            return False
        if flags & Change.VIEW:
            self._viewer.moved()
        if flags & Change.MATERIAL:
            self._upload_materials()
        if flags & Change.LIGHTING and self.params["lighting"] == "zh":
            self._fit_lighting()
        return True

    # ---- per frame --------------------------------------------------------------------
    def launch(self, state):
        self._lighting.launch()
        dev = self._radiance.device
        if self._zh_axes.shape[0]:
            wp.launch(kernels.turn_axes_kernel, dim=self._zh_axes.shape[0], device=dev,
                      inputs=[state.frame_index_device, self._zh_turn, self._zh_axes0, self._zh_axes])

        def inputs(start, stop):
            return [self._surface, self._ops, self._view_lighting, self._tables, start, self._outputs]

        launch_parallel(self._kernel, self._radiance.shape[0], inputs, dev, min_count=CPU_CHUNK_MIN)

    # ---- reports ----------------------------------------------------------------------
    def diagnostics(self) -> dict:
        """Receivers of the last frame clamped for negative radiance, and seen at or below their
        horizon (shaded 0); the viewer (:mod:`warpshade.methods._viewer`: which one, where); the
        BRDFs of the slots and what building them took."""
        f = self._flags.numpy()
        out = {"negative_clamped": int(np.count_nonzero(f & kernels.FLAG_NEGATIVE)),
               "below_horizon": int(np.count_nonzero(f & kernels.FLAG_BELOW_HORIZON)),
               "viewer": self._viewer.describe(),
               "materials": [b.describe() for b in self.slot_brdfs],
               "operator_build_s": [round(op.build_s, 4) for op in self.operators]}
        if self.zh is not None:
            out["zh_lighting_error"] = self.zh.error
        return out

    def model_bytes(self) -> int:
        arrays = [self._light_sh, self._view_sh, self._rank, self._channels, self._matrices, self._material, self._zh_axes, self._zh_coeffs]
        return int(sum(a.capacity for a in arrays))


@register_stage
class RpoVisibilityTracedStage(FrameStage):
    type_name = "rpo.visibility_traced"
    needs_bvh = True
    description = "SH visibility ray traced at every frame in the tangent frames (open below the horizon)"
    parameters = {
        "order": _ORDER,
        "samples": rays_param(256, "rays per vertex per frame"),
        "seed": Param(0, int, "seed of the per-vertex sample rotations (the same rays every frame)"),
    }

    def dims(self):
        return {"C": self.params["order"] ** 2}

    def input_ports(self):
        return {"points": Port("vec3", ("V",)), "normals": Port("vec3", ("V",))}

    def output_ports(self):
        return {"visibility": Port("float32", ("V", "C"), "SH visibility, tangent frame", space="local"),
                "tangents": Port("mat33", ("V",), "tangent frames of the frame (rows t, b, n)")}

    def setup(self, ctx, inputs):
        from ...transfer import TransferTracer

        p = self.params
        self._points, self._normals = inputs["points"], inputs["normals"]
        self._tracer = TransferTracer(ctx.scene, p["order"], p["samples"], space="local", device=ctx.device,
                                      seed=p["seed"], below_horizon="visible", bvh=ctx.state.bvh)
        return {"visibility": self._tracer.visibility_sh, "tangents": self._tracer.tangent_frames.frames}

    def launch(self, state):
        self._tracer.launch(self._points, self._normals)


@register_stage
class RpoVisibilityStaticStage(PrecomputeStage):
    type_name = "rpo.visibility_static"
    version = 1
    description = "SH visibility ray traced once at a bake frame, tangent frame (open below the horizon)"
    parameters = {
        "order": _ORDER,
        "samples": rays_param(1024, "rays per vertex"),
        "seed": Param(0, int, "seed of the per-vertex sample rotations"),
        "frame": _FRAME,
    }

    def dims(self):
        return {"C": self.params["order"] ** 2}

    def output_ports(self):
        return {"visibility": Port("float32", ("V", "C"), "SH visibility at the bake frame, tangent frame",
                                    space="local")}

    def precompute(self, ctx, inputs):
        from ...transfer import compute

        p = self.params
        frame = float(ctx.scene.frames[0]) if p["frame"] is None else float(p["frame"])
        try:
            ctx.scene.frame_index(frame)
        except ValueError as exc:
            raise StageError(f"stage {self.name!r}: parameter 'frame': {exc}") from None
        vis = compute(ctx.scene, frame, p["order"], p["samples"], space="local", device=ctx.device, seed=p["seed"],
                      below_horizon="visible", progress=ctx.progress).visibility
        return {"visibility": np.asarray(vis, np.float32)}

    def check_artifact(self, outputs):
        v = np.asarray(outputs["visibility"])
        if v.dtype != np.float32 or v.ndim != 2 or not np.all(np.isfinite(v)):
            raise ValueError("rpo.visibility_static: visibility must be a finite float32 (V, C) array")
