"""Host orchestration of the SHEXP kernels on fixed device buffers.

:class:`ShexpShader` owns the structs and buffers of :mod:`._kernels` for one configuration
(order, exp method, shading path, accumulation, self-shadowing rule) and a fixed problem size
(vertex count, blocker node count, clusters x cut capacity, sphere lights). Host-side setters
upload into those fixed buffers (host work, between frames); :meth:`ShexpShader.launch` only launches
kernels on fixed buffers, so a frame is recordable; the ``bind_*`` methods point it at device
arrays that other code fills per frame (the frame state's lighting, the animated spheres). On
the CPU the receiver pass is split into chunks over a small thread pool
(:func:`warpshade._wp.launch_parallel`).

Typical use (what the stages do)::

    shader = ShexpShader(order=4, vertex_count=V, node_count=S, device="cpu")
    shader.bind_receivers(points, normals, albedo)       # device arrays, read every launch
    shader.set_flat_cut()                                 # every node, one cluster
    shader.upload_spheres(centres, radii)                 # or bind_spheres(device arrays)
    shader.upload_lighting(light_sh)                      # (3, n*n) float64, world frame
    shader.launch()                                       # -> shader.radiance (V, 3)
"""

from __future__ import annotations

import numpy as np

from ..._wp import cpu_workers, launch_parallel, resolve_device, wp
from ...basis.sh import DEFAULT_DEGREE
from ...basis.sh_warp import sh_kernels
from . import _kernels as kernels, _tables as tables, _trace_kernels as trace_kernels

__all__ = ["ShexpShader", "SphereTracer", "shade_receivers", "CPU_CHUNK_MIN_RECEIVERS"]

#: Below this many receivers the CPU receiver pass is one launch (a thread-pool round trip
#: costs ~0.5 ms, more than the split saves on a few hundred receivers).
CPU_CHUNK_MIN_RECEIVERS = 2048
#: Default lat-long resolution (rows, columns) of the L*H(N) table over normals.
TABLE_SHAPE = (32, 64)


def _f32(a, shape=None) -> np.ndarray:
    out = np.ascontiguousarray(np.asarray(a, dtype=np.float32))
    return out if shape is None else out.reshape(shape)


class ShexpShader:
    """Fixed buffers and launches of one SHEXP configuration (see module docstring).

    Args:
        order: SH order n (2..MAX_KERNEL_ORDER).
        vertex_count: receivers (scene vertices).
        node_count: blocker spheres (hierarchy nodes or leaves) in the node arrays.
        clusters: receiver clusters (rows of the cut lists); 1 for the flat list.
        cut_capacity: entries per cut row (default ``node_count``).
        method: SH exponential (:data:`warpshade.basis.sh.EXP_METHODS`).
        degree: series degree of "ps"/"ps_star" (default 10 / 2).
        shade: "direct", "table" or "product_matrix" (:data:`._kernels.SHADE_MODES`).
        accumulate: "log" (SHEXP) or "product" (baseline).
        rule: self-shadowing rule, "none", "paper" or "continuous".
        window, window_size: visibility window kind (None, "cosine", ...) and size h.
        table_shape: (rows, cols) of the L*H(N) lat-long table (table mode).
        shade_order: shade with the visibility, lighting and clamped cosine truncated to this
            order (<= order): accumulate and exponentiate at a higher order than shading, the
            paper's Fig. 7e (default: ``order``).
        sphere_light_count: sphere lights the frame may have (fixed buffer size).
        store_visibility: also write the windowed visibility vectors ``g`` (V, n*n).
        device: Warp device.
        workers: CPU launch threads (default: every core).
    """

    def __init__(
        self,
        order: int,
        vertex_count: int,
        node_count: int,
        clusters: int = 1,
        cut_capacity: int | None = None,
        method: str = "hyb",
        degree: int | None = None,
        shade: str = "direct",
        accumulate: str = "log",
        rule: str = "continuous",
        window: str | None = None,
        window_size: float | None = None,
        table_shape: tuple = TABLE_SHAPE,
        sphere_light_count: int = 0,
        store_visibility: bool = False,
        shade_order: int | None = None,
        device=None,
        workers: int | None = None,
    ):
        from ...basis.sh_warp import MAX_KERNEL_ORDER

        if not 2 <= int(order) <= MAX_KERNEL_ORDER:
            raise ValueError(f"shexp: order must be in 2..{MAX_KERNEL_ORDER}, got {order!r}")
        if rule not in kernels.RULES:
            raise ValueError(f"shexp: rule must be one of {kernels.RULES}, got {rule!r}")
        if vertex_count < 0 or node_count < 0 or clusters < 1:
            raise ValueError(f"shexp: bad sizes vertex_count={vertex_count}, node_count={node_count}, clusters={clusters}")
        self.order = int(order)
        self.n2 = self.order * self.order
        self.shade_order = self.order if shade_order is None else int(shade_order)
        if not 1 <= self.shade_order <= self.order:
            raise ValueError(f"shexp: shade_order must be in 1..{self.order}, got {shade_order!r}")
        self._band_keep = (np.arange(self.order) < self.shade_order).astype(np.float64)
        self.method = method
        self.degree = int(degree if degree is not None else DEFAULT_DEGREE.get(method, 1))
        self.shade = shade
        self.accumulate = accumulate
        self.rule = rule
        self.device = resolve_device(device)
        self.workers = (cpu_workers() if self.device.is_cpu else 1) if workers is None else max(1, int(workers))
        self.vertex_count = int(vertex_count)
        self.node_count = int(node_count)
        self.clusters = int(clusters)
        self.cut_capacity = int(cut_capacity if cut_capacity is not None else max(node_count, 1))
        self.kernel = kernels.receiver_kernel(self.order, method, shade, accumulate)
        dev = self.device
        bundle = sh_kernels(self.order)
        self.sh_tables = bundle.tables(dev)
        self.exp_tables = bundle.exp_tables(dev)
        n = self.order

        b = kernels.BlockerSet()
        b.centres = wp.zeros(max(node_count, 1), dtype=wp.vec3, device=dev)
        b.radii = wp.zeros(max(node_count, 1), dtype=wp.float32, device=dev)
        b.is_static = wp.zeros(max(node_count, 1), dtype=wp.int32, device=dev)
        b.cut_nodes = wp.full((self.clusters, self.cut_capacity), -1, dtype=wp.int32, device=dev)
        b.cut_count = wp.zeros(self.clusters, dtype=wp.int32, device=dev)
        b.cut_weights = wp.ones((self.clusters, self.cut_capacity, n), dtype=wp.float32, device=dev)
        b.weighted = 0
        b.plane_centre = wp.zeros(0, dtype=wp.vec3, device=dev)
        b.plane_normal = wp.zeros(0, dtype=wp.vec3, device=dev)
        b.plane_radius = wp.zeros(0, dtype=wp.float32, device=dev)
        self.blockers = b

        r = kernels.ReceiverSet()
        r.points = wp.zeros(max(vertex_count, 1), dtype=wp.vec3, device=dev)
        r.normals = wp.zeros(max(vertex_count, 1), dtype=wp.vec3, device=dev)
        r.albedo = wp.zeros((max(vertex_count, 1), 3), dtype=wp.float32, device=dev)
        r.cluster = wp.zeros(max(vertex_count, 1), dtype=wp.int32, device=dev)
        r.baked = wp.zeros(max(vertex_count, 1), dtype=wp.int32, device=dev)
        r.bake = wp.zeros((1, self.n2), dtype=wp.float32, device=dev)
        self.receivers = r

        s = kernels.ShadeInputs()
        s.light = wp.zeros((3, self.n2), dtype=wp.float32, device=dev)
        s.cosine_zh = wp.array((kernels.cosine_zh(n) * self._band_keep).astype(np.float32), dtype=wp.float32, device=dev)
        s.window = wp.array((tables.window_alpha(n, window, window_size) * self._band_keep).astype(np.float32), dtype=wp.float32,
                            device=dev)
        rows, cols = table_shape if shade == "table" else (1, 1)
        s.lh_table = wp.zeros((rows, cols, 3, self.n2), dtype=wp.float32, device=dev)
        msize = self.n2 if shade == "product_matrix" else 1
        s.light_matrix = wp.zeros((3, msize, msize), dtype=wp.float32, device=dev)
        self.sphere_light_count = int(sphere_light_count)
        lights = max(self.sphere_light_count, 0)
        s.sphere_position = wp.zeros(lights, dtype=wp.vec3, device=dev)
        s.sphere_radius = wp.zeros(lights, dtype=wp.float32, device=dev)
        s.sphere_radiance = wp.zeros(lights, dtype=wp.vec3, device=dev)
        if lights and shade != "direct":
            lobes = tables.sphere_light_lobes(n)
            s.lobe_axis_angle = wp.array(_f32(lobes.axis_angle), dtype=wp.float32, device=dev)
            s.lobe_zh = wp.array(_f32(lobes.zh), dtype=wp.float32, device=dev)
        else:
            s.lobe_axis_angle = wp.zeros((2, 2), dtype=wp.float32, device=dev)
            s.lobe_zh = wp.zeros((2, 2, n), dtype=wp.float32, device=dev)
        self.shading = s
        self._light_rows = None  # (3, n*n) product_matrix source rows

        self.radiance = wp.zeros((max(vertex_count, 1), 3), dtype=wp.float32, device=dev)
        self.store_visibility = bool(store_visibility)
        self.visibility = wp.zeros((max(vertex_count, 1) if store_visibility else 1, self.n2), dtype=wp.float32, device=dev)
        self.fallbacks = wp.zeros(1, dtype=wp.int32, device=dev)
        o = kernels.ReceiverOutputs()
        o.radiance = self.radiance
        o.visibility = self.visibility
        o.store_visibility = 1 if self.store_visibility else 0
        o.fallbacks = self.fallbacks
        self.outputs = o

    def set_exp_tables(self, log_cap, ol_a, ol_b, ol_norm_max: float) -> None:
        """Use these blocking-cap log and OL tables (device arrays, e.g. precompute artifacts)
        instead of the process-wide ones: log_cap (S, n), ol_a/ol_b (S,) float32."""
        from ...basis.sh import CAP_THETA_MAX
        from ...basis.sh_warp import SHExpTables

        if tuple(log_cap.shape[1:]) != (self.order,):
            raise ValueError(f"shexp: log-cap table has shape {tuple(log_cap.shape)}, order {self.order} needs (S, {self.order})")
        t = SHExpTables()
        t.log_cap = log_cap
        t.log_cap_theta_max = float(CAP_THETA_MAX)
        t.ol_a = ol_a
        t.ol_b = ol_b
        t.ol_norm_max = float(ol_norm_max)
        self.exp_tables = t

    # ---- receivers ------------------------------------------------------------------------
    def bind_receivers(self, points, normals, albedo=None) -> None:
        """Read receiver positions/normals (and albedo) from these device arrays every launch."""
        self.receivers.points = self._device(points, wp.vec3, (self.vertex_count,), "points")
        self.receivers.normals = self._device(normals, wp.vec3, (self.vertex_count,), "normals")
        if albedo is not None:
            self.receivers.albedo = self._device(albedo, wp.float32, (self.vertex_count, 3), "albedo")

    def set_receiver_clusters(self, cluster) -> None:
        """Receiver cluster (row of the cut lists) of every vertex, (V,) int."""
        c = np.asarray(cluster, np.int64).reshape(-1)
        if c.shape[0] != self.vertex_count or (c.size and (c.min() < 0 or c.max() >= self.clusters)):
            raise ValueError(f"shexp: receiver clusters must be {self.vertex_count} values in 0..{self.clusters - 1}")
        self.receivers.cluster = wp.array(c.astype(np.int32), dtype=wp.int32, device=self.device)

    def set_baked(self, baked_mask, transfer) -> None:
        """Baked static visibility: per-vertex flag (V,) and transfer ``T_p`` (V, n*n) world frame."""
        mask = np.asarray(baked_mask, bool).reshape(-1)
        t = _f32(transfer)
        if mask.shape[0] != self.vertex_count or t.shape != (self.vertex_count, self.n2):
            raise ValueError(f"shexp: baked mask/transfer must be ({self.vertex_count},) and ({self.vertex_count}, {self.n2})")
        if not np.all(np.isfinite(t)):
            raise ValueError("shexp: baked transfer contains NaN or infinite values")
        self.receivers.baked = wp.array(mask.astype(np.int32), dtype=wp.int32, device=self.device)
        self.receivers.bake = wp.array(t, dtype=wp.float32, device=self.device)

    # ---- blockers -------------------------------------------------------------------------
    def bind_spheres(self, centres, radii, static=None) -> None:
        """Read sphere centres/radii from these device arrays (node_count,) every launch."""
        self.blockers.centres = self._device(centres, wp.vec3, (self.node_count,), "sphere centres")
        self.blockers.radii = self._device(radii, wp.float32, (self.node_count,), "sphere radii")
        if static is not None:
            self.set_static(static)

    def set_static(self, static) -> None:
        s = np.asarray(static, bool).reshape(-1)
        if s.shape[0] != self.node_count:
            raise ValueError(f"shexp: static flags must have {self.node_count} entries, got {s.shape[0]}")
        self.blockers.is_static = wp.array(s.astype(np.int32), dtype=wp.int32, device=self.device)

    def set_planes(self, planes) -> None:
        """Static planar blockers: rows ``(centre xyz, unit normal xyz, radius)``, (P, 7)
        (see :func:`._kernels.plane_cap`)."""
        p = np.asarray(planes, np.float64).reshape(-1, 7)
        if not np.all(np.isfinite(p)) or np.any(p[:, 6] < 0.0):
            raise ValueError("shexp: plane blockers must be finite with radius >= 0")
        n = p[:, 3:6] / np.maximum(np.linalg.norm(p[:, 3:6], axis=1, keepdims=True), 1e-300)
        dev = self.device
        self.blockers.plane_centre = wp.array(_f32(p[:, :3], (-1, 3)), dtype=wp.vec3, device=dev)
        self.blockers.plane_normal = wp.array(_f32(n, (-1, 3)), dtype=wp.vec3, device=dev)
        self.blockers.plane_radius = wp.array(_f32(p[:, 6]), dtype=wp.float32, device=dev)

    def upload_spheres(self, centres, radii) -> None:
        """Copy host sphere centres (node_count, 3) and radii (node_count,) into the buffers.

        Raises:
            ValueError: wrong shapes, NaN/inf, or negative radii (name the first bad sphere).
        """
        c = _f32(centres).reshape(-1, 3)
        r = _f32(radii).reshape(-1)
        if c.shape[0] != self.node_count or r.shape[0] != self.node_count:
            raise ValueError(f"shexp: expected {self.node_count} spheres, got centres {c.shape} and radii {r.shape}")
        bad = ~(np.all(np.isfinite(c), axis=1) & np.isfinite(r))
        if np.any(bad):
            raise ValueError(f"shexp: sphere {int(np.flatnonzero(bad)[0])} has a NaN or infinite centre/radius")
        if np.any(r < 0.0):
            raise ValueError(f"shexp: sphere {int(np.flatnonzero(r < 0.0)[0])} has a negative radius")
        if self.node_count:
            self.blockers.centres.assign(c)
            self.blockers.radii.assign(r)

    def set_flat_cut(self, nodes=None) -> None:
        """Every receiver cluster accumulates ``nodes`` (default: all nodes), weights 1."""
        nodes = np.arange(self.node_count) if nodes is None else np.asarray(nodes, np.int64).reshape(-1)
        if nodes.size > self.cut_capacity:
            raise ValueError(f"shexp: {nodes.size} nodes exceed the cut capacity {self.cut_capacity}")
        rows = np.full((self.clusters, self.cut_capacity), -1, np.int32)
        rows[:, : nodes.size] = nodes
        self.blockers.cut_nodes.assign(rows)
        self.blockers.cut_count.assign(np.full(self.clusters, nodes.size, np.int32))
        self.blockers.weighted = 0

    def bind_cut(self, cut_nodes, cut_count, cut_weights=None) -> None:
        """Read per-cluster cut lists (clusters, capacity) / counts (clusters,) and optional
        per-band ratio vectors (clusters, capacity, n) from these device arrays."""
        self.blockers.cut_nodes = cut_nodes
        self.blockers.cut_count = cut_count
        if cut_weights is not None:
            self.blockers.cut_weights = cut_weights
            self.blockers.weighted = 1
        else:
            self.blockers.weighted = 0

    # ---- lighting -------------------------------------------------------------------------
    @property
    def band_keep(self) -> np.ndarray:
        """Per-band factors (n,): 1 below ``shade_order``, 0 from it (what lighting is scaled by)."""
        return self._band_keep.copy()

    def upload_lighting(self, light_sh) -> None:
        """Distant lighting SH (3, n*n), world frame, into the fixed buffer (host write; bands
        from ``shade_order`` on are dropped)."""
        l = np.asarray(light_sh, np.float64)
        if l.shape != (3, self.n2) or not np.all(np.isfinite(l)):
            raise ValueError(f"shexp: lighting must be finite with shape (3, {self.n2}), got {l.shape}")
        from ...basis import sh

        self.shading.light.assign((l * self._band_keep[sh.band_of(self.order)]).astype(np.float32))

    def bind_lighting(self, light) -> None:
        """Read the distant lighting from this device array every launch: (3, n*n) float32,
        world frame, already truncated to ``shade_order`` (e.g. a stage's
        :class:`~warpshade.methods._common.ShLighting`)."""
        if tuple(light.shape) != (3, self.n2):
            raise ValueError(f"shexp: lighting must have shape (3, {self.n2}), got {tuple(light.shape)}")
        self.shading.light = self._device(light, wp.float32, (3, self.n2), "lighting")

    def bind_sphere_lights(self, position, radius, radiance) -> None:
        """Read the sphere lights from these device arrays every launch ((S,) vec3, (S,) float32,
        (S,) vec3; S = ``sphere_light_count``), e.g. a frame state's lighting."""
        for name, arr in (("positions", position), ("radii", radius), ("radiances", radiance)):
            if arr.shape[0] != self.sphere_light_count:
                raise ValueError(f"shexp: the shader was built for {self.sphere_light_count} sphere lights, "
                                 f"got {arr.shape[0]} {name}")
        self.shading.sphere_position = position
        self.shading.sphere_radius = radius
        self.shading.sphere_radiance = radiance

    def upload_sphere_lights(self, lights) -> None:
        """Sphere lights of the frame (objects with position, radius, radiance); at most the
        ``sphere_light_count`` given at construction."""
        lights = list(lights)
        if len(lights) != self.sphere_light_count:
            raise ValueError(f"shexp: the shader was built for {self.sphere_light_count} sphere lights, got {len(lights)}")
        if not lights:
            return
        self.shading.sphere_position.assign(_f32([l.position for l in lights], (-1, 3)))
        self.shading.sphere_radius.assign(_f32([l.radius for l in lights]))
        self.shading.sphere_radiance.assign(_f32([l.radiance for l in lights], (-1, 3)))

    # ---- frame ----------------------------------------------------------------------------
    def launch(self) -> None:
        """Launch the frame's kernels on the fixed buffers (no host work, capture-safe)."""
        dev = self.device
        s = self.shading
        if self.shade == "table":
            rows, cols = s.lh_table.shape[0], s.lh_table.shape[1]
            wp.launch(kernels.lh_table_kernel(self.order), dim=(rows, cols),
                      inputs=[s.light, s.cosine_zh, self.sh_tables, s.lh_table], device=dev)
        elif self.shade == "product_matrix":
            s.light_matrix.zero_()
            wp.launch(sh_kernels(self.order).product_matrix_kernel, dim=3,
                      inputs=[s.light, self.sh_tables, s.light_matrix], device=dev)
        rule = kernels.RULES.index(self.rule)

        self.fallbacks.zero_()

        def inputs(start, stop):
            return [self.blockers, self.receivers, s, self.sh_tables, self.exp_tables, self.outputs, self.degree, rule, start]

        launch_parallel(self.kernel, self.vertex_count, inputs, dev, self.workers, min_count=CPU_CHUNK_MIN_RECEIVERS)

    def fallback_count(self) -> int:
        """Receivers of the last launch whose visibility fell back to the scalar estimate
        (the series left the bound of a visibility function; see :func:`._kernels.receiver_kernel`)."""
        return int(self.fallbacks.numpy()[0])

    def model_bytes(self) -> int:
        arrays = [self.blockers.cut_nodes, self.blockers.cut_weights, self.shading.lh_table, self.shading.light_matrix,
                  self.receivers.bake]
        return int(sum(a.capacity for a in arrays))

    # ---- helpers --------------------------------------------------------------------------
    def _device(self, values, dtype, shape, name):
        if isinstance(values, wp.array):
            if values.device != self.device:
                raise ValueError(f"shexp: {name} live on {values.device}, the shader on {self.device}")
            return values
        a = np.asarray(values, np.float32)
        inner = 3 if dtype == wp.vec3 else None
        if inner is not None:
            a = a.reshape(-1, 3)
        if a.shape[0] != shape[0]:
            raise ValueError(f"shexp: {name} must have {shape[0]} rows, got {a.shape[0]}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"shexp: {name} contain NaN or infinite values")
        return wp.array(a, dtype=dtype, device=self.device)


class SphereTracer:
    """Ray-traced shading against blocker spheres (see :func:`._trace_kernels.sphere_trace_kernel`).

    Shares the blocker and receiver structs of a :class:`ShexpShader` (same spheres, same
    replacement rule). Outputs: ``radiance``/``stderr`` (V,) vec3 with the environment map,
    and ``transfer`` (V, n*n) for shading with SH lighting (:meth:`shade_sh`).
    """

    def __init__(self, shader: ShexpShader, environment, samples: int = 512, seed: int = 0):
        from ...scene._lighting import Environment
        from ...scene._lighting_warp import upload_environment

        if samples < 4:
            raise ValueError(f"sphere tracer: samples must be >= 4, got {samples}")
        self.shader = shader
        # an Environment (uploaded once) or an EnvironmentMap that turns with the frame state
        self.env = upload_environment(environment, shader.device) if isinstance(environment, Environment) else environment
        self.iterations = int(samples) // 2
        self.seed = int(seed)
        dev = shader.device
        self.radiance = wp.zeros(max(shader.vertex_count, 1), dtype=wp.vec3, device=dev)
        self.stderr = wp.zeros(max(shader.vertex_count, 1), dtype=wp.vec3, device=dev)
        self.transfer = wp.zeros((max(shader.vertex_count, 1), shader.n2), dtype=wp.float32, device=dev)
        o = trace_kernels.TraceOutputs()
        o.radiance = self.radiance
        o.stderr = self.stderr
        o.transfer = self.transfer
        self.outputs = o
        self.kernel = trace_kernels.sphere_trace_kernel(shader.order)

    def launch(self) -> None:
        sh_ = self.shader
        rule = kernels.RULES.index(sh_.rule)

        def inputs(start, stop):
            return [sh_.blockers, sh_.receivers, self.env, self.outputs, self.iterations, self.seed, rule, start]

        launch_parallel(self.kernel, sh_.vertex_count, inputs, sh_.device, sh_.workers)

    def shade_sh(self, light_sh, albedo) -> np.ndarray:
        """``albedo / pi * max(0, dot(L_c, t))`` with the traced transfer, (V, 3) float64."""
        t = self.transfer.numpy().astype(np.float64)
        rgb = t @ np.asarray(light_sh, np.float64).T
        return np.asarray(albedo, np.float64) / np.pi * np.maximum(rgb, 0.0)


def shade_receivers(points, normals, albedo, centres, radii, light_sh, order: int = 4, device=None,
                    sphere_lights=(), static=None, baked=None, bake=None, planes=None, **options):
    """One-shot SHEXP shading of host arrays (tests, scripts): returns (radiance, visibility).

    Args:
        points, normals: receivers (V, 3); albedo (V, 3).
        centres, radii: blocker spheres (S, 3), (S,) -- the flat list, every receiver sees all.
        light_sh: distant lighting (3, n*n), world frame.
        order: SH order n.
        sphere_lights: sphere light objects (position, radius, radiance).
        static, baked, bake: static sphere flags (S,), baked receiver flags (V,) and baked
            transfer (V, n*n) (section 7 static visibility).
        planes: static planar blockers, rows (centre, normal, radius), (P, 7).
        **options: :class:`ShexpShader` keyword arguments (method, degree, shade, accumulate,
            rule, window, window_size, table_shape, workers).

    Returns:
        ``(radiance (V, 3), visibility (V, n*n))`` float32 NumPy arrays.
    """
    points = np.asarray(points, np.float64).reshape(-1, 3)
    centres = np.asarray(centres, np.float64).reshape(-1, 3)
    shader = ShexpShader(order, points.shape[0], centres.shape[0], sphere_light_count=len(list(sphere_lights)),
                         store_visibility=True, device=device, **options)
    shader.bind_receivers(points, normals, albedo)
    shader.set_flat_cut()
    shader.upload_spheres(centres, radii)
    if static is not None:
        shader.set_static(static)
    if baked is not None:
        shader.set_baked(baked, bake)
    if planes is not None:
        shader.set_planes(planes)
    shader.upload_lighting(light_sh)
    shader.upload_sphere_lights(sphere_lights)
    shader.launch()
    return shader.radiance.numpy()[: points.shape[0]].copy(), shader.visibility.numpy()[: points.shape[0]].copy()
