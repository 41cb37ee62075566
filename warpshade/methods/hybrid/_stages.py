"""Per-frame ray tracing with few rays and a control variate, reused over frames and the mesh.

* ``hybrid.visibility_transfer`` (per frame): SH visibility as world-frame diffuse transfer, the
  control of ``hybrid.trace``: a data-driven visibility model's local visibility
  (``visibility.predict``), ``R(F^T)(v * cos)`` (:func:`._kernels.visibility_transfer_kernel`), or
  with ``space = "world"`` a world-frame visibility such as SHEXP's (``shexp.visibility``),
  ``v * cos_n`` with the clamped cosine about the vertex normal, at a visibility order up to the
  transfer's (:func:`._kernels.world_visibility_transfer_kernel`).

* ``hybrid.trace`` (per frame): the diffuse transfer of every vertex from ``samples`` rays per
  vertex and frame (a spherical Fibonacci set rotated per vertex and per frame), with a control
  model's transfer ``T_hat`` as control variate (frames in cycles of ``cycle`` shifted Fibonacci
  sets that are stratified together, :mod:`._kernels`)::

      T_i = T_hat_i + (4 pi / K) sum_k [V(w_k) max(0, n.w_k) - f_hat(w_k)] y_i(w_k),
      f_hat(w) = sum_j T_hat_j y_j(w)

  (unbiased for the projection whatever the control; its variance is that of the control's
  residual). The residual is filtered over mesh neighbours (edge-aware: normal and distance
  weights, ``filter_iterations`` Jacobi passes) and averaged per vertex over frames (an
  exponential moving average, uniform for the first ``1 / alpha`` frames); a vertex's history is
  cut where it moved more than ``motion`` mean edge lengths or its normal turned more than
  ``normal_turn`` degrees since the last frame, or where the fresh residual disagrees with the
  history by more than ``threshold`` times their combined variance, and fades as the
  disagreement grows towards that (:mod:`._kernels`). With ``warmup_frames`` ``N > 0`` the output is
  filtered further (``warmup_passes`` passes over the history, blended in per vertex) where a
  vertex's history holds fewer than ``N`` effective frames -- the clip's first frames and after
  cuts -- as far as needed to bring its variance to that of ``N`` frames; the history itself is
  left as it is (:func:`._kernels.warm_blend_kernel`).

  Controls (``control``): ``model`` -- a transfer on the input port ``control`` (the data-driven
  transfer, LDPRT's local transfer with ``space = "local"`` and the tangent frames on ``tangents``,
  a static bake); ``previous`` -- the stage's own last estimate (the history then lives in the
  control: the one-frame estimate ``T_prev + r`` is filtered and ``T = (1 - a) T_prev + a B(T_prev + r)``,
  ``B`` the filter: filtering the correction ``r`` alone and adding it to the state would let the
  filter's alternating modes grow from frame to frame); ``none`` -- plain tracing with reuse.
  Output: ``transfer`` (V, C) for ``prt.shade`` (world frame), or for ``ldprt.shade_rotated``
  (local frame). The filter averages coefficients of neighbours as they are: in the tangent
  frames, whose axes turn from vertex to vertex, that blurs more (measured on the blockers and
  the cloth: ``previous`` in the local frame has about twice the error of the world frame), so the
  local frame suits a control that leaves a small residual (LDPRT's transfer). The frame counter that draws new rotations is a device array advanced inside the
  recorded frame. With ``quantity = "visibility"`` the same estimator gives the SH visibility
  (open below the horizon, tangent frames with ``space = "local"``) that ``rpo.shade`` reads,
  with e.g. ``rpo.visibility_static`` as control. :meth:`HybridTraceStage.diagnostics` reports
  the effective samples per vertex, the history cuts of the last frame and the variance estimate.
"""

from __future__ import annotations

import math

import numpy as np

from ..._wp import cpu_workers, launch_parallel, wp
from ...basis import sh
from ...basis.sh_warp import sh_kernels
from .._common import order_param, rays_param
from ..stage import FrameStage, Param, Port, StageError, register_stage
from . import _kernels as kernels
from ._model import surface_neighbours

__all__: list[str] = []

CONTROLS = ("model", "previous", "none")
SPACES = ("world", "local")
#: Vertices per chunk below which the ray launch is not split over CPU threads.
_CHUNK_MIN_VERTICES = 256


@register_stage
class HybridTraceStage(FrameStage):
    type_name = "hybrid.trace"
    needs_bvh = True
    description = "transfer from few rays per frame with a control variate, reused over frames and mesh neighbours"
    parameters = {
        "order": order_param(6, minimum=1, maximum=8),
        "samples": rays_param(32, "rays per vertex per frame", minimum=1),
        "seed": Param(0, int, "seed of the per-vertex, per-frame sample rotations"),
        "control": Param("model", str, "control variate: a model's transfer on port 'control', the last estimate, "
                         "or none", choices=CONTROLS),
        "quantity": Param("transfer", str, "what the rays estimate: diffuse transfer (for prt.shade) or SH "
                          "visibility open below the horizon (output 'visibility', for rpo.shade)",
                          choices=("transfer", "visibility")),
        "space": Param("world", str, "frame of the coefficients (local: per-vertex tangent frames on port 'tangents')",
                       choices=SPACES),
        "cycle": Param(16, int, "frames per cycle of shifted Fibonacci sets (stratified together; one random "
                       "rotation per vertex and cycle); 1: a new rotation every frame", minimum=1, maximum=256),
        "alpha": Param(0.1, float, "smallest weight of a new frame in the moving average (1: no reuse over frames)",
                       minimum=1e-3, maximum=1.0),
        "threshold": Param(2.0, float, "history cut when |fresh - history|^2 exceeds this many times their variance",
                           minimum=0.0),
        "fade": Param(1.0, float, "the history fades for z = |fresh - history|^2 / variance above this (weight of the "
                      "fresh frame ((z - fade) / (threshold - fade))^2), is cut above the threshold", minimum=0.0),
        "test": Param("filtered", str, "what the variance test compares with the history: the one-frame estimate before "
                      "the filter (raw, against its own variance) or after it (filtered)", choices=("raw", "filtered")),
        "reproject": Param(False, bool, "world frame: carry each vertex's history by its tangent frame's turn since the "
                           "last frame (port 'tangents'), so that a turning surface keeps it"),
        "reset": Param("hard", str, "below the threshold: the history fades from 'fade' on (hard), or the fresh frame "
                       "gets the weight of least mean squared error for the history's estimated bias (soft)",
                       choices=("hard", "soft")),
        "bias_frames": Param(1, int, "soft reset: frames over which the history's bias is estimated (a moving average "
                             "of the excess of |fresh - history|^2 over its variance; 1: this frame's alone)",
                             minimum=1, maximum=64),
        "motion": Param(1.0, float, "history cut when a vertex moves more than this many mean edge lengths per frame",
                        minimum=0.0),
        "normal_turn": Param(20.0, float, "history cut when a normal turns more than this (degrees) per frame",
                             minimum=0.0, maximum=180.0),
        "filter_iterations": Param(1, int, "passes of the edge-aware filter over mesh neighbours (0: none)",
                                   minimum=0, maximum=4),
        "sigma_normal": Param(0.3, float, "normal weight exp(-(1 - n.n') / sigma^2)", minimum=1e-3),
        "sigma_distance": Param(1.0, float, "distance weight width in mean edge lengths", minimum=1e-3),
        "warmup_frames": Param(0.0, float, "history-aware filter: where a vertex's history holds fewer than this many "
                               "effective frames (warm-up, after a cut) the output is filtered further, as far as "
                               "the missing frames' variance needs (0: off)", minimum=0.0, maximum=1000.0),
        "warmup_passes": Param(2, int, "history-aware filter: passes of the edge-aware filter over the history at "
                               "full strength", minimum=1, maximum=8),
        "warmup_limit": Param("mse", str, "history-aware filter: no further than the weight of least mean squared "
                              "error for the filter's estimated bias (mse), or as far as the missing frames need "
                              "(none)", choices=("mse", "none")),
        "warmup_noise": Param(1.0, float, "history-aware filter's limit: the history's actual variance as a fraction "
                              "of the tracked one (the tracked one is the formula for independent rays; stratified ray "
                              "sets and filter passes make the actual one smaller, see benchmarks/"
                              "bench_hybrid_variance.py)", minimum=1e-3, maximum=10.0),
    }

    #: Parameters of the history-aware filter, which is off with ``warmup_frames = 0``.
    WARMUP_PARAMETERS = ("warmup_passes", "warmup_limit", "warmup_noise")

    def __init__(self, name, params=None):
        super().__init__(name, params)
        # parameter-only problems: refused when the graph is checked, not after its precompute stages ran
        self._check_parameters()
        ignored = [k for k in self.WARMUP_PARAMETERS if k in (params or {})]
        if ignored and self.params["warmup_frames"] == 0.0:
            raise StageError(f"stage {self.name!r} ({self.type_name}): parameter(s) {', '.join(map(repr, ignored))} "
                             "only apply to the history-aware filter, which is off with warmup_frames = 0; give "
                             "warmup_frames > 0 or leave them out")

    def _check_parameters(self):
        """Refuse parameter combinations that do not apply (at graph check and again at set-up,
        where a parameter changed between frames arrives)."""
        if self.params["reproject"] and self.params["space"] == "local":
            raise StageError(f"stage {self.name!r} ({self.type_name}): parameter 'reproject' applies to the world "
                             "frame (space = 'world'); in the tangent frames (space = 'local') the history turns "
                             "with the surface already")

    def dims(self):
        return {"C": self.params["order"] ** 2}

    def input_ports(self):
        space = self.params["space"]
        ports = {"points": Port("vec3", ("V",)), "normals": Port("vec3", ("V",))}
        if self.params["control"] == "model":
            ports["control"] = Port("float32", ("V", "C"), f"control model's {self.params['quantity']}, {space} frame",
                                    space=space)
        if space == "local" or self.params["reproject"]:
            ports["tangents"] = Port("mat33", ("V",), "tangent frames, world space, rows (t, b, n)")
        return ports

    def output_ports(self):
        space = self.params["space"]
        if self.params["quantity"] == "visibility":
            return {"visibility": Port("float32", ("V", "C"), f"SH visibility (open below the horizon), {space} frame",
                                       space=space)}
        return {"transfer": Port("float32", ("V", "C"), f"diffuse transfer vectors, {space} frame", space=space)}

    def setup(self, ctx, inputs):
        p = self.params
        dev = ctx.device
        where = f"stage {self.name!r} ({self.type_name})"
        if ctx.state is None or ctx.state.bvh is None:
            raise StageError(f"{where}: needs the frame's BVH (state.bvh)")
        self._check_parameters()
        v, c = ctx.dims["V"], p["order"] ** 2
        try:
            self.neighbours = surface_neighbours(ctx.scene.faces, ctx.scene.points_at(float(ctx.scene.frames[0])))
        except ValueError as exc:
            raise StageError(f"{where}: {exc}") from None
        self.setup_report = dict(self.neighbours.report)
        self._dev = dev
        self._bvh = ctx.state.bvh
        self._points, self._normals = inputs["points"], inputs["normals"]
        self._use_local = 1 if p["space"] == "local" else 0
        self._frames_in = inputs["tangents"] if "tangents" in inputs else wp.empty(0, dtype=wp.mat33, device=dev)
        self._transfer = wp.zeros((v, c), dtype=wp.float32, device=dev)
        if p["control"] == "model":
            self._control, self._use_control = inputs["control"], 1
        elif p["control"] == "previous":
            self._control, self._use_control = self._transfer, 1
        else:
            self._control, self._use_control = wp.zeros((1, c), dtype=wp.float32, device=dev), 0
        self._step = wp.zeros(1, dtype=wp.int32, device=dev)
        self._raw = wp.zeros((v, c), dtype=wp.float32, device=dev)
        self._variance = wp.zeros(v, dtype=wp.float32, device=dev)
        nb = self.neighbours
        self._offsets = wp.array(nb.offsets, dtype=wp.int32, device=dev)
        self._neighbours = wp.array(nb.neighbours if nb.neighbours.size else np.zeros(1, np.int32), dtype=wp.int32, device=dev)
        self._scale = wp.array(nb.scale, dtype=wp.float32, device=dev)
        self._gain = wp.zeros(v, dtype=wp.float32, device=dev)
        self._gain.fill_(1.0)
        passes = p["filter_iterations"]
        self._buffers = [wp.zeros((v, c), dtype=wp.float32, device=dev) for _ in range(min(passes, 2))]
        self._gain_scratch = wp.zeros(v, dtype=wp.float32, device=dev) if passes > 1 else None
        self._fresh = self._raw if passes == 0 else self._buffers[(passes - 1) % 2]
        st = kernels.TemporalState()
        st.history = wp.zeros((v, c), dtype=wp.float32, device=dev)
        st.frames = wp.zeros(v, dtype=wp.float32, device=dev)
        st.variance_mean = wp.zeros(v, dtype=wp.float32, device=dev)
        st.variance = wp.zeros(v, dtype=wp.float32, device=dev)
        st.prev_points = wp.zeros(v, dtype=wp.vec3, device=dev)
        st.prev_normals = wp.zeros(v, dtype=wp.vec3, device=dev)
        st.reset = wp.zeros(v, dtype=wp.int32, device=dev)
        st.excess = wp.zeros(v, dtype=wp.float32, device=dev)
        self._state = st
        tp = kernels.TemporalParams()
        tp.alpha = float(p["alpha"])
        tp.motion = float(p["motion"])
        tp.normal_cos = float(math.cos(math.radians(p["normal_turn"])))
        tp.threshold = float(p["threshold"])
        tp.in_control = 1 if p["control"] == "previous" else 0
        tp.fade = float(p["fade"])
        tp.test_raw = 1 if p["test"] == "raw" else 0
        tp.soft = 1 if p["reset"] == "soft" else 0
        tp.bias_weight = 1.0 / float(p["bias_frames"])
        self._params = tp
        self._tables = sh_kernels(p["order"]).tables(dev)
        if p["reproject"]:
            self._prev_frames = wp.zeros(v, dtype=wp.mat33, device=dev)
            self._reproject_kernel = kernels.reproject_kernel(p["order"])
        # the step's sample set and its SH, shared by every vertex (written at the start of each frame)
        self._set_directions = wp.zeros(p["samples"], dtype=wp.vec3, device=dev)
        self._set_basis = wp.zeros((p["samples"], c), dtype=wp.float32, device=dev)
        self._cycle_table_kernel = kernels.cycle_table_kernel(p["order"])
        self._residual_kernel = kernels.residual_kernel(p["order"])
        self._filter_kernel = kernels.filter_kernel(p["order"])
        self._temporal_kernel = kernels.temporal_kernel(p["order"])
        self._workers = cpu_workers() if dev.is_cpu else 1
        self._output = self._transfer
        if p["warmup_frames"] > 0.0:
            # the filtered output is never fed back: with the last estimate as control it goes to its own array
            if tp.in_control:
                self._output = wp.zeros((v, c), dtype=wp.float32, device=dev)
            self._warm_buffers = [wp.zeros((v, c), dtype=wp.float32, device=dev) for _ in range(2)]
            self._warm_variance = [wp.zeros(v, dtype=wp.float32, device=dev) for _ in range(2)]
            self._warm_weight = wp.zeros(v, dtype=wp.float32, device=dev)
            self._warm_filter_kernel = kernels.warm_filter_kernel(p["order"])
            self._warm_blend_kernel = kernels.warm_blend_kernel(p["order"])
        return {"visibility" if p["quantity"] == "visibility" else "transfer": self._output}

    def launch(self, state):
        p, dev = self.params, self._dev
        v = self._transfer.shape[0]
        settings = kernels.residual_settings(
            quantity=kernels.QUANTITY_VISIBILITY if p["quantity"] == "visibility" else kernels.QUANTITY_TRANSFER,
            count=p["samples"], cycle=p["cycle"], seed=p["seed"], offset=self._bvh.offset, use_local=self._use_local,
            use_control=self._use_control, add_control=self._params.in_control)
        fixed = [self._bvh.id, self._points, self._normals, self._frames_in, self._control, settings, self._step,
                 self._set_directions, self._set_basis, self._tables]

        def ray_inputs(start, stop):
            return [*fixed, start, self._raw, self._variance]

        if p["reproject"]:
            target = self._transfer if self._params.in_control else self._state.history
            wp.launch(self._reproject_kernel, dim=v, device=dev,
                      inputs=[self._frames_in, self._prev_frames, self._state.frames, self._tables, target])
        wp.launch(self._cycle_table_kernel, dim=p["samples"], device=dev,
                  inputs=[self._step, int(p["samples"]), int(p["cycle"]), self._set_directions, self._set_basis])
        launch_parallel(self._residual_kernel, v, ray_inputs, dev, self._workers, min_count=_CHUNK_MIN_VERTICES)
        src = self._raw
        for i in range(p["filter_iterations"]):
            dst = self._buffers[i % 2]
            gain = self._gain if i == 0 else self._gain_scratch
            wp.launch(self._filter_kernel, dim=v, device=dev,
                      inputs=[self._offsets, self._neighbours, self._points, self._normals, self._scale,
                              float(p["sigma_normal"]), float(p["sigma_distance"]), src, dst, gain])
            src = dst
        wp.launch(self._temporal_kernel, dim=v, device=dev,
                  inputs=[self._points, self._normals, self._scale, self._control, self._use_control, self._fresh,
                          self._raw, self._variance, self._gain, self._state, self._params, self._transfer])
        if p["warmup_frames"] > 0.0:
            self._launch_warmup()
        wp.launch(kernels.advance_kernel, dim=1, device=dev, inputs=[self._step])

    def _launch_warmup(self):
        """The history-aware filter: ``warmup_passes`` passes over the history (with its variance)
        and the blend by each vertex's effective frames (:func:`._kernels.warm_blend_kernel`)."""
        p, dev = self.params, self._dev
        v = self._transfer.shape[0]
        st = self._state
        history = self._transfer if self._params.in_control else st.history
        src, src_var = history, st.variance
        for i in range(p["warmup_passes"]):
            dst, dst_var = self._warm_buffers[i % 2], self._warm_variance[i % 2]
            wp.launch(self._warm_filter_kernel, dim=v, device=dev,
                      inputs=[self._offsets, self._neighbours, self._points, self._normals, self._scale,
                              float(p["sigma_normal"]), float(p["sigma_distance"]), src, src_var, dst, dst_var])
            src, src_var = dst, dst_var
        wp.launch(self._warm_blend_kernel, dim=v, device=dev,
                  inputs=[st.frames, float(p["warmup_frames"]), 1 if p["warmup_limit"] == "mse" else 0,
                          float(p["warmup_noise"]), history, st.variance, src, src_var, self._transfer,
                          self._output, self._warm_weight])

    def model_bytes(self) -> int:
        v, c = self._transfer.shape
        warm = 0
        if self.params["warmup_frames"] > 0.0:
            warm = v * c * (2 + (1 if self._output is not self._transfer else 0)) + 3 * v
        return int(4 * (v * c * (3 + min(self.params["filter_iterations"], 2)) + 12 * v + warm))

    def diagnostics(self) -> dict:
        """The last frame: effective samples per vertex (rays x effective frames x the filter's
        variance reduction), history cuts by cause, and the variance estimate of the transfer
        (the square root of its mean over vertices, relative to the transfer's RMS norm)."""
        if not hasattr(self, "_state"):
            return {}
        frames = self._state.frames.numpy().astype(np.float64)
        gain = self._gain.numpy().astype(np.float64)
        eff = self.params["samples"] * frames * gain
        reset = self._state.reset.numpy()
        var = self._state.variance.numpy().astype(np.float64)
        t = self._transfer.numpy().astype(np.float64)
        norm = float(np.sqrt(np.mean(np.sum(t * t, axis=1)))) or 1.0
        warm = {}
        if self.params["warmup_frames"] > 0.0:
            w = self._warm_weight.numpy().astype(np.float64)
            warm = {"warmup_weight_mean": float(w.mean()), "warmup_vertices": int(np.count_nonzero(w > 0.0))}
        return {
            **warm,
            "effective_samples_mean": float(eff.mean()), "effective_samples_min": float(eff.min()),
            "effective_samples_p05": float(np.percentile(eff, 5)),
            "resets_variance": int(np.count_nonzero(reset == 1)), "resets_motion": int(np.count_nonzero(reset == 2)),
            "resets_nonfinite": int(np.count_nonzero(reset == 3)),
            "variance_rel": float(np.sqrt(max(var.mean(), 0.0))) / norm,
            "steps": int(self._step.numpy()[0]),
            **{f"surface_{k}": v for k, v in self.setup_report.items()},
        }


@register_stage
class HybridVisibilityTransferStage(FrameStage):
    type_name = "hybrid.visibility_transfer"
    description = ("diffuse transfer (world frame) from SH visibility, the clamped cosine re-applied: "
                   "a control for hybrid.trace")
    parameters = {
        "order": order_param(6, minimum=1, maximum=8),
        "space": Param("local", str, "frame of the visibility: local (tangent frames on 'tangents', e.g. "
                       "visibility.predict) or world (e.g. shexp.visibility; the cosine about the vertex normal)",
                       choices=SPACES),
        "visibility_order": Param(None, int, "SH order of the visibility (default: order); lower orders are "
                                  "zero-padded", minimum=1, maximum=8),
    }

    def __init__(self, name, params=None):
        super().__init__(name, params)
        self._check_parameters()  # refused when the graph is checked, not after the control's precompute

    def _check_parameters(self):
        n, nv = self.params["order"], self.params["visibility_order"]
        where = f"stage {self.name!r} ({self.type_name})"
        if nv is not None and nv > n:
            raise StageError(f"{where}: parameter 'visibility_order' = {nv} is above 'order' = {n} (the transfer "
                             "cannot hold it)")
        if nv is not None and nv != n and self.params["space"] != "world":
            raise StageError(f"{where}: parameter 'visibility_order' applies to space = 'world' only")

    def dims(self):
        nv = self.params["visibility_order"] or self.params["order"]
        return {"C": self.params["order"] ** 2, "Cv": nv * nv}

    def input_ports(self):
        if self.params["space"] == "world":
            return {"visibility": Port("float32", ("V", "Cv"), "SH visibility (no cosine), world frame", space="world"),
                    "normals": Port("vec3", ("V",))}
        return {"visibility": Port("float32", ("V", "Cv"), "SH visibility (no cosine, open below the horizon), "
                                   "tangent frame", space="local"),
                "tangents": Port("mat33", ("V",), "the tangent frames of the visibility, rows (t, b, n)")}

    def output_ports(self):
        return {"transfer": Port("float32", ("V", "C"), "diffuse transfer implied by the visibility, world frame",
                                 space="world")}

    def setup(self, ctx, inputs):
        dev = ctx.device
        n = self.params["order"]
        nv = self.params["visibility_order"] or n  # checked against order and space in __init__
        self._vis = inputs["visibility"]
        self._tables = sh_kernels(n).tables(dev)
        if self.params["space"] == "world":  # the cosine's axis per vertex: its normal
            self._axes = inputs["normals"]
            self._cos = wp.array(sh.clamped_cosine_zh(n, "zh").astype(np.float32), dtype=wp.float32, device=dev)
            self._kernel = kernels.world_visibility_transfer_kernel(n, nv)
        else:
            self._axes = inputs["tangents"]  # the visibility's tangent frames (the cosine about their n row)
            self._cos = wp.array(sh.clamped_cosine_sh(n).astype(np.float32), dtype=wp.float32, device=dev)
            self._kernel = kernels.visibility_transfer_kernel(n)
        self._transfer = wp.zeros((ctx.dims["V"], n * n), dtype=wp.float32, device=dev)
        return {"transfer": self._transfer}

    def launch(self, state):
        launch_parallel(self._kernel, self._transfer.shape[0],
                        lambda a, b: [self._vis, self._axes, self._cos, self._tables, a, self._transfer],
                        self._transfer.device, min_count=_CHUNK_MIN_VERTICES)

    def model_bytes(self) -> int:
        return int(self._transfer.size * 4) if hasattr(self, "_transfer") else 0
