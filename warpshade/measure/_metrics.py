"""Error metrics of per-vertex radiance against ray-traced ground truth."""

from __future__ import annotations

import numpy as np

__all__: list[str] = []


def error_metrics(estimate, reference, reference_stderr=None) -> dict:
    """Relative error of per-vertex RGB radiance against a reference.

    With ``d_v`` the RGB root-mean-square difference at vertex ``v`` and ``R`` the RMS of the
    reference over all vertices and channels:

    * ``rel_rms`` = sqrt(mean_v d_v^2) / R;
    * ``rel_p99`` = 99th percentile of d_v / R;
    * ``noise_rel_rms`` = RMS of the reference's Monte Carlo standard error / R: differences
      below this are not resolved by the ground truth;
    * ``rel_rms_debiased`` = sqrt(max(0, mean d^2 - mean stderr^2)) / R: the squared error
      with the reference's own variance removed (its noise is independent of the estimate).

    Args:
        estimate: (V, 3) radiance of the method.
        reference: (V, 3) ground-truth radiance.
        reference_stderr: (V, 3) standard error of the ground truth, or None.

    Returns:
        dict of floats (and ``vertex_count``).
    """
    est = np.asarray(estimate, np.float64).reshape(-1, 3)
    ref = np.asarray(reference, np.float64).reshape(-1, 3)
    if est.shape != ref.shape:
        raise ValueError(f"error_metrics: estimate {est.shape} and reference {ref.shape} differ")
    if not np.all(np.isfinite(est)):
        bad = int(np.count_nonzero(~np.isfinite(est).all(axis=1)))
        raise ValueError(f"error_metrics: estimate has {bad} vertices with NaN/inf radiance")
    scale = float(np.sqrt(np.mean(ref**2)))
    if scale == 0.0:
        scale = 1.0
    d = np.sqrt(np.mean((est - ref) ** 2, axis=1))
    mse = float(np.mean(d**2))
    out = {
        "rel_rms": float(np.sqrt(mse)) / scale,
        "rel_p99": float(np.percentile(d, 99)) / scale,
        "reference_rms": scale,
        "vertex_count": int(est.shape[0]),
    }
    if reference_stderr is not None:
        se = np.asarray(reference_stderr, np.float64).reshape(-1, 3)
        var = float(np.mean(se**2))
        out["noise_rel_rms"] = float(np.sqrt(var)) / scale
        out["rel_rms_debiased"] = float(np.sqrt(max(0.0, mse - var))) / scale
    return out


def combine_metrics(per_frame: list[dict]) -> dict:
    """Average metrics over frames (RMS-style quantities combined as root-mean-square)."""
    if not per_frame:
        return {}
    keys = set.intersection(*(set(m) for m in per_frame)) - {"vertex_count"}
    out = {}
    for k in sorted(keys):
        vals = np.array([m[k] for m in per_frame], np.float64)
        out[k] = float(np.sqrt(np.mean(vals**2))) if "rms" in k else float(np.mean(vals))
    out["frames"] = len(per_frame)
    return out
