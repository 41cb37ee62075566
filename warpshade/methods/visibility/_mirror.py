"""Float64 mirrors of the per-frame kernels of :mod:`._kernels` (the tests' oracle, never ground truth).

* :func:`inputs_f64` -- standardised, clamped input-PCA coordinates ``x`` of pose vectors (and the
  relative inputs of the posed points, :mod:`._relative`);
* :func:`predict_f64` -- the per-vertex local visibility (V, C) of one input vector;
* :func:`diffuse_f64` -- eq. 14 and the lighting: ``albedo / pi * L . R(F^T) (v * cos)``.
"""

from __future__ import annotations

import numpy as np

from ...basis import sh

__all__ = ["inputs_f64"]


def inputs_f64(arrays: dict, features: np.ndarray, points=None) -> np.ndarray:
    """``clip((a - mean) @ W, x_low, x_high)`` for pose vectors (n, a) -> (n, k_in); a model with
    relative inputs needs the posed points of the same poses (n, V, 3) to append them."""
    a = np.atleast_2d(np.asarray(features, np.float64))
    width = np.asarray(arrays["pose_mean"]).size
    if a.shape[1] != width:
        if points is None:
            raise ValueError(f"inputs_f64: the model reads {width} inputs per pose and the pose vectors have "
                             f"{a.shape[1]}: pass the posed points for its relative inputs")
        from ._relative import relative_features_f64

        g = relative_features_f64(points, arrays["rest_points"], arrays["labels"], arrays["relative_neighbours"])
        a = np.concatenate([a, g], axis=1)
    x = (a - np.asarray(arrays["pose_mean"], np.float64)) @ np.asarray(arrays["input_weights"], np.float64)
    return np.clip(x, arrays["x_low"], arrays["x_high"])


def activations_f64(arrays: dict, x: np.ndarray) -> np.ndarray:
    """``[phi, tanh(W1 x + b1)]`` for one input vector (k_in,)."""
    x = np.asarray(x, np.float64).reshape(-1)
    qi, qj = np.asarray(arrays["quad_i"]), np.asarray(arrays["quad_j"])
    phi = np.concatenate([x, x[qi] * x[qj]])
    hid = np.tanh(np.asarray(arrays["w1"], np.float64) @ x + np.asarray(arrays["b1"], np.float64))
    return np.concatenate([phi, hid])


def outputs_f64(arrays: dict, x: np.ndarray) -> np.ndarray:
    """Every cluster's PCA weights, concatenated, for one input vector."""
    act = activations_f64(arrays, x)
    w2 = np.asarray(arrays["w2"], np.float64)
    out = np.asarray(arrays["b2"], np.float64).copy()
    for o, (src, n, off) in enumerate(zip(arrays["source"], arrays["length"], arrays["w_offset"])):
        out[o] += w2[off:off + n] @ act[src:src + n]
    return out


def predict_f64(arrays: dict, x: np.ndarray) -> np.ndarray:
    """Local SH visibility of every vertex for one input vector ``x`` (k_in,), (V, C) float64."""
    y = outputs_f64(arrays, x)
    labels = np.asarray(arrays["labels"])
    comps = np.asarray(arrays["components"])
    offs = np.asarray(arrays["y_offset"])
    kmax = np.asarray(arrays["basis"]).shape[2]
    ypad = np.zeros((comps.size, kmax))
    for c in range(comps.size):
        ypad[c, :comps[c]] = y[offs[c]:offs[c] + comps[c]]
    return np.asarray(arrays["mean"], np.float64) + np.einsum("vck,vk->vc", np.asarray(arrays["basis"], np.float64),
                                                              ypad[labels])


def diffuse_f64(visibility: np.ndarray, frames: np.ndarray, light: np.ndarray, albedo: np.ndarray) -> np.ndarray:
    """Diffuse radiance of local visibility (V, C), frames (V, 3, 3), world SH lighting (3, C), albedo (V, 3)."""
    v = np.asarray(visibility, np.float64)
    order = int(round(np.sqrt(v.shape[1])))
    cos = sh.clamped_cosine_sh(order)
    t = sh.product(v, np.broadcast_to(cos, v.shape))
    tw = sh.rotate(t, np.swapaxes(np.asarray(frames, np.float64), -1, -2))
    return np.asarray(albedo, np.float64) / np.pi * np.maximum(tw @ np.asarray(light, np.float64).T, 0.0)
