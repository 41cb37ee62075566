"""Lat-long environment maps as the SG lighting fits and tables read them (float64 NumPy).

The environment is the bilinear interpolation of its texels (``Environment.radiance``, rows
clamped at the poles, azimuth wrapped), integrated with each texel's exact solid angle
(:func:`warpshade.basis.quadrature.latlong`). Used by the diffuse fit (:mod:`._envfit`) and the
prefiltered table (:mod:`._prefilter`).
"""

from __future__ import annotations

import math

import numpy as np

from ...basis import quadrature
from ...scene._lighting import Environment

__all__ = [
    "bilinear_map",
    "cell_means",
    "check_environment",
    "environment_integral",
    "mip_chain",
    "row_weights",
    "source_chain",
    "subdivided",
]


def check_environment(env, where: str) -> np.ndarray:
    """The environment image as float64 (H, W, 3), checked: an Environment, finite, non-negative
    (ValueError naming ``where`` otherwise)."""
    if not isinstance(env, Environment):
        raise ValueError(f"{where}: env must be a warpshade.scene._lighting.Environment, got {type(env).__name__}")
    img = np.asarray(env.image, np.float64)
    name = env.path or "<array>"
    if not np.all(np.isfinite(img)):
        raise ValueError(f"{where}: environment {name} has NaN or infinite texels")
    if np.any(img < 0.0):
        count = int(np.count_nonzero(np.any(img < 0.0, axis=-1)))
        raise ValueError(f"{where}: environment {name} has {count} texels with negative radiance (min {img.min():.3g})")
    return img


def row_weights(height: int, width: int) -> np.ndarray:
    """Exact solid angle of one texel in each row, (H,) (as :func:`quadrature.latlong`)."""
    return quadrature.latlong(height, width).weights.reshape(height, width)[:, 0]


def mip_chain(image: np.ndarray) -> list[np.ndarray]:
    """The map and its 2x2 solid-angle weighted means while both sides are even (float64).

    A coarse texel's solid angle is the sum of its four children's, so each level's quadrature
    ``sum L w`` equals the full map's exactly."""
    chain = [np.asarray(image, np.float64)]
    while chain[-1].shape[0] % 2 == 0 and chain[-1].shape[1] % 2 == 0 and chain[-1].shape[0] >= 2:
        img = chain[-1]
        h, w = img.shape[:2]
        rw = row_weights(h, w)
        pair = img[:, 0::2] + img[:, 1::2]  # (h, w/2, 3)
        top, bottom = pair[0::2], pair[1::2]
        wt, wb = rw[0::2, None, None], rw[1::2, None, None]
        chain.append((wt * top + wb * bottom) / (2.0 * (wt + wb)))
    return chain


def cell_means(image: np.ndarray) -> np.ndarray:
    """Mean of the bilinear radiance over each texel: ``[1, 6, 1] / 8`` along rows and columns
    (the mean of a piecewise-linear interpolant over a cell centred on a node), rows clamped at
    the poles and azimuth wrapped as ``Environment.radiance`` does. Float64 (H, W, 3)."""
    img = np.asarray(image, np.float64)
    up = np.concatenate([img[:1], img[:-1]])
    down = np.concatenate([img[1:], img[-1:]])
    img = (up + 6.0 * img + down) / 8.0
    return (np.roll(img, 1, axis=1) + 6.0 * img + np.roll(img, -1, axis=1)) / 8.0


def source_chain(image: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Sources of the prefilter sums: ``(radiance (H, W, 3), direction (H, W, 3))`` per mip.

    The finest is the texel means of the bilinear radiance at the texel centres; each coarser
    one holds the solid-angle weighted 2x2 means and, as its direction, the luminance-weighted
    centroid of its children's directions, so a bright source smaller than a coarse texel (a
    sun) keeps its position instead of moving to the texel centre."""
    rec709 = np.array([0.2126, 0.7152, 0.0722])
    means = cell_means(image)
    h, w = means.shape[:2]
    out = [(means, quadrature.latlong_directions(h, w))]
    for img in mip_chain(means)[1:]:
        fine, fine_dirs = out[-1]
        fh, fw = fine.shape[:2]
        rw = row_weights(fh, fw)[:, None]
        mass = (np.maximum(fine @ rec709, 0.0) + 1e-9 * max(float(fine.max()), 1e-300)) * rw
        moment = mass[..., None] * fine_dirs
        summed = moment[0::2, 0::2] + moment[0::2, 1::2] + moment[1::2, 0::2] + moment[1::2, 1::2]
        dirs = summed / np.maximum(np.linalg.norm(summed, axis=-1, keepdims=True), 1e-300)
        out.append((img, dirs))
    return out


def environment_integral(env) -> np.ndarray:
    """``sum_texels L w`` (exact texel solid angles), RGB (3,): the integral of the map over the
    sphere, which ``Gamma(p, 0)`` equals."""
    img = check_environment(env, "environment_integral")
    rw = row_weights(env.height, env.width)
    return np.einsum("hwc,h->c", img, rw)


def subdivided(image: np.ndarray, sub: int) -> tuple[np.ndarray, np.ndarray]:
    """The bilinear radiance at the centres of a ``sub``-times finer lat-long grid (each texel
    split into ``sub x sub`` cells equal in theta and phi), with those centres' directions."""
    h, w = image.shape[:2]
    dirs = quadrature.latlong_directions(h * sub, w * sub)
    values = bilinear_map(image, dirs.reshape(-1, 3)).reshape(h * sub, w * sub, 3)
    return values, dirs



def bilinear_map(image: np.ndarray, d_map: np.ndarray) -> np.ndarray:
    """Bilinear lookup of a lat-long map at unit map-frame directions (N, 3): the arithmetic of
    ``Environment.radiance`` / ``env_radiance`` (rows clamped at the poles, azimuth wrapped)."""
    h, w = image.shape[:2]
    theta = np.arccos(np.clip(d_map[:, 2], -1.0, 1.0))
    phi = np.mod(np.arctan2(d_map[:, 1], d_map[:, 0]), 2.0 * math.pi)
    v = theta / math.pi * h - 0.5
    u = phi / (2.0 * math.pi) * w - 0.5
    v0, u0 = np.floor(v), np.floor(u)
    fv, fu = (v - v0)[:, None], (u - u0)[:, None]
    r0 = np.clip(v0, 0, h - 1).astype(np.int64)
    r1 = np.clip(v0 + 1, 0, h - 1).astype(np.int64)
    c0 = np.mod(u0, w).astype(np.int64)
    c1 = np.mod(c0 + 1, w)
    img = np.asarray(image, np.float64)
    return (1 - fv) * ((1 - fu) * img[r0, c0] + fu * img[r0, c1]) + fv * ((1 - fu) * img[r1, c0] + fu * img[r1, c1])
