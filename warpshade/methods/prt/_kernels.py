"""Warp kernels of static PRT and unshadowed irradiance (float64 mirrors: :mod:`._mirror`)."""

import functools

from ..._wp import wp

from ...basis.sh_warp import sh_kernels

wp.set_module_options({"enable_backward": False})

INV_PI = 0.3183098861837907


@wp.kernel
def shade_transfer_kernel(
    transfer: wp.array2d(dtype=wp.float32),
    light: wp.array2d(dtype=wp.float32),
    albedo: wp.array2d(dtype=wp.float32),
    radiance: wp.array2d(dtype=wp.float32),
):
    """radiance[v, c] = albedo[v, c] / pi * max(0, dot(transfer[v, :], light[c, :]))."""
    v = wp.tid()
    r = float(0.0)
    g = float(0.0)
    b = float(0.0)
    for i in range(transfer.shape[1]):
        t = transfer[v, i]
        r += t * light[0, i]
        g += t * light[1, i]
        b += t * light[2, i]
    # SH truncation rings below zero in deep shadow; negative light is clamped away.
    radiance[v, 0] = albedo[v, 0] * INV_PI * wp.max(r, 0.0)
    radiance[v, 1] = albedo[v, 1] * INV_PI * wp.max(g, 0.0)
    radiance[v, 2] = albedo[v, 2] * INV_PI * wp.max(b, 0.0)


@wp.kernel
def shade_transfer_rgb_kernel(
    transfer: wp.array3d(dtype=wp.float32),
    light: wp.array2d(dtype=wp.float32),
    albedo: wp.array2d(dtype=wp.float32),
    radiance: wp.array2d(dtype=wp.float32),
):
    """radiance[v, c] = albedo[v, c] / pi * max(0, dot(transfer[v, c, :], light[c, :])): per-channel
    transfer (interreflected: the bounces depend on the albedo of what they hit)."""
    v = wp.tid()
    for c in range(3):
        acc = float(0.0)
        for i in range(transfer.shape[2]):
            acc += transfer[v, c, i] * light[c, i]
        radiance[v, c] = albedo[v, c] * INV_PI * wp.max(acc, 0.0)


@functools.lru_cache(maxsize=None)
def unshadowed_kernel(order: int):
    """Kernel shading by the normal-indexed irradiance of order-``order`` SH lighting.

    ``light_conv`` holds the lighting already convolved with the clamped cosine
    (``A_l * L_lm``), so radiance = albedo / pi * dot(light_conv[c], y(n)).
    """
    sh = sh_kernels(order)
    sh_eval = sh.eval
    N = sh.coeff_count

    @wp.kernel(enable_backward=False, module="unique")
    def kernel(
        normals: wp.array(dtype=wp.vec3),
        light_conv: wp.array2d(dtype=wp.float32),
        albedo: wp.array2d(dtype=wp.float32),
        radiance: wp.array2d(dtype=wp.float32),
    ):
        v = wp.tid()
        y = sh_eval(wp.normalize(normals[v]))
        r = float(0.0)
        g = float(0.0)
        b = float(0.0)
        for i in range(N):
            r += light_conv[0, i] * y[i]
            g += light_conv[1, i] * y[i]
            b += light_conv[2, i] * y[i]
        radiance[v, 0] = albedo[v, 0] * INV_PI * wp.max(r, 0.0)
        radiance[v, 1] = albedo[v, 1] * INV_PI * wp.max(g, 0.0)
        radiance[v, 2] = albedo[v, 2] * INV_PI * wp.max(b, 0.0)

    return kernel
