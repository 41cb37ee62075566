"""The sinusoidal wrinkle model (Sloan et al. 2005, Sec. 4.2).

A wrinkle is an extruded sinusoidal groove. In the *groove frame* (x across the groove, y along
it, z the base-surface normal; lengths in groove periods) the height field is::

    h(x) = -depth (1 - cos(2 pi x)) / 2                      (x = phase in [0, 1), depth >= 0)

Its diffuse transfer (shadowing by the groove walls, cosine about the true wrinkled normal) is
ray traced once over a grid of phase x and depth d (:func:`groove_transfer`), expressed in the
groove frame, and fitted with a 3-lobe ZH model whose parameters are *bilinear functions* of
(x, d) over a coarse control grid, periodic in x (:func:`fit_wrinkle_table`). As in the paper,
the DC and linear bands are stored explicitly (their control values by linear least squares),
the lobes fit the higher bands, and the fit is a single optimisation over the whole map (so
lobes correspond between neighbouring (x, d) and interpolate cleanly), initialised by an optimal
linear lobe with two lobes placed symmetrically about it in the groove's cross-section plane at
a searched angle, then refined by conjugate gradients (``scipy.optimize.minimize(method="CG")``
with the analytic gradient; "L-BFGS-B" is available too).

At render time the groove is shading only (the mesh stays smooth): per vertex the phase x (from
its rest position), the groove orientation in its tangent frame and the depth d (a static
ramp plus a term driven by the local compression of the deforming mesh) select lobe parameters
by bilinear look-up; the lobes are rotated to world by the tangent frame (see ``ldprt.wrinkle``
stages).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import sparse

from ...basis import sh
from ...basis.zh import fitting as _zh_fit
from ...geometry._frames import TangentFrames

__all__ = [
    "WrinkleTable",
    "bilinear_weights",
    "evaluate_table",
    "fit_wrinkle_table",
    "groove_height",
    "groove_layout",
    "groove_mesh",
    "groove_transfer",
]

LOBES = 3


def groove_height(x, depth) -> np.ndarray:
    """``h(x) = -depth (1 - cos(2 pi x)) / 2`` in groove periods."""
    return -np.asarray(depth, np.float64) * 0.5 * (1.0 - np.cos(2.0 * np.pi * np.asarray(x, np.float64)))


def groove_mesh(depth: float, phase_count: int, periods: int = 4, length: float = 8.0, rows: int = 33):
    """Triangulated groove height field: x in [-periods, periods] with ``phase_count`` vertices
    per period (vertex k at x = k / phase_count), y in [-length/2, length/2].

    Returns:
        ``(points (P, 3), faces (F, 3), receivers (phase_count,))``: receivers are the vertices at
        x = 0 .. (phase_count-1)/phase_count on the middle row y = 0.
    """
    xs = np.arange(-periods * phase_count, periods * phase_count + 1) / phase_count
    ys = np.linspace(-0.5 * length, 0.5 * length, rows)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    pts = np.stack([gx.ravel(), gy.ravel(), groove_height(gx, depth).ravel()], 1)
    idx = np.arange(gx.size).reshape(gx.shape)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    zero = periods * phase_count
    receivers = idx[zero : zero + phase_count, rows // 2]
    return pts, faces, receivers


def groove_transfer(order: int, phase_count: int, depths, samples: int = 512, device=None, seed: int = 0) -> np.ndarray:
    """Ray-traced diffuse transfer of the groove, groove frame, shape (len(depths), phase_count, n*n)."""
    from ...scene import Mesh, Scene
    from ...transfer import compute

    out = []
    for depth in np.asarray(depths, dtype=np.float64):
        pts, faces, receivers = groove_mesh(float(depth), phase_count)
        scene = Scene.from_meshes([Mesh("/groove", pts, faces)])
        res = compute(scene, 0.0, order, samples, space="world", device=device, seed=seed, vertices=receivers)
        out.append(res.transfer.astype(np.float64))
    return np.stack(out)


def bilinear_weights(phase, depth, phase_controls: int, depth_controls: int, max_depth: float) -> sparse.csr_matrix:
    """Bilinear basis weights, (S, phase_controls * depth_controls); periodic in phase (control
    i at x = i / phase_controls), clamped in depth (control j at d = j max_depth / (Cd - 1)).
    Column index = i * depth_controls + j."""
    x = np.mod(np.asarray(phase, np.float64), 1.0) * phase_controls
    d = np.clip(np.asarray(depth, np.float64) / max_depth, 0.0, 1.0) * (depth_controls - 1)
    i0 = np.floor(x).astype(np.int64) % phase_controls
    tx = x - np.floor(x)
    i1 = (i0 + 1) % phase_controls
    j0 = np.minimum(np.floor(d).astype(np.int64), depth_controls - 2)
    td = d - j0
    rows = np.repeat(np.arange(x.size), 4)
    cols = np.stack([i0 * depth_controls + j0, i1 * depth_controls + j0, i0 * depth_controls + j0 + 1,
                     i1 * depth_controls + j0 + 1], 1).ravel()
    vals = np.stack([(1 - tx) * (1 - td), tx * (1 - td), (1 - tx) * td, tx * td], 1).ravel()
    return sparse.csr_matrix((vals, (rows, cols)), shape=(x.size, phase_controls * depth_controls))


@dataclass
class WrinkleTable:
    """Control values of the wrinkle model, groove frame (see module docstring).

    Attributes:
        axes: (Cx, Cd, 3, 3) lobe axes (unnormalised control values; normalise after interpolating).
        coeffs: (Cx, Cd, 3, n) lobe convolution coefficients (bands 0-1 zero).
        stored: (Cx, Cd, 4) DC + linear SH.
        max_depth: depth of the last depth control (groove periods).
        sample_error: relative error over the fitted samples (paper's metric), float.
        independent_error: the same for an independent per-sample 3-lobe fit (no correspondence).
        initial_error: error of the initial guess (before the joint optimisation).
        iterations: optimiser iterations.
    """

    axes: np.ndarray
    coeffs: np.ndarray
    stored: np.ndarray
    max_depth: float
    sample_error: float
    independent_error: float
    initial_error: float
    iterations: int

    @property
    def order(self) -> int:
        return int(self.coeffs.shape[-1])


def _parameters(w, theta, count):
    return (w @ theta.reshape(w.shape[1], -1)).reshape(count, -1)


def fit_wrinkle_table(transfer, max_depth: float, phase_controls: int = 16, depth_controls: int = 6,
                      method: str = "CG", max_iterations: int = 400, angles: int = 16) -> WrinkleTable:
    """Fit the 3-lobe bilinear (x, d) model to groove transfer sampled on a regular grid.

    Args:
        transfer: (Sd, Sx, n*n) from :func:`groove_transfer` with depths ``linspace(0, max_depth, Sd)``
            and phases ``arange(Sx) / Sx``.
        max_depth: largest sampled depth.
        phase_controls, depth_controls: control grid (Cx periodic, Cd including both ends).
        method: "CG" (the paper) or "L-BFGS-B".
        max_iterations: optimiser iterations.
        angles: candidate half-angles of the two side lobes for the initial guess.
    """
    from scipy.optimize import minimize

    t_grid = np.asarray(transfer, np.float64)
    sd, sx, n2 = t_grid.shape
    order = math.isqrt(n2)
    phases = np.arange(sx) / sx
    depths = np.linspace(0.0, max_depth, sd)
    dd, xx = np.meshgrid(depths, phases, indexing="ij")
    t = t_grid.reshape(-1, n2)
    count = t.shape[0]
    w = bilinear_weights(xx.ravel(), dd.ravel(), phase_controls, depth_controls, max_depth)
    wd = w.toarray()
    stored_ctrl, *_ = np.linalg.lstsq(wd, t[:, :4], rcond=None)
    target = t.copy()
    target[:, :4] = 0.0
    problem = _zh_fit.FitProblem(order, LOBES, 2)
    fitted = problem.fitted

    # initial guess: optimal linear lobe + two lobes rotated by +-beta about the groove (y) axis
    a0 = _zh_fit.optimal_linear_axes(t)

    def rot_y(v, beta):
        c, s = np.cos(beta), np.sin(beta)
        return np.stack([c * v[:, 0] + s * v[:, 2], v[:, 1], -s * v[:, 0] + c * v[:, 2]], 1)

    best = None
    for beta in np.linspace(0.1, 1.4, angles):
        axes = np.stack([a0, rot_y(a0, beta), rot_y(a0, -beta)], 1)
        coeffs = _zh_fit.solve_coefficients(target, axes, fitted)
        psi = float(np.sum(_zh_fit._psi(target, axes, coeffs)))
        if best is None or psi < best[0]:
            best = (psi, axes, coeffs)
    p_init = _zh_fit.pack(problem, best[1], best[2])
    theta0, *_ = np.linalg.lstsq(wd, p_init, rcond=None)
    norm2 = float(np.sum(t * t))
    stored_resid = float(np.sum((wd @ stored_ctrl - t[:, :4]) ** 2))

    def fun(theta_flat):
        p = _parameters(w, theta_flat, count)
        psi, grad = _zh_fit.objective(problem, p, target)
        return float(psi.sum()) / norm2, (w.T @ grad).ravel() / norm2

    f0, _ = fun(theta0.ravel())
    res = minimize(fun, theta0.ravel(), jac=True, method=method, options={"maxiter": int(max_iterations)})
    theta = res.x.reshape(w.shape[1], -1)
    axes_c, coeffs_c = _zh_fit.unpack(problem, theta)
    ctrl = (phase_controls, depth_controls)
    indep = _zh_fit.fit_lobes(target, problem, _zh_fit.FitOptions(restarts=0))
    return WrinkleTable(
        axes=axes_c.reshape(*ctrl, LOBES, 3),
        coeffs=coeffs_c.reshape(*ctrl, LOBES, order),
        stored=stored_ctrl.reshape(*ctrl, 4),
        max_depth=float(max_depth),
        sample_error=float(np.sqrt(res.fun + stored_resid / norm2)),
        independent_error=float(np.sqrt((np.sum(indep.psi) + stored_resid) / norm2)),
        initial_error=float(np.sqrt(f0 + stored_resid / norm2)),
        iterations=int(res.nit),
    )


def evaluate_table(table: WrinkleTable, phase, depth) -> np.ndarray:
    """Float64 reference: SH transfer (groove frame) at (phase, depth) pairs, shape (S, n*n)."""
    cx, cd = table.axes.shape[:2]
    w = bilinear_weights(phase, depth, cx, cd, table.max_depth)
    axes = (w @ table.axes.reshape(cx * cd, -1)).reshape(-1, LOBES, 3)
    coeffs = (w @ table.coeffs.reshape(cx * cd, -1)).reshape(-1, LOBES, table.order)
    axes = axes / np.linalg.norm(axes, axis=-1, keepdims=True)
    y = sh.basis(axes.reshape(-1, 3), table.order).reshape(axes.shape[0], LOBES, -1)
    out = np.einsum("bij,bij->bj", y, coeffs[:, :, sh.band_of(table.order)])
    out[:, :4] += w @ table.stored.reshape(cx * cd, 4)
    return out


def groove_layout(scene, axis, center, grooves: int, depth_range, cap_cosine: float = 0.7):
    """Per-vertex groove parameters on a rest pose around an axis (flutes along the axis).

    Returns dict of NumPy arrays (V,): ``phase`` (grooves * angle around the axis / 2 pi),
    ``groove_angle`` (angle from the rest tangent to the groove's cross-section direction, about
    the normal), ``base_depth`` (linear ramp ``depth_range`` along the axis; 0 where
    ``|n . axis| > cap_cosine``: end caps), ``axis_neighbour`` / ``rest_length`` (the one-ring
    neighbour most aligned with the axis, and the rest distance to it).
    """
    tf = TangentFrames.from_scene(scene, device="cpu")
    rule = tf.rule
    parts = [m.points @ m.transforms[0][:3, :3] + m.transforms[0][3, :3] for m in scene.meshes]
    p = np.concatenate(parts)
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    rel = p - np.asarray(center, np.float64)
    along = rel @ a
    radial = rel - along[:, None] * a
    ref = np.cross(a, [1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.cross(a, [0.0, 1.0, 0.0])
    ref /= np.linalg.norm(ref)
    angle = np.arctan2(radial @ np.cross(a, ref), radial @ ref)
    phase = np.mod(grooves * angle / (2.0 * np.pi), 1.0)
    n = rule.rest_normals
    across = np.cross(a, radial)
    across -= np.sum(across * n, axis=1, keepdims=True) * n
    length = np.linalg.norm(across, axis=1, keepdims=True)
    across = np.where(length > 1e-12, across / np.maximum(length, 1e-300), rule.rest_tangents)
    t = rule.rest_tangents
    b = np.cross(n, t)
    groove_angle = np.arctan2(np.sum(across * b, axis=1), np.sum(across * t, axis=1))
    lo, hi = along.min(), along.max()
    ramp = (along - lo) / max(hi - lo, 1e-12)
    base = depth_range[0] + (depth_range[1] - depth_range[0]) * ramp
    base = np.where(np.abs(n @ a) > cap_cosine, 0.0, base)
    owner = np.repeat(np.arange(p.shape[0]), np.diff(rule.offsets))
    e = p[rule.neighbours] - p[owner]
    score = np.abs(e @ a) / np.maximum(np.linalg.norm(e, axis=1), 1e-300)
    neighbour = np.full(p.shape[0], -1, np.int64)
    rest_len = np.zeros(p.shape[0])
    for v in range(p.shape[0]):
        s, t_ = rule.offsets[v], rule.offsets[v + 1]
        if t_ > s:
            k = s + int(np.argmax(score[s:t_]))
            neighbour[v] = rule.neighbours[k]
            rest_len[v] = np.linalg.norm(e[k])
    return {"phase": phase, "groove_angle": groove_angle, "base_depth": base, "axis_neighbour": neighbour,
            "rest_length": rest_len}
