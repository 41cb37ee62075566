"""Environment maps on the Warp device: bilinear lookup and luminance importance sampling.

:func:`upload_environment` turns a :class:`warpshade.scene._lighting.Environment` into an
:class:`EnvironmentMap` ``@wp.struct`` that kernels take as an argument, and the ``@wp.func``
helpers below read it:

* :func:`env_radiance` -- bilinearly filtered radiance in a *world* direction, the exact float32
  counterpart of :meth:`Environment.radiance`: the direction is taken to the map frame with
  ``to_world^T``, then ``theta = acos(z)``, ``phi = atan2(y, x)`` (in [0, 2 pi)) index the
  lat-long image (row 0 = +z pole, texel centres at ``(i + 0.5) pi / H`` and
  ``(j + 0.5) 2 pi / W``), wrapping in azimuth and clamping at the poles.
* :func:`env_sample` -- draws a world direction with a solid-angle pdf that is piecewise
  constant per texel: texel ``(i, j)`` is chosen with probability proportional to
  ``(luminance(i, j) + LUMINANCE_FLOOR * mean_luminance) * solid_angle(i)`` (the exact texel
  solid angle ``(cos theta_i0 - cos theta_i1) 2 pi / W``, i.e. luminance times sin(theta) to
  first order), where ``luminance(i, j)`` is the texel's own, or half that of an edge neighbour,
  or a quarter of a corner neighbour's, whichever is largest (wrapping in azimuth): the bilinear
  look-up spreads every texel into its neighbours with those largest weights, and a small, very
  bright sun must be sampled there too through a marginal CDF over rows and a conditional CDF per row, and the
  direction is then uniform in solid angle inside the texel (``z`` uniform between the row's
  edge cosines, ``phi`` uniform in the column). Hence the pdf of a direction in texel
  ``(i, j)`` is ``(luminance(i, j) + floor) / sum(weights)`` per steradian.
* :func:`env_pdf` -- that pdf for any world direction.

The floor keeps the pdf positive where the bilinear filter spreads radiance half a texel into
black texels (so light sampling alone stays unbiased); a black map samples uniformly.
Luminance is Rec. 709: ``0.2126 R + 0.7152 G + 0.0722 B`` (negative values clamped to 0).

:class:`FrameLighting` is the frame's lighting on the device (the ``lighting`` of a
:class:`~warpshade.scene._state.FrameState`): the SH of every distant light rotated to the frame
(Warp zxzxz rotation of each light's first-pose projection), the frame's distant-light
directions, environment rotations and sphere-light centres, all filled by kernels from the
frame index on the device.
"""

import functools

import numpy as np

from .._wp import HostFields, HostInput, resolve_device, wp
from ..basis import quadrature
from ..basis.sh_warp import MAX_KERNEL_ORDER, SHTables, sh_kernels

__all__ = [
    "LUMINANCE_FLOOR",
    "EnvironmentMap",
    "upload_environment",
    "disabled_environment",
    "LatLongTaps",
    "latlong_taps",
    "env_radiance",
    "env_sample",
    "env_pdf",
    "env_texel_pdf_f64",
    "lookup_environment",
    "sample_environment",
    "FrameLighting",
]

wp.set_module_options({"enable_backward": False})

#: Added to every texel's luminance, as a fraction of the mean luminance, before building the
#: sampling CDF: about 1% of samples go uniformly over the sphere.
LUMINANCE_FLOOR = 0.01

_REC709 = np.array([0.2126, 0.7152, 0.0722])


@wp.struct
class EnvironmentMap:
    """A lat-long environment on the device (see module docstring).

    Fields:
        image: radiance, wp.array2d(vec3), shape (H, W), linear RGB, map frame.
        to_world: map-to-world rotation, a one-element wp.array(mat33): a view into the frame's
            lighting (:class:`FrameLighting`) when the environment turns over frames, so kernels
            read the current frame's rotation without the struct changing.
        height, width: image size.
        row_cdf: marginal CDF over rows, shape (H + 1,), from 0 to 1.
        col_cdf: conditional CDF over columns per row, shape (H, W + 1).
        texel_pdf: solid-angle pdf of each texel, shape (H, W), 1/sr.
        row_cos: ``cos(theta)`` at the row edges, shape (H + 1,), from 1 to -1.
        enabled: 1 for a real map, 0 for the placeholder of "no environment" (radiance 0).
    """

    image: wp.array2d(dtype=wp.vec3)
    to_world: wp.array(dtype=wp.mat33)
    height: int
    width: int
    row_cdf: wp.array(dtype=float)
    col_cdf: wp.array2d(dtype=float)
    texel_pdf: wp.array2d(dtype=float)
    row_cos: wp.array(dtype=float)
    enabled: int


def env_texel_pdf_f64(env) -> tuple[np.ndarray, np.ndarray]:
    """Float64 sampling distribution of an environment.

    Returns:
        ``(texel_probability, texel_pdf)``, both shape (H, W), float64: the probability of
        choosing each texel (sums to 1) and the solid-angle pdf inside it (1/sr).
    """
    from scipy.ndimage import maximum_filter

    h, w = env.height, env.width
    # the bilinear look-up spreads a texel half a texel into its neighbours (weight up to 1/2 across
    # an edge, 1/4 at a corner), so a tiny bright source (a sun of a few texels) must be sampled
    # there too, or its bilinear skirt is reached only by rare, huge-weight samples
    raw = np.maximum(env.image.astype(np.float64) @ _REC709, 0.0)
    mode = ("nearest", "wrap")
    edges = np.maximum(maximum_filter(raw, size=(3, 1), mode=mode), maximum_filter(raw, size=(1, 3), mode=mode))
    lum = np.maximum(0.5 * edges, 0.25 * maximum_filter(raw, size=3, mode=mode))
    lum = np.maximum(raw, lum)
    solid = quadrature.latlong(h, w).weights.reshape(h, w)  # exact texel solid angles
    mean = float((lum * solid).sum() / (4.0 * np.pi))
    density = lum + LUMINANCE_FLOOR * mean if mean > 0.0 else np.ones_like(lum)
    weights = density * solid
    prob = weights / weights.sum()
    return prob, density / weights.sum()


def upload_environment(env, device=None, to_world=None) -> EnvironmentMap:
    """Upload an :class:`~warpshade.scene._lighting.Environment` and its sampling CDFs.

    Args:
        env: the environment (lat-long image, map frame, ``to_world``).
        device: Warp device (None = Warp's default).
        to_world: optional one-element wp.array(mat33) on ``device`` to read the map-to-world
            rotation from (default: a new array holding ``env.to_world``).

    Returns:
        :class:`EnvironmentMap` whose arrays live on ``device``.
    """
    dev = resolve_device(device)
    h, w = env.height, env.width
    prob, pdf = env_texel_pdf_f64(env)
    row_p = prob.sum(axis=1)
    row_cdf = np.concatenate([[0.0], np.cumsum(row_p)])
    row_cdf /= row_cdf[-1]
    col_cdf = np.concatenate([np.zeros((h, 1)), np.cumsum(prob, axis=1)], axis=1)
    col_cdf /= np.where(col_cdf[:, -1:] > 0.0, col_cdf[:, -1:], 1.0)
    out = EnvironmentMap()
    out.image = wp.array(env.image.astype(np.float32), dtype=wp.vec3, device=dev)
    if to_world is None:
        to_world = wp.array([wp.mat33(*np.asarray(env.to_world, np.float32).reshape(-1))], dtype=wp.mat33, device=dev)
    out.to_world = to_world
    out.height = h
    out.width = w
    out.row_cdf = wp.array(row_cdf.astype(np.float32), dtype=float, device=dev)
    out.col_cdf = wp.array(col_cdf.astype(np.float32), dtype=float, device=dev)
    out.texel_pdf = wp.array(pdf.astype(np.float32), dtype=float, device=dev)
    out.row_cos = wp.array(np.cos(np.arange(h + 1) * (np.pi / h)).astype(np.float32), dtype=float, device=dev)
    out.enabled = 1
    return out


def disabled_environment(device=None) -> EnvironmentMap:
    """Placeholder :class:`EnvironmentMap` for "no environment" (radiance 0, pdf 0)."""
    dev = resolve_device(device)
    out = EnvironmentMap()
    out.image = wp.zeros((1, 1), dtype=wp.vec3, device=dev)
    out.to_world = wp.array([wp.mat33(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)], dtype=wp.mat33, device=dev)
    out.height = 1
    out.width = 1
    out.row_cdf = wp.array([0.0, 1.0], dtype=float, device=dev)
    out.col_cdf = wp.array([[0.0, 1.0]], dtype=float, device=dev)
    out.texel_pdf = wp.zeros((1, 1), dtype=float, device=dev)
    out.row_cos = wp.array([1.0, -1.0], dtype=float, device=dev)
    out.enabled = 0
    return out


@wp.func
def _to_map(env: EnvironmentMap, direction: wp.vec3) -> wp.vec3:
    return wp.normalize(wp.transpose(env.to_world[0]) * direction)


@wp.struct
class LatLongTaps:
    """The bilinear footprint of a direction on a lat-long map: rows ``r0, r1`` (clamped at the
    poles), columns ``c0, c1`` (wrapped in azimuth), and the weights ``fv``, ``fu`` of the second."""

    r0: int
    r1: int
    c0: int
    c1: int
    fv: float
    fu: float


@wp.func
def latlong_taps(d: wp.vec3, height: int, width: int):
    """:class:`LatLongTaps` of a unit map-frame direction on a ``height`` x ``width`` lat-long map
    (row 0 = +z pole, texel centres at ``(i + 0.5) pi / H`` and ``(j + 0.5) 2 pi / W``)."""
    theta = wp.acos(wp.clamp(d[2], -1.0, 1.0))
    phi = wp.atan2(d[1], d[0])
    if phi < 0.0:
        phi += 2.0 * wp.pi
    v = theta / wp.pi * float(height) - 0.5
    u = phi / (2.0 * wp.pi) * float(width) - 0.5
    v0 = wp.floor(v)
    u0 = wp.floor(u)
    t = LatLongTaps()
    t.fv = v - v0
    t.fu = u - u0
    t.r0 = wp.clamp(int(v0), 0, height - 1)
    t.r1 = wp.clamp(int(v0) + 1, 0, height - 1)
    t.c0 = ((int(u0) % width) + width) % width
    t.c1 = (t.c0 + 1) % width
    return t


@wp.func
def env_radiance(env: EnvironmentMap, direction: wp.vec3) -> wp.vec3:
    """Bilinear radiance of the environment in a world direction (0 when disabled)."""
    if env.enabled == 0:
        return wp.vec3(0.0)
    t = latlong_taps(_to_map(env, direction), env.height, env.width)
    top = (1.0 - t.fu) * env.image[t.r0, t.c0] + t.fu * env.image[t.r0, t.c1]
    bottom = (1.0 - t.fu) * env.image[t.r1, t.c0] + t.fu * env.image[t.r1, t.c1]
    return (1.0 - t.fv) * top + t.fv * bottom


@wp.func
def env_pdf(env: EnvironmentMap, direction: wp.vec3) -> float:
    """Solid-angle pdf (1/sr) of :func:`env_sample` for a world direction (0 when disabled)."""
    if env.enabled == 0:
        return 0.0
    d = _to_map(env, direction)
    theta = wp.acos(wp.clamp(d[2], -1.0, 1.0))
    phi = wp.atan2(d[1], d[0])
    if phi < 0.0:
        phi += 2.0 * wp.pi
    row = wp.clamp(int(theta / wp.pi * float(env.height)), 0, env.height - 1)
    col = wp.clamp(int(phi / (2.0 * wp.pi) * float(env.width)), 0, env.width - 1)
    return env.texel_pdf[row, col]


@wp.func
def env_sample(env: EnvironmentMap, u1: float, u2: float, u3: float, u4: float) -> wp.vec4:
    """Draw a world direction from the luminance distribution.

    Args:
        env: the environment (must be enabled).
        u1, u2: uniform numbers in [0, 1) choosing the texel (row, then column).
        u3, u4: uniform numbers in [0, 1) placing the direction inside the texel.

    Returns:
        vec4 ``(x, y, z, pdf)``: the unit world direction and its solid-angle pdf (1/sr).
    """
    h = env.height
    w = env.width
    # Row: largest r with row_cdf[r] <= u1 (binary search over the marginal CDF).
    lo = int(0)
    hi = h
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if env.row_cdf[mid] <= u1:
            lo = mid
        else:
            hi = mid
    row = lo
    clo = int(0)
    chi = w
    while chi - clo > 1:
        mid = (clo + chi) // 2
        if env.col_cdf[row, mid] <= u2:
            clo = mid
        else:
            chi = mid
    col = clo
    z = env.row_cos[row] + (env.row_cos[row + 1] - env.row_cos[row]) * u3
    z = wp.clamp(z, -1.0, 1.0)
    phi = (float(col) + u4) * (2.0 * wp.pi / float(w))
    r = wp.sqrt(wp.max(0.0, 1.0 - z * z))
    d = env.to_world[0] * wp.vec3(r * wp.cos(phi), r * wp.sin(phi), z)
    return wp.vec4(d[0], d[1], d[2], env.texel_pdf[row, col])


@wp.kernel
def _lookup_kernel(env: EnvironmentMap, dirs: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = env_radiance(env, dirs[i])


@wp.kernel
def _sample_kernel(
    env: EnvironmentMap,
    seed: int,
    dirs: wp.array(dtype=wp.vec3),
    pdfs: wp.array(dtype=float),
    pdf_lookup: wp.array(dtype=float),
):
    i = wp.tid()
    state = wp.rand_init(seed, i)
    s = env_sample(env, wp.randf(state), wp.randf(state), wp.randf(state), wp.randf(state))
    d = wp.vec3(s[0], s[1], s[2])
    dirs[i] = d
    pdfs[i] = s[3]
    pdf_lookup[i] = env_pdf(env, d)


def lookup_environment(env_map: EnvironmentMap, directions, device=None) -> np.ndarray:
    """Host helper: :func:`env_radiance` at world directions (N, 3) -> (N, 3) float32."""
    dev = resolve_device(device)
    d = wp.array(np.asarray(directions, np.float32).reshape(-1, 3), dtype=wp.vec3, device=dev)
    out = wp.empty(d.shape[0], dtype=wp.vec3, device=dev)
    wp.launch(_lookup_kernel, dim=d.shape[0], inputs=[env_map, d, out], device=dev)
    return out.numpy()


def sample_environment(env_map: EnvironmentMap, count: int, seed: int = 0, device=None):
    """Host helper: ``count`` draws of :func:`env_sample`.

    Returns:
        ``(directions (count, 3), pdf (count,), pdf_from_env_pdf (count,))``, float32; the last
        is :func:`env_pdf` re-evaluated at the drawn direction (equal to the second up to
        directions landing exactly on a texel edge).
    """
    dev = resolve_device(device)
    if env_map.enabled == 0:
        raise ValueError("sample_environment: the environment is disabled (no map to sample)")
    dirs = wp.empty(count, dtype=wp.vec3, device=dev)
    pdf = wp.empty(count, dtype=float, device=dev)
    pdf2 = wp.empty(count, dtype=float, device=dev)
    wp.launch(_sample_kernel, dim=count, inputs=[env_map, int(seed), dirs, pdf, pdf2], device=dev)
    return dirs.numpy(), pdf.numpy(), pdf2.numpy()



# ---- the frame's lighting on the device -------------------------------------------------------
@functools.lru_cache(maxsize=None)
def _lighting_sh_kernel(order: int):
    """Kernel: the frame's world SH (3, n*n) = sum_k rotate(base_k, R[t, k]), or the override."""
    bundle = sh_kernels(order)
    vec_t = bundle.vec
    C = bundle.coeff_count
    sh_load = bundle.load
    sh_rotate = bundle.rotate

    @wp.kernel(enable_backward=False, module="unique")
    def kernel(
        frame: wp.array(dtype=wp.int32),
        rotations: wp.array(dtype=wp.mat33),
        rotation_frames: int,
        light_count: int,
        base: wp.array2d(dtype=wp.float32),
        override: wp.array2d(dtype=wp.float32),
        tables: SHTables,
        out: wp.array2d(dtype=wp.float32),
        changed: wp.array(dtype=wp.int32),
    ):
        t = wp.min(frame[0], rotation_frames - 1)
        flag = int(0)
        for c in range(3):
            acc = vec_t()
            if frame[1] != 0:
                acc = sh_load(override, c)
            else:
                for k in range(light_count):
                    acc = acc + sh_rotate(sh_load(base, k * 3 + c), rotations[t * light_count + k], tables)
            for i in range(C):
                if out[c, i] != acc[i]:
                    flag = 1
                out[c, i] = acc[i]
        changed[0] = flag

    return kernel


@wp.kernel
def _sh_prefix_kernel(src: wp.array2d(dtype=wp.float32), dst: wp.array2d(dtype=wp.float32)):
    c, i = wp.tid()
    dst[c, i] = src[c, i]


@wp.kernel
def _lights_kernel(
    frame: wp.array(dtype=wp.int32),
    rotations: wp.array(dtype=wp.mat33),
    rotation_frames: int,
    light_count: int,
    distant_slot: wp.array(dtype=wp.int32),
    distant_direction0: wp.array(dtype=wp.vec3),
    distant_direction: wp.array(dtype=wp.vec3),
    environment_slot: wp.array(dtype=wp.int32),
    environment_to_world0: wp.array(dtype=wp.mat33),
    environment_to_world: wp.array(dtype=wp.mat33),
    sphere_table: wp.array(dtype=wp.vec3),
    sphere_frames: int,
    sphere_position: wp.array(dtype=wp.vec3),
):
    t = wp.min(frame[0], rotation_frames - 1)
    for i in range(distant_direction0.shape[0]):
        distant_direction[i] = wp.normalize(rotations[t * light_count + distant_slot[i]] * distant_direction0[i])
    for e in range(environment_to_world0.shape[0]):
        environment_to_world[e] = rotations[t * light_count + environment_slot[e]] * environment_to_world0[e]
    s_count = sphere_position.shape[0]
    ts = wp.min(frame[0], sphere_frames - 1)
    for s in range(s_count):
        sphere_position[s] = sphere_table[ts * s_count + s]


def _vec3_array(rows, device):
    return wp.array(np.asarray(rows, np.float32).reshape(-1, 3), dtype=wp.vec3, device=device)


def _float_array(values, device):
    return wp.array(np.asarray(values, np.float32).reshape(-1), dtype=wp.float32, device=device)


class FrameLighting:
    """The lights of the current frame on one device (``FrameState.lighting``).

    Built once from a :class:`~warpshade.scene._lighting.LightingSource` and the scene's time
    codes; :meth:`launch` (kernels only, capture-safe) fills every array below for the frame
    whose index is ``frame_input.array[0]``. Arrays keep their addresses for the object's life,
    so stages bind them once.

    Args:
        source: the lighting description (host, float64).
        frames: the scene's time codes, (T,).
        frame_input: the evaluator's :class:`~warpshade._wp.HostFields` (read only):
            ``frame_index`` and ``sh_override`` (then the coefficients of :meth:`set_override`).
        device: the Warp device.

    Attributes:
        changed: (1,) int32: 1 when the SH lighting differs from the previous launch's (kernels
            that tabulate the lighting skip their rebuild when 0).
        sphere_position: (S,) vec3, world; sphere_radius: (S,) float32; sphere_radiance: (S,)
            vec3, the sphere lights in the order of ``source.sphere_lights()``.
        distant_direction: (D,) vec3, unit, towards each DistantLight; distant_irradiance (D,)
            vec3; distant_cos_half (D,) float32 (1 for a delta light).
        environment_to_world: (E,) mat33, the map-to-world rotation of each Environment.
    """

    def __init__(self, source, frames, frame_input: HostFields, device=None):
        from ._lighting import DistantLight, Environment

        dev = resolve_device(device)
        self.device = dev
        self.source = source
        self.frames = np.asarray(frames, np.float64).reshape(-1)
        self._input = frame_input
        distant = source.distant_lights
        self.light_count = len(distant)
        table = source.rotation_table(self.frames)
        self.rotation_frames = int(table.shape[0])
        self._rotations = wp.array(table.reshape(-1, 3, 3).astype(np.float32), dtype=wp.mat33, device=dev)
        if self.light_count == 0:
            self._rotations = wp.array(np.eye(3, dtype=np.float32)[None], dtype=wp.mat33, device=dev)
        lights = [(k, light) for k, light in enumerate(distant) if isinstance(light, DistantLight)]
        envs = [(k, light) for k, light in enumerate(distant) if isinstance(light, Environment)]
        self.distant_lights = [light for _, light in lights]
        self.environments = [light for _, light in envs]
        self._distant_slot = wp.array(np.array([k for k, _ in lights], np.int32), dtype=wp.int32, device=dev)
        self._distant_direction0 = _vec3_array([light.direction for _, light in lights], dev)
        self.distant_direction = wp.zeros(len(lights), dtype=wp.vec3, device=dev)
        self.distant_irradiance = _vec3_array([light.irradiance for _, light in lights], dev)
        self.distant_cos_half = _float_array(
            [np.cos(np.radians(light.angle_deg) / 2.0) if light.angle_deg > 0 else 1.0 for _, light in lights], dev)
        self._environment_slot = wp.array(np.array([k for k, _ in envs], np.int32), dtype=wp.int32, device=dev)
        self._environment_to_world0 = wp.array(
            np.array([light.to_world for _, light in envs], np.float32).reshape(-1, 3, 3), dtype=wp.mat33, device=dev)
        self.environment_to_world = wp.zeros(len(envs), dtype=wp.mat33, device=dev)
        spheres = source.sphere_lights()
        positions = source.sphere_position_table(self.frames)
        self.sphere_frames = int(positions.shape[0])
        self._sphere_table = _vec3_array(positions.reshape(-1, 3), dev)
        self.sphere_position = wp.zeros(len(spheres), dtype=wp.vec3, device=dev)
        self.sphere_radius = _float_array([s.radius for s in spheres], dev)
        self.sphere_radiance = _vec3_array([s.radiance for s in spheres], dev)
        self.changed = wp.zeros(1, dtype=wp.int32, device=dev)
        self._orders: dict[int, wp.array] = {}
        self._max_order = 0
        self._env_maps: dict[int, EnvironmentMap] = {}

    # ---- what stages ask for ------------------------------------------------------------
    @property
    def sphere_light_count(self) -> int:
        return int(self.sphere_position.shape[0])

    @property
    def orders(self) -> tuple:
        """The SH orders asked for so far (each filled by :meth:`launch`)."""
        return tuple(sorted(self._orders))

    def sh(self, order: int) -> wp.array:
        """The frame's distant lighting as SH, world frame, wp.array2d (3, order**2) float32.

        The same array every frame (bind it once); asking for an order makes :meth:`launch`
        fill it. Lower orders are prefixes of higher ones (SH rotation keeps bands apart).
        """
        order = int(order)
        if not 1 <= order <= MAX_KERNEL_ORDER:
            raise ValueError(f"lighting: SH order must be in 1..{MAX_KERNEL_ORDER}, got {order}")
        if order not in self._orders:
            self._orders[order] = wp.zeros((3, order * order), dtype=wp.float32, device=self.device)
            if order > self._max_order:
                self._build(order)
        return self._orders[order]

    def environment_map(self, index: int = 0) -> EnvironmentMap:
        """The ``index``-th Environment as an :class:`EnvironmentMap` that turns with the frame
        (its ``to_world`` is a view of :attr:`environment_to_world`)."""
        if not 0 <= index < len(self.environments):
            raise ValueError(f"lighting: no environment {index} (the lighting has {len(self.environments)})")
        if index not in self._env_maps:
            self._env_maps[index] = upload_environment(self.environments[index], self.device,
                                                       to_world=self.environment_to_world[index : index + 1])
        return self._env_maps[index]

    def _build(self, order: int) -> None:
        n2 = order * order
        base = self.source.base_sh(order).reshape(-1, n2) if self.light_count else np.zeros((1, n2))
        self._base = wp.array(base.astype(np.float32), dtype=wp.float32, device=self.device)
        self._override = HostInput((3, n2), wp.float32, self.device)
        self._full = wp.zeros((3, n2), dtype=wp.float32, device=self.device)
        self._tables = sh_kernels(order).tables(self.device)
        self._sh_kernel = _lighting_sh_kernel(order)
        self._max_order = order

    # ---- overrides (host writes, read by the next frame) --------------------------------
    def set_override(self, coeffs) -> None:
        """The world-frame SH coefficients (3, n*n), n >= every asked order, used instead of the
        lights' while the frame input ``sh_override`` is set (by the evaluator's
        ``set_lighting_override``). Only the SH lighting is overridden; stages that sample the
        lights themselves keep the source's lights."""
        c = np.asarray(coeffs, np.float64)
        need = self._max_order * self._max_order
        if c.ndim != 2 or c.shape[0] != 3 or c.shape[1] < need or int(round(np.sqrt(c.shape[1]))) ** 2 != c.shape[1]:
            raise ValueError(f"lighting override has shape {c.shape}; the graph needs (3, {need}) "
                             f"(order {self._max_order}) or a higher order")
        if not np.all(np.isfinite(c)):
            raise ValueError("lighting override contains NaN or infinite coefficients")
        if need:
            self._override.host[...] = c[:, :need]

    # ---- per frame ----------------------------------------------------------------------
    def launch(self) -> None:
        """Fill the frame's lighting arrays (kernels only; the frame index is already on the device)."""
        dev = self.device
        frame = self._input.array
        if self._max_order:
            self._override.launch()
            wp.launch(self._sh_kernel, dim=1, device=dev, inputs=[
                frame, self._rotations, self.rotation_frames, self.light_count, self._base, self._override.array,
                self._tables, self._full, self.changed])
            for order, out in self._orders.items():
                if order == self._max_order:
                    wp.copy(out, self._full)
                else:
                    wp.launch(_sh_prefix_kernel, dim=(3, order * order), inputs=[self._full, out], device=dev)
        if self.distant_direction.shape[0] or self.environment_to_world.shape[0] or self.sphere_position.shape[0]:
            wp.launch(_lights_kernel, dim=1, device=dev, inputs=[
                frame, self._rotations, self.rotation_frames, max(self.light_count, 1), self._distant_slot,
                self._distant_direction0, self.distant_direction, self._environment_slot, self._environment_to_world0,
                self.environment_to_world, self._sphere_table, max(self.sphere_frames, 1), self.sphere_position])
