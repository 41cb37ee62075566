"""Ray-cast preview images: a pinhole camera over the frame's BVH, per-vertex or per-pixel shading.

Pipeline (every per-pixel loop is a Warp kernel):

1. :func:`render_gbuffer` casts one primary ray per pixel (``wp.mesh_query_ray``, closest hit)
   and stores per pixel: hit flag, hit position, shading normal (barycentric interpolation of
   the vertex normals, normalised and flipped toward the camera, i.e. two-sided), triangle,
   barycentric coordinates and the ray direction (:class:`GBuffer`, flat arrays of
   ``height * width`` entries in row-major order, row 0 at the top).
2. Shading: :func:`interpolate_vertex_values` (a (vertex_count, 3) array interpolated with the
   hit's barycentric coordinates) or any callable ``shade(gbuffer) -> (pixel_count, 3)``.
3. Misses show the environment (bilinear lookup in the ray direction) or a neutral grey.
4. :mod:`warpshade.render._image` tone-maps and writes the PNG atomically.

Supersampling renders at ``supersample`` times the resolution and box-filters down.
Warp barycentrics: a hit ``(face, u, v)`` is ``u * p0 + v * p1 + (1 - u - v) * p2``.
"""

import math

import numpy as np

from .._wp import resolve_device, wp
from ..geometry._bvh import RAY_MAX_DISTANCE, Visibility
from ..scene._lighting_warp import EnvironmentMap, env_radiance, upload_environment
from ._camera import camera_basis, camera_for
from ._image import tonemap, write_png

__all__: list[str] = []

wp.set_module_options({"enable_backward": False})

_RAY_MAX = wp.constant(RAY_MAX_DISTANCE)


@wp.kernel
def _primary_kernel(
    mesh_id: wp.uint64,
    faces: wp.array2d(dtype=wp.int32),
    normals: wp.array(dtype=wp.vec3),
    eye: wp.vec3,
    forward: wp.vec3,
    right: wp.vec3,
    up: wp.vec3,
    tan_half_v: float,
    width: int,
    height: int,
    hit: wp.array(dtype=wp.int32),
    position: wp.array(dtype=wp.vec3),
    normal: wp.array(dtype=wp.vec3),
    face: wp.array(dtype=wp.int32),
    bary: wp.array(dtype=wp.vec2),
    direction: wp.array(dtype=wp.vec3),
):
    row, col = wp.tid()
    i = row * width + col
    aspect = float(width) / float(height)
    x = (2.0 * (float(col) + 0.5) / float(width) - 1.0) * tan_half_v * aspect
    y = (1.0 - 2.0 * (float(row) + 0.5) / float(height)) * tan_half_v
    d = wp.normalize(forward + x * right + y * up)
    direction[i] = d
    q = wp.mesh_query_ray(mesh_id, eye, d, _RAY_MAX)
    if q.result:
        hit[i] = 1
        position[i] = eye + q.t * d
        face[i] = q.face
        bary[i] = wp.vec2(q.u, q.v)
        f = q.face
        n = q.u * normals[faces[f, 0]] + q.v * normals[faces[f, 1]] + (1.0 - q.u - q.v) * normals[faces[f, 2]]
        length = wp.length(n)
        if length > 1.0e-20:
            n = n / length
        else:
            n = q.normal
        if wp.dot(n, d) > 0.0:
            n = -n
        normal[i] = n
    else:
        hit[i] = 0
        position[i] = wp.vec3(0.0)
        face[i] = -1
        bary[i] = wp.vec2(0.0)
        normal[i] = wp.vec3(0.0)


@wp.kernel
def _interpolate_kernel(
    hit: wp.array(dtype=wp.int32),
    face: wp.array(dtype=wp.int32),
    bary: wp.array(dtype=wp.vec2),
    faces: wp.array2d(dtype=wp.int32),
    values: wp.array(dtype=wp.vec3),
    out: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    if hit[i] == 0:
        out[i] = wp.vec3(0.0)
        return
    f = face[i]
    b = bary[i]
    out[i] = b[0] * values[faces[f, 0]] + b[1] * values[faces[f, 1]] + (1.0 - b[0] - b[1]) * values[faces[f, 2]]


@wp.kernel
def _background_kernel(
    hit: wp.array(dtype=wp.int32),
    direction: wp.array(dtype=wp.vec3),
    env: EnvironmentMap,
    use_env: int,
    colour: wp.array(dtype=wp.vec3),
    background: wp.array(dtype=wp.int32),
):
    i = wp.tid()
    background[i] = 0
    if hit[i] == 0:
        if use_env != 0:
            colour[i] = env_radiance(env, direction[i])
        else:
            background[i] = 1  # filled with the display grey after tone mapping


@wp.kernel
def _downsample_kernel(
    src: wp.array(dtype=wp.vec3),
    src_flag: wp.array(dtype=wp.int32),
    factor: int,
    width: int,
    dst: wp.array(dtype=wp.vec3),
    dst_flag: wp.array(dtype=wp.float32),
):
    row, col = wp.tid()
    acc = wp.vec3(0.0)
    flag = float(0.0)
    src_width = width * factor
    for a in range(factor):
        for b in range(factor):
            k = (row * factor + a) * src_width + col * factor + b
            acc += src[k]
            flag += float(src_flag[k])
    scale = 1.0 / float(factor * factor)
    dst[row * width + col] = acc * scale
    dst_flag[row * width + col] = flag * scale


class GBuffer:
    """Per-pixel primary-hit data (flat, row-major, ``height * width`` entries, device arrays).

    Attributes:
        width, height: resolution.
        hit: 1 where the ray hit a triangle, wp.array(int32).
        position: world hit position, wp.array(vec3) (0 for misses).
        normal: unit shading normal facing the camera, wp.array(vec3).
        face: hit triangle (index into the BVH's faces), wp.array(int32), -1 for misses.
        bary: Warp barycentrics (u, v) of the hit, wp.array(vec2).
        direction: unit ray direction, wp.array(vec3), world space.
        bvh: the :class:`~warpshade.geometry._bvh.Visibility` that was ray-cast.
        faces: the BVH's triangles on the device, wp.array2d(int32), shape (triangle_count, 3).
    """

    def __init__(self, width, height, device, bvh):
        self.width = width
        self.height = height
        self.device = device
        self.bvh = bvh
        self.faces = wp.array(bvh.faces, dtype=wp.int32, device=device)
        count = width * height
        self.hit = wp.zeros(count, dtype=wp.int32, device=device)
        self.position = wp.zeros(count, dtype=wp.vec3, device=device)
        self.normal = wp.zeros(count, dtype=wp.vec3, device=device)
        self.face = wp.zeros(count, dtype=wp.int32, device=device)
        self.bary = wp.zeros(count, dtype=wp.vec2, device=device)
        self.direction = wp.zeros(count, dtype=wp.vec3, device=device)

    @property
    def pixel_count(self) -> int:
        return self.width * self.height


def render_gbuffer(bvh: Visibility, normals, camera, width: int, height: int) -> GBuffer:
    """Cast one primary ray per pixel through ``camera`` against ``bvh``.

    Args:
        bvh: the frame's :class:`~warpshade.geometry._bvh.Visibility` (already refit).
        normals: unit vertex normals, wp.array(vec3) on the BVH's device, (vertex_count,).
        camera: :class:`~warpshade.scene.Camera`.
        width, height: resolution in pixels.
    """
    if width < 1 or height < 1:
        raise ValueError(f"render: image size must be positive, got {width}x{height}")
    dev = bvh.device
    forward, right, up = camera_basis(camera)
    gb = GBuffer(width, height, dev, bvh)
    wp.launch(
        _primary_kernel,
        dim=(height, width),
        inputs=[
            bvh.id, gb.faces, normals, wp.vec3(*np.asarray(camera.position, np.float32)), wp.vec3(*forward.astype(np.float32)),
            wp.vec3(*right.astype(np.float32)), wp.vec3(*up.astype(np.float32)),
            float(math.tan(math.radians(camera.vertical_fov) / 2.0)), width, height,
            gb.hit, gb.position, gb.normal, gb.face, gb.bary, gb.direction,
        ],
        device=dev,
    )
    return gb


def interpolate_vertex_values(gbuffer: GBuffer, values):
    """Barycentric interpolation of per-vertex RGB values at each pixel's hit.

    Args:
        gbuffer: from :func:`render_gbuffer`.
        values: per-vertex values, shape (vertex_count, 3) (NumPy or wp.array(vec3)).

    Returns:
        wp.array(vec3), shape (pixel_count,), zero for misses.
    """
    dev = gbuffer.device
    if isinstance(values, wp.array):
        vals = values
    else:
        arr = np.asarray(values, np.float32)
        if arr.ndim != 2 or arr.shape[1] != 3:
            raise ValueError(f"render: vertex colours must have shape (vertex_count, 3), got {arr.shape}")
        vals = wp.array(arr, dtype=wp.vec3, device=dev)
    if vals.shape[0] != gbuffer.bvh.vertex_count:
        raise ValueError(f"render: {vals.shape[0]} vertex colours for {gbuffer.bvh.vertex_count} vertices")
    out = wp.empty(gbuffer.pixel_count, dtype=wp.vec3, device=dev)
    wp.launch(_interpolate_kernel, dim=gbuffer.pixel_count, inputs=[gbuffer.hit, gbuffer.face, gbuffer.bary, gbuffer.faces, vals, out], device=dev)
    return out


class RenderResult:
    """A rendered image.

    Attributes:
        image: tone-mapped sRGB image, shape (height, width, 3), uint8.
        linear: linear radiance before tone mapping, shape (height, width, 3), float32 (the grey
            background is 0 here).
        coverage: fraction of each pixel covered by geometry, shape (height, width), float32.
        camera: the camera used; path: the PNG written, or None.
    """

    def __init__(self, image, linear, coverage, camera, path):
        self.image = image
        self.linear = linear
        self.coverage = coverage
        self.camera = camera
        self.path = path


def render(
    scene,
    frame=None,
    colors=None,
    shade=None,
    camera=None,
    width: int = 320,
    height: int = 240,
    environment=None,
    exposure: float = 0.0,
    tonemap_mode: str = "srgb",
    supersample: int = 1,
    path=None,
    device=None,
    bvh: Visibility | None = None,
    state=None,
) -> RenderResult:
    """Render a frame with per-vertex colours or a per-pixel shading callback.

    Args:
        scene: the :class:`~warpshade.scene.Scene`.
        frame: time code (default: the first frame).
        colors: per-vertex linear RGB, shape (vertex_count, 3) -- or
        shade: callable ``shade(gbuffer) -> (pixel_count, 3)`` linear RGB (wp.array(vec3) or
            NumPy), evaluated at the supersampled resolution. Exactly one of the two.
        camera: a :class:`~warpshade.scene.Camera`; default ``scene.camera`` or a 3/4 framing.
        width, height: output resolution in pixels.
        environment: an :class:`~warpshade.scene.Environment` shown where rays miss (default:
            neutral grey).
        exposure: exposure in stops (linear values are multiplied by ``2**exposure``).
        tonemap_mode: "srgb" (clamp + sRGB) or "reinhard" (``c / (1 + c)`` + sRGB).
        supersample: rays per pixel along each axis (box filter).
        path: write the PNG here (atomically) when given.
        device: Warp device (None = Warp's default).
        bvh, state: reuse an existing BVH / FrameState of this frame (per-frame loops).
    """
    if (colors is None) == (shade is None):
        raise ValueError("render: pass exactly one of colors= (per-vertex) or shade= (per-pixel callback)")
    if supersample < 1:
        raise ValueError(f"render: supersample must be >= 1, got {supersample}")
    dev = resolve_device(device)
    frame = scene.frames[0] if frame is None else frame
    if state is None:
        state = scene.evaluate(frame, device=dev)
    if bvh is None:
        bvh = Visibility.from_scene(scene, device=dev)
    bvh.update(state.points)
    camera = camera if camera is not None else camera_for(scene, frame, aspect=width / height)
    ss = int(supersample)
    gb = render_gbuffer(bvh, state.normals, camera, width * ss, height * ss)
    if colors is not None:
        colour = interpolate_vertex_values(gb, colors)
    else:
        out = shade(gb)
        if isinstance(out, wp.array):
            colour = out
        else:
            arr = np.asarray(out, np.float32).reshape(-1, 3)
            if arr.shape[0] != gb.pixel_count:
                raise ValueError(f"render: shade callback returned {arr.shape[0]} pixels, expected {gb.pixel_count}")
            colour = wp.array(arr, dtype=wp.vec3, device=dev)
    background = wp.empty(gb.pixel_count, dtype=wp.int32, device=dev)
    env_map = upload_environment(environment, dev) if environment is not None else None
    if env_map is None:
        from ..scene._lighting_warp import disabled_environment

        env_map = disabled_environment(dev)
    wp.launch(
        _background_kernel,
        dim=gb.pixel_count,
        inputs=[gb.hit, gb.direction, env_map, 1 if environment is not None else 0, colour, background],
        device=dev,
    )
    linear = wp.empty(width * height, dtype=wp.vec3, device=dev)
    grey = wp.empty(width * height, dtype=wp.float32, device=dev)
    coverage = wp.empty(width * height, dtype=wp.float32, device=dev)
    wp.launch(_downsample_kernel, dim=(height, width), inputs=[colour, background, ss, width, linear, grey], device=dev)
    wp.launch(_downsample_kernel, dim=(height, width), inputs=[colour, gb.hit, ss, width, wp.empty(width * height, dtype=wp.vec3, device=dev), coverage], device=dev)
    image = tonemap(linear, grey, width, height, exposure=exposure, mode=tonemap_mode)
    if path is not None:
        write_png(path, image)
    return RenderResult(
        image=image,
        linear=linear.numpy().reshape(height, width, 3),
        coverage=coverage.numpy().reshape(height, width),
        camera=camera,
        path=None if path is None else str(path),
    )

