"""The SG/SSDF method's artifacts: per-vertex SSDF visibility (PCA), and the lighting prepared from
an environment (an SG mixture for the diffuse term, the prefiltered table for the specular term).

* :func:`bake_ssdf_model` -- ray-traced hemisphere visibility per vertex, turned into signed angular
  distances and compressed by PCA with the term count chosen from an error budget
  (:mod:`warpshade.transfer._ssdf`); cached by the graph as the artifact of ``sg.ssdf``;
* :func:`decode_maps` -- the PCA expanded back to ``(V, R, R)`` maps at set-up (what the per-frame
  kernels fetch from; ``ssdf = "pca"`` keeps the coefficients instead);
* :func:`environment_lighting` -- the environment's SG mixture and prefiltered table, built once per
  environment image and settings (an in-process cache, so a run that swaps lighting back and
  forth builds each once).
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass

import numpy as np

from ...transfer import SSDFModel, bake_ssdf, compress_ssdf
from ._envfit import fit_environment
from ._prefilter import PrefilteredEnvironment

__all__ = [
    "SUN_MODES",
    "split_sun",
    "empty_table",
    "environment_hash",
    "remember",
]


def bake_ssdf_model(scene, frame, resolution: int, supersample: int, error_budget: float, max_terms: int, device=None,
                    progress=None) -> SSDFModel:
    """SSDFs of every vertex at ``frame`` (``resolution`` x ``resolution`` maps from a map
    ``supersample`` times finer), compressed to the fewest PCA terms within ``error_budget``
    (RMS radians)."""
    maps = bake_ssdf(scene, frame, resolution=resolution, supersample=supersample, device=device, progress=progress)
    return compress_ssdf(maps, error_budget=error_budget, max_terms=max_terms)


def decode_maps(model: SSDFModel) -> np.ndarray:
    """The PCA reconstruction of every vertex's map, shape (V, R, R), float32 (radians)."""
    r = int(model.resolution)
    flat = model.coeffs.astype(np.float32) @ model.basis.astype(np.float32) + model.mean.astype(np.float32)[None]
    return np.ascontiguousarray(flat.reshape(-1, r, r), dtype=np.float32)


@dataclass
class EnvironmentLighting:
    """An environment prepared for the kernels (map frame).

    Attributes:
        mixture: the RGB SG mixture of the diffuse term (:class:`~warpshade.basis.sg.SGMixture`).
        table: the :class:`~warpshade.methods.sg._prefilter.PrefilteredEnvironment` (eq. 35).
        fit: what the fit reports (lobe count, errors); build_s: seconds spent building both;
        image_hash: content hash of the environment image it was built from.
    """

    mixture: object
    table: object
    fit: dict
    build_s: float
    image_hash: str
    sun: object = None

    @property
    def sun_lobes(self) -> tuple:
        """(axes (S, 3), sharpness (S,), amplitude (S, 3)) of the suns taken out of the image (map
        frame; S = 0 when none)."""
        if self.sun is None:
            return np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3))
        return self.sun.axes, self.sun.sharpness, np.asarray(self.sun.amplitude, np.float64).reshape(-1, 3)

    def arrays(self) -> dict:
        """Plain arrays for the graph cache (``sg.environment``)."""
        out = {f"table_{k}": v for k, v in self.table.arrays().items()}
        sun_axes, sun_sharpness, sun_amplitude = self.sun_lobes
        out.update({"sun_axes": sun_axes, "sun_sharpness": sun_sharpness, "sun_amplitude": sun_amplitude})
        out.update({"axes": self.mixture.axes, "sharpness": self.mixture.sharpness,
                    "amplitude": np.asarray(self.mixture.amplitude, np.float64).reshape(-1, 3),
                    "image_hash": np.frombuffer(bytes.fromhex(self.image_hash), np.uint8).copy(),
                    "fit_errors": np.array([self.fit.get("irradiance_fit_error", -1.0), self.fit.get("irradiance_error", -1.0),
                                            self.fit.get("radiance_error", -1.0)], np.float64),
                    "build_s": np.array([self.build_s])})
        return out

    @classmethod
    def from_arrays(cls, arrays) -> "EnvironmentLighting":
        """Rebuild from :meth:`arrays`, checking every entry (ValueError naming the bad one)."""
        from ...basis.sg import SGMixture

        for key in ("axes", "sharpness", "amplitude", "image_hash", "fit_errors", "build_s"):
            if key not in arrays:
                raise ValueError(f"EnvironmentLighting.from_arrays: missing entry {key!r}")
        table = PrefilteredEnvironment.from_arrays({k[6:]: v for k, v in arrays.items() if k.startswith("table_")})
        axes = np.asarray(arrays["axes"], np.float64)
        amp = np.asarray(arrays["amplitude"], np.float64)
        if axes.ndim != 2 or axes.shape[1] != 3 or not np.all(np.isfinite(axes)) or not np.all(np.isfinite(amp)) or np.any(amp < 0):
            raise ValueError("EnvironmentLighting.from_arrays: entries 'axes'/'amplitude' must be finite (K, 3), amplitudes >= 0")
        mixture = SGMixture(axes, np.asarray(arrays["sharpness"], np.float64), amp)
        errors = np.asarray(arrays["fit_errors"], np.float64).reshape(-1)
        fit = {"lobe_count": mixture.lobe_count, "irradiance_fit_error": float(errors[0]), "irradiance_error": float(errors[1]),
               "radiance_error": float(errors[2])}
        sun = None
        if "sun_axes" in arrays and np.asarray(arrays["sun_axes"]).size:
            sun = SGMixture(np.asarray(arrays["sun_axes"], np.float64), np.asarray(arrays["sun_sharpness"], np.float64),
                            np.asarray(arrays["sun_amplitude"], np.float64).reshape(-1, 3))
        return cls(mixture, table, fit, float(np.asarray(arrays["build_s"]).reshape(-1)[0]),
                   bytes(np.asarray(arrays["image_hash"], np.uint8)).hex(), sun)


_CACHE: dict = {}


def environment_hash(env) -> str:
    """Content hash of an environment's image (what its SG fit and table depend on)."""
    h = hashlib.sha256(np.ascontiguousarray(env.image, np.float32).tobytes())
    h.update(repr(env.image.shape).encode())
    return h.hexdigest()


#: Sun handling of :func:`environment_lighting`: left in the image (the paper) or taken out as lobes.
SUN_MODES = ("keep", "separate")
#: A sun is taken out when the image's peak luminance exceeds this many times its median.
SUN_PEAK_RATIO = 1000.0
#: Texels within this angle of the peak and above SUN_TEXEL_FRACTION of its luminance belong to the sun.
SUN_RADIUS_DEG = 6.0
SUN_TEXEL_FRACTION = 1e-3


def split_sun(env):
    """Take a small, very bright sun out of an environment image (map frame).

    The sun is the set of texels within :data:`SUN_RADIUS_DEG` of the brightest texel whose
    luminance exceeds :data:`SUN_TEXEL_FRACTION` of its peak, present only when the peak is more
    than :data:`SUN_PEAK_RATIO` times the median. Its texels are replaced by the mean of the ring
    around them; what they carried above it (radiance times solid angle, per channel) becomes one
    SG lobe about the energy-weighted mean direction with the sharpness of eq. 33 for its solid
    angle (``f_a^-1(2 Omega)``) and the amplitude that integrates to that energy.

    Returns:
        (residual Environment, an SGMixture of one lobe with RGB amplitude), or (env, None) without a sun.
    """
    from ...basis import quadrature
    from ...basis.sg import SGMixture, integral, sharpness_for_area

    img = np.asarray(env.image, np.float64)
    h, w = img.shape[:2]
    lum = img @ np.array([0.2126, 0.7152, 0.0722])
    peak = float(lum.max())
    median = float(np.median(lum))
    if peak <= 0.0 or peak < SUN_PEAK_RATIO * max(median, 1e-30):
        return env, None
    q = quadrature.latlong(h, w)
    dirs = q.directions.reshape(h, w, 3)
    solid = q.weights.reshape(h, w)
    i, j = np.unravel_index(int(np.argmax(lum)), lum.shape)
    cos_to_peak = dirs @ dirs[i, j]
    near = cos_to_peak >= np.cos(np.radians(SUN_RADIUS_DEG))
    sun = near & (lum >= SUN_TEXEL_FRACTION * peak)
    ring = near & ~sun
    background = img[ring].mean(axis=0) if ring.any() else np.zeros(3)
    excess = np.clip(img[sun] - background[None], 0.0, None)  # (n, 3)
    energy = (excess * solid[sun][:, None]).sum(axis=0)
    weights = (excess @ np.array([0.2126, 0.7152, 0.0722])) * solid[sun]
    axis = (dirs[sun] * weights[:, None]).sum(axis=0)
    axis /= np.linalg.norm(axis)
    omega = float(solid[sun].sum())
    lam = float(sharpness_for_area(2.0 * omega))
    residual = img.copy()
    residual[sun] = background[None]
    lobe = SGMixture(axis[None], np.array([lam]), (energy / float(integral(lam)))[None])
    return type(env)(residual.astype(np.float32), env.to_world, env.path), lobe


def environment_lighting(env, lobes: int, error_budget, method: str, device=None, progress=None,
                         sun: str = "separate") -> EnvironmentLighting:
    """The SG mixture (at most ``lobes`` lobes, fewer when ``error_budget`` allows) and the
    prefiltered table of ``env`` (in its map frame), built once per image and settings in a
    process (the graph caches them on disk as the artifact of ``sg.environment``). With
    ``sun = "separate"`` (default; ``"keep"`` is the paper's way) a small, very bright sun is first taken out as a lobe
    (:func:`split_sun`): it is then shaded as a distant light (eq. 42-43, visibility looked up
    at the sun's own direction) instead of through the table (eq. 41, the visibility of the whole
    BRDF lobe), and the rest of the sky goes to the mixture and the table."""
    if sun not in SUN_MODES:
        raise ValueError(f"environment_lighting: sun must be one of {SUN_MODES}, got {sun!r}")
    image_hash = environment_hash(env)
    key = (image_hash, lobes, error_budget, method, sun)
    hit = _CACHE.get(key)
    if hit is not None:
        return hit
    t0 = time.perf_counter()
    # fitted in the map frame: the frame's map-to-world rotation is applied per frame on the device
    local = type(env)(env.image, np.eye(3), env.path)
    sun_lobe = None
    if sun == "separate":
        local, sun_lobe = split_sun(local)
    fit = fit_environment(local, max_lobes=lobes, error_budget=error_budget, method=method)
    table = PrefilteredEnvironment.build(local, device=device, progress=_level_progress(progress))
    out = EnvironmentLighting(fit.mixture, table, dict(fit.report), time.perf_counter() - t0, image_hash, sun_lobe)
    _CACHE[key] = out
    return out


def _level_progress(progress):
    """A ``(done, total)`` callable for the table build: ``progress`` itself when callable, a tqdm
    bar when true, else None."""
    if progress is None or progress is False:
        return None
    if callable(progress):
        return progress
    from ...tasks import progress_bar

    bar = {}

    def update(done, total):
        if "bar" not in bar:
            bar["bar"] = progress_bar(total=total, desc="SG environment table", unit="level", leave=False)
        bar["bar"].update(done - bar["bar"].n)
        if done >= total:
            bar["bar"].close()

    return update


def remember(lighting: EnvironmentLighting, lobes: int, error_budget, method: str, sun: str = "separate") -> None:
    """Keep an environment read from the graph cache for in-process reuse."""
    _CACHE.setdefault((lighting.image_hash, lobes, error_budget, method, sun), lighting)


_EMPTY: dict = {}


def empty_table(device):
    """A black prefiltered table (no environment in the run), one per device."""
    from ...scene._lighting import Environment

    key = str(device)
    if key not in _EMPTY:
        black = Environment.constant((0.0, 0.0, 0.0), height=4, width=8)
        _EMPTY[key] = PrefilteredEnvironment.build(black, levels=np.array([1.0, 2.0]), device=device).to_device(device)
    return _EMPTY[key]

