"""Tone mapping (Warp kernel with a float64 mirror) and atomic PNG output.

Tone mapping of a linear RGB value ``c`` with exposure ``e`` stops:

* ``"srgb"``: ``x = clamp(c * 2**e, 0, 1)``;
* ``"reinhard"``: ``x = k / (1 + k)`` per channel with ``k = max(c * 2**e, 0)``;

then the sRGB transfer function (``12.92 x`` below 0.0031308, else ``1.055 x**(1/2.4) - 0.055``)
and rounding to 8 bits. Pixels partly covered by the neutral grey background (fraction ``g``)
are composited in display space: ``(1 - g) * T(c / (1 - g)) + g * GREY_BACKGROUND``.
"""

from pathlib import Path

import numpy as np

from .._fileio import atomic_path
from .._wp import wp

__all__: list[str] = []

wp.set_module_options({"enable_backward": False})

#: Display value (sRGB-encoded, 0..1) of the neutral grey background.
GREY_BACKGROUND = 0.5

#: Tone-mapping curves, in the order of the kernel's ``mode`` argument.
TONEMAP_MODES = ("srgb", "reinhard")

_GREY = wp.constant(GREY_BACKGROUND)


@wp.func
def _encode(c: float, scale: float, mode: int) -> float:
    k = wp.max(c * scale, 0.0)
    x = wp.min(k, 1.0)
    if mode == 1:
        x = k / (1.0 + k)
    if x <= 0.0031308:
        return 12.92 * x
    return 1.055 * wp.pow(x, 1.0 / 2.4) - 0.055


@wp.kernel
def _tonemap_kernel(
    linear: wp.array(dtype=wp.vec3),
    grey: wp.array(dtype=wp.float32),
    width: int,
    scale: float,
    mode: int,
    out: wp.array3d(dtype=wp.uint8),
):
    row, col = wp.tid()
    i = row * width + col
    g = wp.clamp(grey[i], 0.0, 1.0)
    c = linear[i]
    cover = 1.0 - g
    for ch in range(3):
        v = g * _GREY
        if cover > 1.0e-6:
            v += cover * _encode(c[ch] / cover, scale, mode)
        out[row, col, ch] = wp.uint8(wp.clamp(int(v * 255.0 + 0.5), 0, 255))


def _mode_index(mode: str) -> int:
    if mode not in TONEMAP_MODES:
        raise ValueError(f"tonemap: mode must be one of {TONEMAP_MODES}, got {mode!r}")
    return TONEMAP_MODES.index(mode)


def tonemap(linear, grey, width: int, height: int, exposure: float = 0.0, mode: str = "srgb") -> np.ndarray:
    """Tone-map a linear image on its device.

    Args:
        linear: linear RGB, wp.array(vec3), shape (height * width,), row-major.
        grey: background coverage per pixel, wp.array(float32), same length (0 = none).
        width, height: resolution.
        exposure: stops; mode: "srgb" or "reinhard".

    Returns:
        uint8 image, shape (height, width, 3), sRGB.
    """
    dev = linear.device
    out = wp.empty((height, width, 3), dtype=wp.uint8, device=dev)
    wp.launch(
        _tonemap_kernel,
        dim=(height, width),
        inputs=[linear, grey, width, float(2.0**exposure), _mode_index(mode), out],
        device=dev,
    )
    return out.numpy()


def tonemap_f64(linear, grey=None, exposure: float = 0.0, mode: str = "srgb") -> np.ndarray:
    """Float64 mirror of :func:`tonemap`: (H, W, 3) linear -> (H, W, 3) uint8."""
    c = np.asarray(linear, np.float64)
    g = np.zeros(c.shape[:2]) if grey is None else np.clip(np.asarray(grey, np.float64).reshape(c.shape[:2]), 0, 1)
    cover = (1.0 - g)[..., None]
    with np.errstate(divide="ignore", invalid="ignore"):
        k = np.maximum(np.where(cover > 1e-6, c / cover, 0.0) * 2.0**exposure, 0.0)
    x = np.minimum(k, 1.0) if _mode_index(mode) == 0 else k / (1.0 + k)
    enc = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)
    v = g[..., None] * GREY_BACKGROUND + np.where(cover > 1e-6, cover * enc, 0.0)
    return np.clip(np.floor(v * 255.0 + 0.5), 0, 255).astype(np.uint8)


def write_png(path, image) -> Path:
    """Write an 8-bit RGB image to ``path`` atomically (temporary file + os.replace).

    Args:
        path: destination .png path; its directory must exist.
        image: uint8 array, shape (height, width, 3).
    """
    from PIL import Image

    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"write_png: expected a uint8 (height, width, 3) image, got {img.dtype} {img.shape}")
    path = Path(path)
    if not path.parent.is_dir():
        raise ValueError(f"write_png: directory {path.parent} does not exist")
    with atomic_path(path) as tmp:
        Image.fromarray(img, mode="RGB").save(tmp, format="PNG")
    return path
