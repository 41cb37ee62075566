"""Environment maps on the Warp device: bilinear lookup and luminance importance sampling.

:func:`upload_environment` turns a :class:`warpshade.scene.lighting.Environment` into an
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
  first order) through a marginal CDF over rows and a conditional CDF per row, and the
  direction is then uniform in solid angle inside the texel (``z`` uniform between the row's
  edge cosines, ``phi`` uniform in the column). Hence the pdf of a direction in texel
  ``(i, j)`` is ``(luminance(i, j) + floor) / sum(weights)`` per steradian.
* :func:`env_pdf` -- that pdf for any world direction.

The floor keeps the pdf positive where the bilinear filter spreads radiance half a texel into
black texels (so light sampling alone stays unbiased); a black map samples uniformly.
Luminance is Rec. 709: ``0.2126 R + 0.7152 G + 0.0722 B`` (negative values clamped to 0).
"""

import numpy as np

from .._wp import resolve_device, wp
from ..basis import quadrature

__all__ = [
    "LUMINANCE_FLOOR",
    "EnvironmentMap",
    "upload_environment",
    "disabled_environment",
    "env_radiance",
    "env_sample",
    "env_pdf",
    "env_texel_pdf_reference",
    "lookup_environment",
    "sample_environment",
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
        to_world: map-to-world rotation.
        height, width: image size.
        row_cdf: marginal CDF over rows, shape (H + 1,), from 0 to 1.
        col_cdf: conditional CDF over columns per row, shape (H, W + 1).
        texel_pdf: solid-angle pdf of each texel, shape (H, W), 1/sr.
        row_cos: ``cos(theta)`` at the row edges, shape (H + 1,), from 1 to -1.
        enabled: 1 for a real map, 0 for the placeholder of "no environment" (radiance 0).
    """

    image: wp.array2d(dtype=wp.vec3)
    to_world: wp.mat33
    height: int
    width: int
    row_cdf: wp.array(dtype=float)
    col_cdf: wp.array2d(dtype=float)
    texel_pdf: wp.array2d(dtype=float)
    row_cos: wp.array(dtype=float)
    enabled: int


def env_texel_pdf_reference(env) -> tuple[np.ndarray, np.ndarray]:
    """Float64 sampling distribution of an environment.

    Returns:
        ``(texel_probability, texel_pdf)``, both shape (H, W), float64: the probability of
        choosing each texel (sums to 1) and the solid-angle pdf inside it (1/sr).
    """
    h, w = env.height, env.width
    lum = np.maximum(env.image.astype(np.float64) @ _REC709, 0.0)
    solid = quadrature.latlong(h, w).weights.reshape(h, w)  # exact texel solid angles
    mean = float((lum * solid).sum() / (4.0 * np.pi))
    density = lum + LUMINANCE_FLOOR * mean if mean > 0.0 else np.ones_like(lum)
    weights = density * solid
    prob = weights / weights.sum()
    return prob, density / weights.sum()


def upload_environment(env, device=None) -> EnvironmentMap:
    """Upload an :class:`~warpshade.scene.lighting.Environment` and its sampling CDFs.

    Args:
        env: the environment (lat-long image, map frame, ``to_world``).
        device: Warp device (None = Warp's default).

    Returns:
        :class:`EnvironmentMap` whose arrays live on ``device``.
    """
    dev = resolve_device(device)
    h, w = env.height, env.width
    prob, pdf = env_texel_pdf_reference(env)
    row_p = prob.sum(axis=1)
    row_cdf = np.concatenate([[0.0], np.cumsum(row_p)])
    row_cdf /= row_cdf[-1]
    col_cdf = np.concatenate([np.zeros((h, 1)), np.cumsum(prob, axis=1)], axis=1)
    col_cdf /= np.where(col_cdf[:, -1:] > 0.0, col_cdf[:, -1:], 1.0)
    out = EnvironmentMap()
    out.image = wp.array(env.image.astype(np.float32), dtype=wp.vec3, device=dev)
    out.to_world = wp.mat33(*np.asarray(env.to_world, np.float32).reshape(-1))
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
    out.to_world = wp.mat33(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
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
    return wp.normalize(wp.transpose(env.to_world) * direction)


@wp.func
def env_radiance(env: EnvironmentMap, direction: wp.vec3) -> wp.vec3:
    """Bilinear radiance of the environment in a world direction (0 when disabled)."""
    if env.enabled == 0:
        return wp.vec3(0.0)
    d = _to_map(env, direction)
    theta = wp.acos(wp.clamp(d[2], -1.0, 1.0))
    phi = wp.atan2(d[1], d[0])
    if phi < 0.0:
        phi += 2.0 * wp.pi
    h = env.height
    w = env.width
    v = theta / wp.pi * float(h) - 0.5
    u = phi / (2.0 * wp.pi) * float(w) - 0.5
    v0 = wp.floor(v)
    u0 = wp.floor(u)
    fv = v - v0
    fu = u - u0
    r0 = wp.clamp(int(v0), 0, h - 1)
    r1 = wp.clamp(int(v0) + 1, 0, h - 1)
    c0 = ((int(u0) % w) + w) % w
    c1 = (c0 + 1) % w
    top = (1.0 - fu) * env.image[r0, c0] + fu * env.image[r0, c1]
    bottom = (1.0 - fu) * env.image[r1, c0] + fu * env.image[r1, c1]
    return (1.0 - fv) * top + fv * bottom


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
    d = env.to_world * wp.vec3(r * wp.cos(phi), r * wp.sin(phi), z)
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

