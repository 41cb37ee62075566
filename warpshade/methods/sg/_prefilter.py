"""SG lighting (Wang et al. 2009, sec. 6), the specular term: the prefiltered environment
``Gamma_L(p, lambda)`` and its float64 oracle. The kernels' lookup is in :mod:`._lighting_warp`.

**Prefiltered environment** (:class:`PrefilteredEnvironment`). ``Gamma_L(p, lambda) = integral
G(i; p, lambda, 1) L(i) di`` (eq. 34-35), where ``L`` is the environment as the renderer and the
ray-traced reference see it: the bilinear interpolation of the texels (``Environment.radiance``).
The table stores the normalised ``Gamma_hat = Gamma / integral(G)`` (the lobe-weighted mean
radiance, tending to ``L(p)`` for sharp lobes and to the mean radiance for broad ones) for
sharpness levels ``0.5 * sqrt(2)^k`` up to 8192 (or less, see :func:`default_levels`) as lat-long
maps in the environment's map frame. The factor sqrt(2) keeps the interpolation between levels
within about 1 % on a sky with a bright sun (a factor 2 gives 4 %); the last level is where a
lobe's width (``1 / sqrt(lambda)``) is a quarter of the environment's texel (capped at 8192).

* Each level's map has ``OUTPUT_TEXELS_PER_SIGMA`` texels per lobe width, rounded up to a
  size of the environment's 2x mip chain or to ``MAX_OUTPUT_SCALE`` times its size: broad lobes
  get coarse maps, lobes narrower than a few texels maps finer than the environment.
* Each output texel sums the source texels within the lobe's support, the angle beyond which
  ``G < SUPPORT_THRESHOLD`` (relative to its peak), times their exact solid angles. The source
  is the coarsest mip (solid-angle weighted 2x2 means: energy is preserved exactly) with at
  least ``SOURCE_TEXELS_PER_SIGMA`` texels per lobe width; for lobes narrower than that on the
  full map, each texel is split into ``sub x sub`` cells where the bilinear radiance is
  evaluated, so a sun disc of a few texels is integrated accurately at every sharpness.
* Lookup (:meth:`PrefilteredEnvironment.lookup`, :func:`._lighting_warp.gamma_lookup`, same
  arithmetic): bilinear within a map; between levels linear in ``log lambda`` of
  ``log Gamma_hat`` (geometric), exact for a uniform region (constant) and for a source much
  smaller than the lobe (``Gamma_hat`` proportional to ``lambda``), where linear interpolation
  of ``Gamma`` would be off by 6 % halfway; below the first level linear in ``lambda`` from the
  mean radiance (so ``Gamma(p, 0)`` is exactly the environment's integral); beyond the last
  level linear in the lobe width ``sqrt(lambda_last / lambda)`` towards the environment's own
  bilinear radiance, the exact limit ``Gamma -> L(p) integral(G)``. The result is
  ``Gamma_hat * integral(G)``. Directions are world directions with a world->map rotation, so a
  turning sky only changes that matrix.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ...basis import quadrature, sg
from ._envmap import bilinear_map, check_environment, environment_integral, row_weights, source_chain, subdivided

__all__ = [
    "OUTPUT_TEXELS_PER_SIGMA",
    "SOURCE_TEXELS_PER_SIGMA",
    "SUPPORT_THRESHOLD",
    "default_levels",
    "gamma_f64",
]

#: Truncation of a prefilter lobe, relative to its peak: a 1-degree sun 10^4 times brighter than
#: the sky, dropped at this weight, changes Gamma of a lambda = 100 lobe by ~0.15 % of the sky's.
SUPPORT_THRESHOLD = 1.0e-5
#: Texels per lobe width (1/sqrt(lambda)) of a level's map: bilinear error ~ (1/4)^2 / 8 = 0.8 %
#: of the curvature of the sharpest feature (a point-like sun blurred by the lobe).
OUTPUT_TEXELS_PER_SIGMA = 4.0
#: Source texels per lobe width when summing: the lobe's variation over a texel of texel means
#: costs ~ (1/k)^2 / 24 = 1 %, the 2x2 means of the mip a variance h^2/12 = 2 % of the lobe's
#: (the luminance centroids keep sources in place).
SOURCE_TEXELS_PER_SIGMA = 2.0
#: Most cells per texel side when a lobe is narrower than the full map resolves.
MAX_SUBDIVISION = 16
#: Smallest map height of a level (when the mip chain allows).
MIN_LEVEL_HEIGHT = 8
#: Largest map of a level, as a multiple of the environment's size: lobes narrower than a texel
#: get maps up to this much finer than the environment, to resolve a sun blurred by the lobe.
MAX_OUTPUT_SCALE = 2
#: Default level sharpness: first, growth factor, cap.
LEVEL_FIRST = 0.5
LEVEL_FACTOR = math.sqrt(2.0)
LEVEL_CAP = 8192.0
#: Sub-cells per lobe width of :func:`gamma_f64` (finer than the kernel's).
REFERENCE_CELLS_PER_SIGMA = 5.0
REFERENCE_MAX_SUBDIVISION = 24

_FORMAT_VERSION = 1




def default_levels(env) -> np.ndarray:
    """``0.5 * sqrt(2)^k`` up to the first level whose lobe width ``1/sqrt(lambda)`` is at most a
    quarter of the map's texel angle ``pi / H``, capped at 8192. Float64 (L,).

    Beyond the last level the lookup blends towards the map's own bilinear radiance linearly in
    the lobe width; that is accurate only once the lobe is well inside a texel (near a sun edge
    ``Gamma_hat`` still falls steeply while the lobe shrinks from half a texel to a quarter)."""
    texel = math.pi / env.height
    top = min(LEVEL_CAP, 16.0 / texel ** 2)
    levels = [LEVEL_FIRST]
    while levels[-1] < top:
        levels.append(levels[-1] * LEVEL_FACTOR)
    return np.asarray(levels)


def _check_levels(levels) -> np.ndarray:
    lv = np.asarray(levels, np.float64)
    if lv.ndim != 1 or lv.size < 1 or not np.all(np.isfinite(lv)) or np.any(lv <= 0.0) or np.any(np.diff(lv) <= 0.0):
        raise ValueError(f"PrefilteredEnvironment: levels must be a non-empty, strictly increasing 1-D array of "
                         f"finite sharpness values > 0, got {levels!r}")
    return lv


def _pick(chain, needed_height: float):
    """Index of the coarsest chain entry at least ``needed_height`` tall (0 = the full map)."""
    for idx in range(len(chain) - 1, -1, -1):
        if chain[idx].shape[0] >= needed_height:
            return idx
    return 0


def _output_shape(chain, needed_height: float) -> tuple[int, int]:
    """A level's map size: the smallest of the mip chain's sizes and ``MAX_OUTPUT_SCALE`` times
    the environment's that is at least ``needed_height`` (and ``MIN_LEVEL_HEIGHT``) tall."""
    h, w = chain[0].shape[:2]
    sizes = [c.shape[:2] for c in chain[::-1]] + [(h * k, w * k) for k in range(2, MAX_OUTPUT_SCALE + 1)]
    need = max(needed_height, MIN_LEVEL_HEIGHT)
    for size in sizes:
        if size[0] >= need:
            return int(size[0]), int(size[1])
    return int(sizes[-1][0]), int(sizes[-1][1])


def _support_angle(lam: float) -> float:
    # G = exp(-lam |p - s|^2 / 2) = exp(lam (cos - 1)) >= threshold  <=>  cos >= 1 + ln(t) / lam
    return math.acos(max(-1.0, 1.0 + math.log(SUPPORT_THRESHOLD) / lam))



@dataclass
class PrefilteredEnvironment:
    """The prefiltered environment ``Gamma_L(p, lambda)`` (eq. 34-35) as a pyramid over lambda.

    Attributes:
        levels: sharpness of each level, (L,) float64, increasing.
        maps: L + 1 lat-long maps (H_l, W_l, 3) float32 in the environment's map frame: the
            normalised ``Gamma_hat = Gamma / integral(G)`` of each level, then the environment
            itself (the lambda -> infinity limit).
        mean: ``Gamma_hat`` at lambda = 0, the mean radiance (3,) float64.
        world_to_map: default rotation (3, 3) taking world directions to the map frame (the
            transpose of the environment's ``to_world`` at build time).
        report: ``build_s``, ``nbytes``, and per level its ``lambda``, map ``shape``, ``source``
            shape and ``sub`` (cells per source texel side).
    """

    levels: np.ndarray
    maps: list
    mean: np.ndarray
    world_to_map: np.ndarray = field(default_factory=lambda: np.eye(3))
    report: dict = field(default_factory=dict)

    # ---- construction -----------------------------------------------------------------------
    @classmethod
    def build(cls, env, levels=None, device=None, progress=None) -> "PrefilteredEnvironment":
        """Prefilter an environment with the Warp kernel :data:`._lighting_warp.prefilter_kernel`.

        Args:
            env: :class:`~warpshade.scene._lighting.Environment` (finite, non-negative).
            levels: sharpness values (increasing, > 0); default :func:`default_levels`.
            device: Warp device (None = Warp's default).
            progress: optional callable ``(done_levels, level_count)`` after each level.

        Returns:
            The table (host copies of the maps; :meth:`to_device` uploads them).
        """
        from ..._wp import launch_parallel, resolve_device, wp
        from ._lighting_warp import prefilter_kernel

        t0 = time.perf_counter()
        img = check_environment(env, "PrefilteredEnvironment.build")
        lv = _check_levels(default_levels(env) if levels is None else levels)
        dev = resolve_device(device)
        sources = source_chain(img)
        chain = [c[0] for c in sources]
        full_h = img.shape[0]
        mean = environment_integral(env) / (4.0 * math.pi)
        src_cache: dict = {}
        maps, info = [], []
        for n, lam in enumerate(lv):
            sigma = 1.0 / math.sqrt(lam)
            oh, ow = _output_shape(chain, OUTPUT_TEXELS_PER_SIGMA * math.pi / sigma)
            need_src = SOURCE_TEXELS_PER_SIGMA * math.pi / sigma
            src_idx = _pick(chain, need_src)
            sub = 1
            if src_idx == 0 and full_h < need_src:
                # even: the cell mid-points then integrate the bilinear radiance exactly (its kinks
                # are at the texel centres, i.e. on cell boundaries)
                sub = int(min(MAX_SUBDIVISION, 2 * math.ceil(need_src / full_h / 2.0)))
            key = (src_idx, sub)
            if key not in src_cache:
                if sub == 1:
                    values, dirs = sources[src_idx]
                else:
                    values, dirs = subdivided(img, sub)
                sh, sw = values.shape[:2]
                src_cache[key] = (wp.array(values.astype(np.float32), dtype=wp.vec3, device=dev),
                                  wp.array(dirs.astype(np.float32), dtype=wp.vec3, device=dev),
                                  wp.array(row_weights(sh, sw).astype(np.float32), dtype=float, device=dev))
            src = src_cache[key]
            out = wp.zeros(oh * ow, dtype=wp.vec3, device=dev)
            unit = float(sg.integral(lam))
            support = _support_angle(float(lam))

            def inputs(start, stop, src=src, out=out, oh=oh, ow=ow, lam=lam, support=support, unit=unit):
                return [*src, int(oh), int(ow), float(lam), float(support), float(1.0 / unit), int(start), out]

            launch_parallel(prefilter_kernel, oh * ow, inputs, dev, min_count=256)
            maps.append(out.numpy().reshape(oh, ow, 3))
            info.append({"lambda": float(lam), "shape": [int(oh), int(ow)],
                         "source": list(chain[src_idx].shape[:2]), "sub": int(sub)})
            if progress is not None:
                progress(n + 1, lv.size)
        maps.append(np.asarray(env.image, np.float32).copy())
        table = cls(lv, maps, mean, np.asarray(env.to_world, np.float64).T.copy())
        table.report = {"build_s": time.perf_counter() - t0, "nbytes": table.nbytes, "levels": info,
                        "device": str(dev)}
        return table

    @property
    def level_count(self) -> int:
        return int(self.levels.size)

    @property
    def nbytes(self) -> int:
        """Bytes of the maps (float32 RGB), the table's memory on the device."""
        return int(sum(m.size for m in self.maps) * 4)

    # ---- caching ----------------------------------------------------------------------------
    def arrays(self) -> dict:
        """Plain arrays for a cache: ``levels`` (L,), ``heights`` / ``widths`` (L + 1,) int64,
        ``data`` (sum of map texels, 3) float32, ``mean`` (3,), ``world_to_map`` (3, 3),
        ``format_version`` (1,)."""
        return {
            "levels": self.levels.copy(),
            "heights": np.array([m.shape[0] for m in self.maps], np.int64),
            "widths": np.array([m.shape[1] for m in self.maps], np.int64),
            "data": np.concatenate([m.reshape(-1, 3) for m in self.maps]).astype(np.float32),
            "mean": np.asarray(self.mean, np.float64).copy(),
            "world_to_map": np.asarray(self.world_to_map, np.float64).copy(),
            "format_version": np.array([_FORMAT_VERSION], np.int64),
        }

    @classmethod
    def from_arrays(cls, arrays) -> "PrefilteredEnvironment":
        """Rebuild from :meth:`arrays` (e.g. read from a cache), checking every entry.

        Raises:
            ValueError: naming the missing or inconsistent entry.
        """
        need = ("levels", "heights", "widths", "data", "mean", "world_to_map", "format_version")
        for key in need:
            if key not in arrays:
                raise ValueError(f"PrefilteredEnvironment.from_arrays: missing entry {key!r}")
        version = np.asarray(arrays["format_version"]).reshape(-1)
        if version.size != 1 or int(version[0]) != _FORMAT_VERSION:
            raise ValueError(f"PrefilteredEnvironment.from_arrays: format_version {version.tolist()} is not {_FORMAT_VERSION}")
        try:
            lv = _check_levels(arrays["levels"])
        except ValueError as exc:
            raise ValueError(f"PrefilteredEnvironment.from_arrays: entry 'levels': {exc}") from None
        heights = np.asarray(arrays["heights"]).reshape(-1)
        widths = np.asarray(arrays["widths"]).reshape(-1)
        if heights.shape != (lv.size + 1,) or widths.shape != (lv.size + 1,) or np.any(heights < 1) or np.any(widths < 1):
            raise ValueError(f"PrefilteredEnvironment.from_arrays: entries 'heights'/'widths' must hold {lv.size + 1} "
                             f"positive sizes, got {heights.tolist()} / {widths.tolist()}")
        data = np.asarray(arrays["data"])
        total = int(np.sum(heights.astype(np.int64) * widths))
        if data.shape != (total, 3):
            raise ValueError(f"PrefilteredEnvironment.from_arrays: entry 'data' must be ({total}, 3), got {data.shape}")
        if not np.all(np.isfinite(data)) or np.any(data < 0.0):
            raise ValueError("PrefilteredEnvironment.from_arrays: entry 'data' has NaN, infinite or negative values")
        mean = np.asarray(arrays["mean"], np.float64)
        if mean.shape != (3,) or not np.all(np.isfinite(mean)) or np.any(mean < 0.0):
            raise ValueError(f"PrefilteredEnvironment.from_arrays: entry 'mean' must be 3 finite values >= 0, got {mean!r}")
        rot = np.asarray(arrays["world_to_map"], np.float64)
        if rot.shape != (3, 3) or not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6):
            raise ValueError("PrefilteredEnvironment.from_arrays: entry 'world_to_map' must be a (3, 3) rotation")
        maps, start = [], 0
        for h, w in zip(heights, widths):
            maps.append(data[start:start + h * w].astype(np.float32).reshape(int(h), int(w), 3))
            start += int(h * w)
        return cls(lv, maps, mean, rot)

    # ---- lookups ----------------------------------------------------------------------------
    def _rotation(self, world_to_map):
        if world_to_map is None:
            return np.asarray(self.world_to_map, np.float64)
        rot = np.asarray(world_to_map, np.float64)
        if rot.shape != (3, 3) or not np.all(np.isfinite(rot)):
            raise ValueError(f"PrefilteredEnvironment.lookup: world_to_map must be a finite (3, 3) rotation, got {rot.shape}")
        return rot

    def lookup_hat(self, p, lam, world_to_map=None) -> np.ndarray:
        """Normalised ``Gamma_hat(p, lambda) = Gamma / integral(G)``, (N, 3) float64 (see :meth:`lookup`)."""
        d, lam = self._query(p, lam, world_to_map)
        return self._hat(d, lam)

    def lookup(self, p, lam, world_to_map=None) -> np.ndarray:
        """``Gamma_L(p, lambda)``, (N, 3) float64: the kernel's arithmetic (module docstring) in float64.

        Args:
            p: lobe axes, world frame, (N, 3) (normalised here).
            lam: sharpness, (N,) or a scalar, >= 0.
            world_to_map: rotation (3, 3) from world to the map frame (default: the build's).
        """
        d, lam = self._query(p, lam, world_to_map)
        return self._hat(d, lam) * sg.integral(lam)[:, None]

    def _query(self, p, lam, world_to_map):
        p = np.asarray(p, np.float64).reshape(-1, 3)
        lam = np.broadcast_to(np.asarray(lam, np.float64), (p.shape[0],)).copy()
        if not np.all(np.isfinite(p)) or not np.all(np.isfinite(lam)) or np.any(lam < 0.0):
            raise ValueError("PrefilteredEnvironment.lookup: p must be finite and lam finite and >= 0")
        d = p @ self._rotation(world_to_map).T
        norm = np.linalg.norm(d, axis=1, keepdims=True)
        if np.any(norm <= 0.0):
            raise ValueError("PrefilteredEnvironment.lookup: p has zero-length directions")
        return d / norm, lam

    def _hat(self, d, lam) -> np.ndarray:
        lv = self.levels
        out = np.zeros((d.shape[0], 3))
        last = lv.size - 1
        low = lam <= lv[0]
        high = (lam >= lv[-1]) & ~low
        mid = ~low & ~high
        if low.any():
            t = (lam[low] / lv[0])[:, None]
            out[low] = (1 - t) * self.mean[None] + t * bilinear_map(self.maps[0], d[low])
        if high.any():
            s = np.sqrt(lv[-1] / lam[high])[:, None]
            out[high] = s * bilinear_map(self.maps[last], d[high]) + (1 - s) * bilinear_map(self.maps[last + 1], d[high])
        if mid.any():
            ll = np.log(lam[mid])
            log_lv = np.log(lv)
            k = np.clip(np.searchsorted(log_lv, ll, side="right") - 1, 0, max(last - 1, 0))
            t = np.clip((ll - log_lv[k]) / (log_lv[k + 1] - log_lv[k]), 0.0, 1.0)[:, None]
            dm = d[mid]
            res = np.zeros((dm.shape[0], 3))
            for kk in np.unique(k):
                sel = k == kk
                a = np.maximum(bilinear_map(self.maps[kk], dm[sel]), 0.0)
                b = np.maximum(bilinear_map(self.maps[kk + 1], dm[sel]), 0.0)
                res[sel] = np.power(a, 1 - t[sel]) * np.power(b, t[sel])
            out[mid] = res
        return out

    # ---- device ------------------------------------------------------------------------------
    def to_device(self, device=None):
        """Upload as a :class:`._lighting_warp.PrefilteredTable` (float32) on ``device``."""
        from ..._wp import resolve_device, wp
        from ._lighting_warp import PrefilteredTable

        dev = resolve_device(device)
        arr = self.arrays()
        sizes = arr["heights"] * arr["widths"]
        table = PrefilteredTable()
        table.data = wp.array(arr["data"], dtype=wp.vec3, device=dev)
        table.offset = wp.array(np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int32), dtype=wp.int32, device=dev)
        table.height = wp.array(arr["heights"].astype(np.int32), dtype=wp.int32, device=dev)
        table.width = wp.array(arr["widths"].astype(np.int32), dtype=wp.int32, device=dev)
        table.log_lambda = wp.array(np.log(self.levels).astype(np.float32), dtype=float, device=dev)
        table.level_count = self.level_count
        table.lambda_first = float(self.levels[0])
        table.lambda_last = float(self.levels[-1])
        table.mean = wp.vec3(*np.asarray(self.mean, np.float32))
        return table

    def lookup_device(self, p, lam, world_to_map=None, device=None, table=None) -> np.ndarray:
        """Host helper: :func:`._lighting_warp.gamma_lookup` at (N, 3) world axes -> (N, 3) float32."""
        from ..._wp import resolve_device, wp
        from ._lighting_warp import gamma_lookup_kernel

        dev = resolve_device(device)
        p = np.asarray(p, np.float32).reshape(-1, 3)
        lam = np.broadcast_to(np.asarray(lam, np.float32), (p.shape[0],))
        rot = self._rotation(world_to_map)
        table = self.to_device(dev) if table is None else table
        dirs = wp.array(p, dtype=wp.vec3, device=dev)
        lams = wp.array(np.ascontiguousarray(lam), dtype=float, device=dev)
        out = wp.empty(p.shape[0], dtype=wp.vec3, device=dev)
        wp.launch(gamma_lookup_kernel, dim=p.shape[0],
                  inputs=[table, wp.mat33(*rot.astype(np.float32).reshape(-1)), dirs, lams, out], device=dev)
        return out.numpy()


def gamma_f64(env, p, lam) -> np.ndarray:
    """Float64 oracle of ``Gamma_L(p, lambda)`` by direct quadrature over every texel (no
    truncation): each texel is split into ``n x n`` cells of exact solid angle (n even, at least 2,
    such that a cell is at most 1/5 of the lobe width, at most 24) and ``Environment.radiance``
    (bilinear) is evaluated at each cell centre, which integrates the bilinear radiance exactly
    where the lobe is constant over a cell.

    Args:
        env: the environment (its ``to_world`` places it in the world).
        p: lobe axes, world frame, (N, 3).
        lam: sharpness, (N,) or a scalar, >= 0.

    Returns:
        (N, 3) float64.
    """
    check_environment(env, "gamma_f64")
    p = np.asarray(p, np.float64).reshape(-1, 3)
    p = p / np.linalg.norm(p, axis=1, keepdims=True)
    lam = np.broadcast_to(np.asarray(lam, np.float64), (p.shape[0],))
    h, w = env.height, env.width
    texel = math.pi / h
    # even cell counts: the mid-points then integrate the bilinear radiance exactly per cell
    subs = np.array([int(min(REFERENCE_MAX_SUBDIVISION,
                             2 * math.ceil(REFERENCE_CELLS_PER_SIGMA * texel * math.sqrt(max(l, 1e-12)) / 2.0)))
                     for l in lam])
    out = np.zeros((p.shape[0], 3))
    for n in np.unique(subs):
        hh, ww = h * int(n), w * int(n)
        q = quadrature.latlong(hh, ww)
        dirs_world = q.directions @ np.asarray(env.to_world, np.float64).T
        values = env.radiance(dirs_world) * q.weights[:, None]
        for i in np.nonzero(subs == n)[0]:
            g = np.exp(-0.5 * lam[i] * np.sum((dirs_world - p[i]) ** 2, axis=1))
            out[i] = g @ values
    return out
