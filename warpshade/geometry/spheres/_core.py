"""Sphere sets bounding one solid: construction, outside-volume estimators, coverage (the
public names are re-exported by :mod:`warpshade.geometry.spheres`)."""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..._wp import launch_parallel, resolve_device, wp
from . import _fit as _fit
from . import _kernels as _k

#: Occupancy-grid cells of the construction: at least this many, and this many per sphere
#: (the bunny at 128 spheres: E 0.279 with 120k cells, 0.250 with 240k).
DEFAULT_GRID_CELLS = 120_000
GRID_CELLS_PER_SPHERE = 2_000


# ---- sphere sets ----------------------------------------------------------------------------
@dataclass
class OutsideVolume:
    """Outside volume of a sphere set w.r.t. a solid (randomised QMC, see module docstring).

    Attributes:
        per_sphere: V(S_i - T) per sphere, (S,) float64, scene units cubed.
        per_sphere_stderr: standard error of each, (S,).
        total: sum of ``per_sphere`` (eq. 35), with ``total_stderr``.
        union: V(union S_i - T), with ``union_stderr``.
        samples_per_sphere, replicates: the estimator's sample counts.
    """

    per_sphere: np.ndarray
    per_sphere_stderr: np.ndarray
    total: float
    total_stderr: float
    union: float
    union_stderr: float
    samples_per_sphere: int
    replicates: int


@dataclass
class SphereSet:
    """Spheres bounding one solid, with the facts of their construction.

    Attributes:
        centres: sphere centres, (S, 3) float64, in the frame of the points they were fit to.
        radii: radii, (S,) float64, same units.
        source: name of the mesh (USD prim path or a given name).
        error: E = sum_i V(S_i - T) / V(T) (eq. 35 / volume, QMC estimate).
        error_stderr: standard error of ``error``.
        error_union: V(union S_i - T) / V(T).
        grid_error: E by the grid estimator the optimisation minimised.
        volume: V(T), QMC estimate, scene units cubed.
        sphere_outside_volume: V(S_i - T) per sphere, (S,).
        sample_face, sample_bary: the surface samples as barycentric points of the mesh's
            faces, (Ns,) int64 and (Ns, 3) float64 (deform them with the mesh).
        sample_sphere: the sphere whose cluster holds each surface sample, (Ns,) int64; that
            sphere bounds it.
        interior_points: interior samples, (Ni, 3) float64; ``interior_sphere`` (Ni,) likewise.
        closed: whether the mesh was closed (False: a shell of ``shell_thickness`` was bounded).
        parameters: construction parameters and statistics (JSON-serialisable dict).
    """

    centres: np.ndarray
    radii: np.ndarray
    source: str = ""
    error: float = float("nan")
    error_stderr: float = float("nan")
    error_union: float = float("nan")
    grid_error: float = float("nan")
    volume: float = float("nan")
    sphere_outside_volume: np.ndarray = field(default_factory=lambda: np.zeros(0))
    sample_face: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    sample_bary: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    sample_sphere: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    interior_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    interior_sphere: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    closed: bool = True
    shell_thickness: float = 0.0
    parameters: dict = field(default_factory=dict)

    _ARRAYS = (
        "centres",
        "radii",
        "sphere_outside_volume",
        "sample_face",
        "sample_bary",
        "sample_sphere",
        "interior_points",
        "interior_sphere",
    )
    _SCALARS = ("source", "error", "error_stderr", "error_union", "grid_error", "volume", "closed", "shell_thickness")

    @property
    def sphere_count(self) -> int:
        return int(self.radii.shape[0])

    def surface_samples(self, points: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """The surface samples placed on a (possibly deformed) copy of the mesh, (Ns, 3)."""
        p = np.asarray(points, np.float64)
        return np.einsum("nk,nkj->nj", self.sample_bary, p[np.asarray(faces, np.int64)[self.sample_face]])

    def to_arrays(self) -> dict:
        """Plain NumPy arrays (for the artifact cache); invert with :meth:`from_arrays`."""
        out = {name: np.asarray(getattr(self, name)) for name in self._ARRAYS}
        meta = {name: getattr(self, name) for name in self._SCALARS}
        meta["parameters"] = self.parameters
        out["meta_json"] = np.array(json.dumps(meta))
        return out

    @classmethod
    def from_arrays(cls, arrays: dict) -> SphereSet:
        """Rebuild a set from :meth:`to_arrays` output."""
        missing = [n for n in cls._ARRAYS + ("meta_json",) if n not in arrays]
        if missing:
            raise ValueError(f"SphereSet.from_arrays: missing arrays {missing}")
        meta = json.loads(str(np.asarray(arrays["meta_json"])))
        kwargs = {n: np.array(arrays[n]) for n in cls._ARRAYS}
        kwargs.update({n: meta[n] for n in cls._SCALARS})
        return cls(parameters=meta.get("parameters", {}), **kwargs)


def _unit_ball(count: int, replicates: int, seed: int) -> np.ndarray:
    """Scrambled-Sobol points mapped volume-preservingly into the unit ball, (R, count, 3)."""
    from scipy.stats import qmc

    out = np.empty((replicates, count, 3))
    for r in range(replicates):
        u = qmc.Sobol(d=3, scramble=True, seed=np.random.default_rng([seed, r])).random(count)
        radius = np.cbrt(u[:, 0])
        z = 1.0 - 2.0 * u[:, 1]
        phi = 2.0 * np.pi * u[:, 2]
        s = np.sqrt(np.maximum(0.0, 1.0 - z * z))
        out[r] = radius[:, None] * np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)
    return out


def _check_spheres(centres, radii, name: str) -> tuple[np.ndarray, np.ndarray]:
    c = np.asarray(centres, np.float64).reshape(-1, 3)
    r = np.asarray(radii, np.float64).reshape(-1)
    if c.shape[0] != r.shape[0]:
        raise ValueError(f"{name}: {c.shape[0]} centres but {r.shape[0]} radii")
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(r))):
        raise ValueError(f"{name}: sphere centres or radii contain NaN or infinite values")
    if np.any(r < 0):
        raise ValueError(f"{name}: negative radius")
    return c, r


def outside_volume(
    centres,
    radii,
    points=None,
    faces=None,
    *,
    name: str = "<mesh>",
    samples_per_sphere: int = 1024,
    replicates: int = 4,
    seed: int = 0,
    open_mesh: str = "error",
    shell_thickness: float | None = None,
    device=None,
    solid=None,
) -> OutsideVolume:
    """Outside volume of spheres w.r.t. the solid of a triangle mesh (QMC, Warp kernel).

    Each sphere gets ``samples_per_sphere`` scrambled-Sobol points per replicate, mapped into
    the ball by ``(u0^(1/3), z = 1 - 2 u1, phi = 2 pi u2)`` (volume preserving, so the set stays
    low-discrepancy). A kernel classifies each point against the solid (winding number over the
    BVH) and counts the spheres covering it: ``V(S_i - T) = V(S_i) mean(outside)``, and the
    union's outside volume is ``sum_i V(S_i) mean(outside / cover)``. Errors are standard errors
    over ``replicates`` independent scramblings; the classification itself is exact away from
    the surface (the fast winding number's far-field approximation only moves points within
    float32 distance of it).

    Args:
        centres: (S, 3); radii: (S,); points/faces: the mesh (or a prepared ``solid``).
        name: mesh name for error messages.
        samples_per_sphere: points per sphere per replicate (a power of two keeps Sobol balanced).
        replicates: independent scramblings (>= 2 for a standard error).
        open_mesh, shell_thickness: see :func:`fit_spheres`.
        device: Warp device.

    Returns:
        :class:`OutsideVolume`.
    """
    c, r = _check_spheres(centres, radii, f"outside_volume ({name})")
    if solid is None:
        solid = _fit.make_solid(points, faces, name, open_mesh=open_mesh, shell_thickness=shell_thickness, device=device)
    if replicates < 2:
        raise ValueError(f"outside_volume ({name}): replicates must be >= 2 for a standard error, got {replicates}")
    s_count = c.shape[0]
    if s_count == 0:
        z = np.zeros(0)
        return OutsideVolume(z, z, 0.0, 0.0, 0.0, 0.0, samples_per_sphere, replicates)
    dev = solid.device
    balls = _unit_ball(samples_per_sphere, replicates, seed)
    cw = wp.array(c.astype(np.float32), dtype=wp.vec3, device=dev)
    rw = wp.array(r.astype(np.float32), dtype=wp.float32, device=dev)
    n = s_count * samples_per_sphere
    outside = wp.empty(n, dtype=wp.float32, device=dev)
    union_w = wp.empty(n, dtype=wp.float32, device=dev)
    mid, th = solid.mesh_id, float(solid.shell_thickness)
    ball_volume = 4.0 / 3.0 * np.pi * r**3
    per = np.empty((replicates, s_count))
    uni = np.empty(replicates)
    for rep in range(replicates):
        ub = wp.array(balls[rep].astype(np.float32), dtype=wp.vec3, device=dev)
        launch_parallel(_k.ball_samples_kernel, n, lambda start, stop, ub=ub: [mid, th, cw, rw, ub, start, outside, union_w], dev,
                        min_count=_fit.SPLIT_MIN)
        per[rep] = ball_volume * outside.numpy().reshape(s_count, samples_per_sphere).astype(np.float64).mean(axis=1)
        uni[rep] = float(np.sum(ball_volume * union_w.numpy().reshape(s_count, samples_per_sphere).astype(np.float64).mean(axis=1)))
    root = math.sqrt(replicates)
    totals = per.sum(axis=1)
    return OutsideVolume(
        per_sphere=per.mean(axis=0),
        per_sphere_stderr=per.std(axis=0, ddof=1) / root,
        total=float(totals.mean()),
        total_stderr=float(totals.std(ddof=1) / root),
        union=float(uni.mean()),
        union_stderr=float(uni.std(ddof=1) / root),
        samples_per_sphere=samples_per_sphere,
        replicates=replicates,
    )


def solid_volume(
    points=None,
    faces=None,
    *,
    name: str = "<mesh>",
    samples: int = 16384,
    replicates: int = 4,
    seed: int = 0,
    open_mesh: str = "error",
    shell_thickness: float | None = None,
    device=None,
    solid=None,
) -> tuple[float, float]:
    """Volume of the solid (union of closed components, or the shell), QMC in the bounding box.

    Returns:
        (volume, standard error) in scene units cubed.
    """
    from scipy.stats import qmc

    if solid is None:
        solid = _fit.make_solid(points, faces, name, open_mesh=open_mesh, shell_thickness=shell_thickness, device=device)
    lo = solid.merged_points.min(axis=0) - solid.shell_thickness
    hi = solid.merged_points.max(axis=0) + solid.shell_thickness
    box = float(np.prod(hi - lo))
    dev = solid.device
    inside = wp.empty(samples, dtype=wp.float32, device=dev)
    vols = np.empty(replicates)
    mid, th = solid.mesh_id, float(solid.shell_thickness)
    for rep in range(replicates):
        u = qmc.Sobol(d=3, scramble=True, seed=np.random.default_rng([seed, 7, rep])).random(samples)
        x = wp.array((lo + u * (hi - lo)).astype(np.float32), dtype=wp.vec3, device=dev)
        launch_parallel(_k.box_samples_kernel, samples, lambda start, stop, x=x: [mid, th, x, start, inside], dev,
                        min_count=_fit.SPLIT_MIN)
        vols[rep] = box * float(inside.numpy().astype(np.float64).mean())
    return float(vols.mean()), float(vols.std(ddof=1) / math.sqrt(replicates))


def coverage_gap(points, centres, radii, device=None) -> np.ndarray:
    """How far each point lies outside a sphere set (Warp kernel, float32).

    Args:
        points: (N, 3) query points; centres (S, 3), radii (S,) the spheres (same frame).
        device: Warp device.

    Returns:
        gap (N,) float32: ``min_s |p - c_s| - r_s``; <= 0 where some sphere covers the point.
    """
    dev = resolve_device(device)
    c, r = _check_spheres(centres, radii, "coverage_gap")
    p = np.ascontiguousarray(points, np.float32).reshape(-1, 3)
    if not np.all(np.isfinite(p)):
        raise ValueError("coverage_gap: points contain NaN or infinite values")
    out = wp.empty(p.shape[0], dtype=wp.float32, device=dev)
    if p.shape[0]:
        wp.launch(
            _k.coverage_gap_kernel,
            dim=p.shape[0],
            inputs=[
                wp.array(p, dtype=wp.vec3, device=dev),
                wp.array(c.astype(np.float32), dtype=wp.vec3, device=dev),
                wp.array(r.astype(np.float32), dtype=wp.float32, device=dev),
                out,
            ],
            device=dev,
        )
    return out.numpy()


def coverage_gap_f64(points, centres, radii) -> np.ndarray:
    """Float64 mirror of :func:`coverage_gap`."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    c, r = _check_spheres(centres, radii, "coverage_gap_f64")
    out = np.empty(p.shape[0])
    for start in range(0, p.shape[0], 4096):
        d = np.linalg.norm(p[start : start + 4096, None, :] - c[None], axis=2) - r[None]
        out[start : start + 4096] = d.min(axis=1)
    return out


def fit_spheres(
    points,
    faces,
    sphere_count: int | None = 32,
    *,
    target_error: float | None = None,
    name: str = "<mesh>",
    open_mesh: str = "error",
    shell_thickness: float | None = None,
    grid_cells: int | None = None,
    interior_step: int = 3,
    iterations: int = 10,
    teleports: int = 16,
    powell_sweeps: int = 3,
    tolerance: float = 1e-3,
    prune: bool = True,
    samples_per_sphere: int = 1024,
    seed: int = 0,
    progress: bool = False,
    device=None,
) -> SphereSet:
    """Spheres that bound a closed triangle mesh with small outside volume (sec. 6.2).

    Args:
        points: vertices, (V, 3), any float dtype, any frame (the spheres come out in it).
        faces: triangles, (F, 3) integer indices. The mesh must be closed (after merging
            coincident vertices) unless ``open_mesh="shell"``.
        sphere_count: number of spheres (the result may have fewer when ``prune`` drops
            spheres whose samples others already cover). With ``target_error`` it is the
            maximum count tried.
        target_error: if given, fit 1, 2, 4, ... spheres (up to ``sphere_count``) and return the
            first set whose E is at most this ("model no more than the scene needs").
        name: mesh name used in messages and stored as ``source``.
        open_mesh: "error" (default: refuse open meshes) or "shell" (bound the shell of
            half-thickness ``shell_thickness`` around the surface; default 1% of the diagonal).
        grid_cells: cells of the occupancy grid of the outside-volume objective (default
            ``max(120000, 2000 * sphere_count)``: smaller spheres need finer cells).
        interior_step: interior samples every this many grid cells.
        iterations: Lloyd iterations of the first phase (each teleport trial runs up to 3).
        teleports: cluster-teleportation attempts (stops after 3 rejections in a row).
        powell_sweeps: Powell sweeps per centre update.
        tolerance: relative E decrease under which Lloyd iterations stop.
        prune: drop spheres whose samples are covered by the others.
        samples_per_sphere: QMC points per sphere per replicate for the reported E.
        seed: seeds the initial centres and the QMC scrambling.
        progress: show a tqdm bar over the teleport attempts.
        device: Warp device of the classification kernels.

    Returns:
        :class:`SphereSet` bounding every surface and interior sample.

    Raises:
        ValueError: naming the mesh, for NaN points, an open mesh (with ``open_mesh="error"``),
            a closed mesh of (almost) zero volume, or a sphere count < 1 or larger than the
            number of samples.
    """
    t0 = time.perf_counter()
    if sphere_count is None:
        sphere_count = 64 if target_error is not None else 32
    if isinstance(sphere_count, bool) or not isinstance(sphere_count, (int, np.integer)) or sphere_count < 1:
        raise ValueError(f"mesh {name}: sphere_count must be an integer >= 1, got {sphere_count!r}")
    solid = _fit.make_solid(points, faces, name, open_mesh=open_mesh, shell_thickness=shell_thickness, device=device)
    if grid_cells is None:
        grid_cells = max(DEFAULT_GRID_CELLS, GRID_CELLS_PER_SPHERE * int(sphere_count))
    disc = _fit.Discretisation(solid, grid_cells=grid_cells, interior_step=interior_step)
    sample_count = disc.samples.shape[0]
    if sphere_count > sample_count:
        raise ValueError(
            f"mesh {name}: sphere_count {sphere_count} exceeds the {sample_count} samples of the mesh "
            f"at this grid resolution (grid_cells={grid_cells}); use fewer spheres or more cells"
        )
    volume, volume_stderr = solid_volume(solid=solid, seed=seed)
    common = {
        "iterations": iterations,
        "teleports": teleports,
        "powell_sweeps": powell_sweeps,
        "tolerance": tolerance,
        "prune": prune,
        "samples_per_sphere": samples_per_sphere,
        "seed": seed,
        "progress": progress,
    }
    if target_error is None:
        result = _fit_count(solid, disc, int(sphere_count), volume, volume_stderr, **common)
        trials = [(result.sphere_count, result.error)]
    else:
        if not target_error > 0:
            raise ValueError(f"mesh {name}: target_error must be > 0, got {target_error!r}")
        trials = []
        count = 1
        while True:
            result = _fit_count(solid, disc, count, volume, volume_stderr, **common)
            trials.append((count, result.error))
            if result.error <= target_error or count >= sphere_count:
                break
            count = min(2 * count, int(sphere_count))
    result.parameters.update(
        {
            "requested_sphere_count": int(sphere_count),
            "target_error": target_error,
            "trials": [[int(a), float(b)] for a, b in trials],
            "grid_cells": int(grid_cells),
            "grid_spacing": float(disc.h),
            "interior_step": int(interior_step),
            "open_mesh": open_mesh,
            "seconds": time.perf_counter() - t0,
        }
    )
    return result


def _fit_count(solid, disc, count, volume, volume_stderr, *, iterations, teleports, powell_sweeps, tolerance, prune, samples_per_sphere, seed, progress) -> SphereSet:
    """One construction with a fixed sphere count (see :func:`fit_spheres`)."""
    t0 = time.perf_counter()
    state, history = _fit.construct(disc, count, iterations, teleports, tolerance, powell_sweeps, seed, progress, prune=prune)
    centres, radii = state.centres.copy(), state.radii.copy()
    clustered = disc.surface_clustered
    surface_sphere = np.full(disc.surface.shape[0], -1, dtype=np.int64)
    surface_sphere[clustered] = state.labels[: disc.surface_count]
    interior_sphere = state.labels[disc.surface_count :].copy()
    # samples left out of the clustering join the cluster of their nearest clustered sample (a
    # neighbour on the same part of the surface, so the membership follows the mesh when it
    # deforms); then one more centre update on the complete clusters, and exact bounds
    rest = np.nonzero(~clustered)[0]
    if rest.size:
        _, nearest = disc.kdtree.query(disc.surface[rest])
        surface_sphere[rest] = state.labels[np.asarray(nearest, np.int64)]
    if rest.size:
        members = [np.concatenate([disc.surface[surface_sphere == i], disc.interior[interior_sphere == i]]) for i in range(radii.size)]
        centres = _fit.update_centres(disc, members, centres, powell_sweeps)
        radii = np.array([_fit.bounding_radius(m, c) for m, c in zip(members, centres)])
    radii = radii * (1.0 + _fit.RADIUS_PAD_RELATIVE) + _fit.RADIUS_PAD_RELATIVE * solid.diagonal
    if not (np.all(np.isfinite(centres)) and np.all(np.isfinite(radii))):
        raise RuntimeError(f"mesh {solid.name}: the construction produced non-finite spheres")
    grid_outside = np.array([disc.outside_volume(c, r) for c, r in zip(centres, radii)])
    ov = outside_volume(centres, radii, solid=solid, samples_per_sphere=samples_per_sphere, seed=seed)
    rel_var = (ov.total_stderr / max(ov.total, 1e-300)) ** 2 + (volume_stderr / volume) ** 2
    error = ov.total / volume
    return SphereSet(
        centres=centres,
        radii=radii,
        source=solid.name,
        error=float(error),
        error_stderr=float(error * math.sqrt(rel_var)),
        error_union=float(ov.union / volume),
        grid_error=float(grid_outside.sum() / disc.volume),
        volume=float(volume),
        sphere_outside_volume=ov.per_sphere,
        sample_face=disc.sample_face.copy(),
        sample_bary=disc.sample_bary.copy(),
        sample_sphere=surface_sphere,
        interior_points=disc.interior.copy(),
        interior_sphere=interior_sphere,
        closed=solid.closed,
        shell_thickness=float(solid.shell_thickness),
        parameters={
            "sphere_count": int(count),
            "final_sphere_count": int(radii.shape[0]),
            "iterations": int(iterations),
            "teleports": int(teleports),
            "teleports_tried": int(history["teleports_tried"]),
            "teleports_accepted": int(history["teleports_accepted"]),
            "initial_grid_error": float(history["initial_error"] / disc.volume),
            "clustered_grid_error": float(history["final_error"] / disc.volume),
            "powell_sweeps": int(powell_sweeps),
            "seed": int(seed),
            "prune": bool(prune),
            "volume_stderr": float(volume_stderr),
            "grid_volume": float(disc.volume),
            "samples_clustered": int(disc.samples.shape[0]),
            "samples_surface": int(disc.surface.shape[0]),
            "samples_interior": int(disc.interior.shape[0]),
            "construction_seconds": time.perf_counter() - t0,
        },
    )
