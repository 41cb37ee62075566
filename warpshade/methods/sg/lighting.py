"""SG lighting (Wang et al. 2009, sec. 6): the environment as a few SG lobes for the diffuse term,
the prefiltered environment ``Gamma_L(p, lambda)`` for the specular term, and sphere / distant
lights as single SG lobes. Float64 fitting, tables and oracles; the kernels are in
:mod:`.lighting_warp`.

**Diffuse environment** (:func:`fit_environment`). The paper fits "a few lobes (< 10)"
preserving the brightest areas. Candidates are lobes with axes on a spherical Fibonacci set
plus the brightest texels, at sharpness values from 0.5 up to what the fit grid resolves
(``1 / texel_angle^2``). The objective is the squared radiance error over the sphere plus the
squared error of the irradiance (the radiance convolved with the exact clamped cosine) over a
set of normals, each normalised by its target's norm; both are linear in the amplitudes. Lobes
are chosen greedily (the candidate that most reduces the objective with a non-negative
amplitude is added, then all amplitudes are re-solved per channel by ``scipy.optimize.nnls``).
``method="lbfgsb"`` then refines axes, sharpness and amplitudes jointly
(``scipy.optimize.minimize(method="L-BFGS-B")``, analytic gradient, sharpness as its log within
bounds, amplitudes >= 0). The report carries, on the full-resolution map: the relative L2
radiance error, the relative RMS (and max) irradiance error of the mixture by exact quadrature
(``irradiance_fit_error``: the lighting fit alone) and the irradiance the renderer computes --
``sum_k inner_product(lobe_k, clamped-cosine SG)`` (eq. 39-40) -- against exact quadrature of
the environment times ``max(0, n.s)`` (``irradiance_error``, which also holds the single-lobe
clamped cosine's own error: 8 % on a constant sky with the paper's lobe).

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
* Lookup (:meth:`PrefilteredEnvironment.lookup`, :func:`.lighting_warp.gamma_lookup`, same
  arithmetic): bilinear within a map; between levels linear in ``log lambda`` of
  ``log Gamma_hat`` (geometric), exact for a uniform region (constant) and for a source much
  smaller than the lobe (``Gamma_hat`` proportional to ``lambda``), where linear interpolation
  of ``Gamma`` would be off by 6 % halfway; below the first level linear in ``lambda`` from the
  mean radiance (so ``Gamma(p, 0)`` is exactly the environment's integral); beyond the last
  level linear in the lobe width ``sqrt(lambda_last / lambda)`` towards the environment's own
  bilinear radiance, the exact limit ``Gamma -> L(p) integral(G)``. The result is
  ``Gamma_hat * integral(G)``. Directions are world directions with a world->map rotation, so a
  turning sky only changes that matrix.

**Local lights** (eq. 32-33): :func:`point_light_lobe` (sphere lights) and
:func:`directional_light_lobe`, normalised so that a lobe integrates to the light's radiance times
its solid angle (the ray-traced reference's emission); :func:`inside_hull` detects a point light
inside an object's convex hull (precomputed visibility covers distant light only).
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from ...basis import quadrature, sg
from ...scene.lighting import DistantLight, Environment, SphereLight

__all__ = [
    "CANDIDATE_BRIGHTEST",
    "CANDIDATE_FIBONACCI",
    "EnvironmentSG",
    "FIT_HEIGHT",
    "FIT_METHODS",
    "FIT_NORMALS",
    "MAX_DIFFUSE_LOBES",
    "MIN_DISTANT_ANGLE_DEG",
    "OUTPUT_TEXELS_PER_SIGMA",
    "PrefilteredEnvironment",
    "SOURCE_TEXELS_PER_SIGMA",
    "SUPPORT_THRESHOLD",
    "default_levels",
    "directional_light_lobe",
    "environment_integral",
    "fit_environment",
    "gamma_reference",
    "inside_hull",
    "point_light_lobe",
]

#: "Fewer than 10" lobes for the diffuse environment (sec. 6).
MAX_DIFFUSE_LOBES = 9
#: Height of the map the diffuse fit runs on (the environment's mip chain entry at or below it).
FIT_HEIGHT = 64
#: Normals (spherical Fibonacci) over which irradiance is fitted and measured.
FIT_NORMALS = 256
#: Candidate lobe axes: Fibonacci directions, and the brightest texels of the fit map.
CANDIDATE_FIBONACCI = 96
CANDIDATE_BRIGHTEST = 16
#: Diffuse fit methods.
FIT_METHODS = ("nnls", "lbfgsb")
#: Budget metrics accepted by :func:`fit_environment`.
BUDGET_METRICS = ("irradiance_fit", "irradiance", "radiance")
#: Smallest sharpness L-BFGS-B may reach (a lobe this broad is nearly constant).
MIN_FIT_SHARPNESS = 0.05

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
#: Sub-cells per lobe width of :func:`gamma_reference` (finer than the kernel's).
REFERENCE_CELLS_PER_SIGMA = 5.0
REFERENCE_MAX_SUBDIVISION = 24

#: Angular diameter (degrees) a DistantLight of ``angle_deg`` below it is given: a delta light has
#: no finite SG. 0.53 deg is the sun's (and DistantLight's default); its sharpness ~1.2e5 keeps the
#: float32 exponent of an SG product within 1e-2 (lambda * float32 epsilon).
MIN_DISTANT_ANGLE_DEG = 0.53

_FORMAT_VERSION = 1


# ------------------------------------------------------------------------------------------------
# environment helpers


def _check_environment(env, where: str) -> np.ndarray:
    if not isinstance(env, Environment):
        raise ValueError(f"{where}: env must be a warpshade.scene.lighting.Environment, got {type(env).__name__}")
    img = np.asarray(env.image, np.float64)
    name = env.path or "<array>"
    if not np.all(np.isfinite(img)):
        raise ValueError(f"{where}: environment {name} has NaN or infinite texels")
    if np.any(img < 0.0):
        count = int(np.count_nonzero(np.any(img < 0.0, axis=-1)))
        raise ValueError(f"{where}: environment {name} has {count} texels with negative radiance (min {img.min():.3g})")
    return img


def _row_weights(height: int, width: int) -> np.ndarray:
    """Exact solid angle of one texel in each row, (H,) (as :func:`quadrature.latlong`)."""
    return quadrature.latlong(height, width).weights.reshape(height, width)[:, 0]


def _mip_chain(image: np.ndarray) -> list[np.ndarray]:
    """The map and its 2x2 solid-angle weighted means while both sides are even (float64).

    A coarse texel's solid angle is the sum of its four children's, so each level's quadrature
    ``sum L w`` equals the full map's exactly."""
    chain = [np.asarray(image, np.float64)]
    while chain[-1].shape[0] % 2 == 0 and chain[-1].shape[1] % 2 == 0 and chain[-1].shape[0] >= 2:
        img = chain[-1]
        h, w = img.shape[:2]
        rw = _row_weights(h, w)
        pair = img[:, 0::2] + img[:, 1::2]  # (h, w/2, 3)
        top, bottom = pair[0::2], pair[1::2]
        wt, wb = rw[0::2, None, None], rw[1::2, None, None]
        chain.append((wt * top + wb * bottom) / (2.0 * (wt + wb)))
    return chain


def _cell_means(image: np.ndarray) -> np.ndarray:
    """Mean of the bilinear radiance over each texel: ``[1, 6, 1] / 8`` along rows and columns
    (the mean of a piecewise-linear interpolant over a cell centred on a node), rows clamped at
    the poles and azimuth wrapped as ``Environment.radiance`` does. Float64 (H, W, 3)."""
    img = np.asarray(image, np.float64)
    up = np.concatenate([img[:1], img[:-1]])
    down = np.concatenate([img[1:], img[-1:]])
    img = (up + 6.0 * img + down) / 8.0
    return (np.roll(img, 1, axis=1) + 6.0 * img + np.roll(img, -1, axis=1)) / 8.0


def _source_chain(image: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Sources of the prefilter sums: ``(radiance (H, W, 3), direction (H, W, 3))`` per mip.

    The finest is the texel means of the bilinear radiance at the texel centres; each coarser
    one holds the solid-angle weighted 2x2 means and, as its direction, the luminance-weighted
    centroid of its children's directions, so a bright source smaller than a coarse texel (a
    sun) keeps its position instead of moving to the texel centre."""
    rec709 = np.array([0.2126, 0.7152, 0.0722])
    means = _cell_means(image)
    h, w = means.shape[:2]
    out = [(means, quadrature.latlong_directions(h, w))]
    for img in _mip_chain(means)[1:]:
        fine, fine_dirs = out[-1]
        fh, fw = fine.shape[:2]
        rw = _row_weights(fh, fw)[:, None]
        mass = (np.maximum(fine @ rec709, 0.0) + 1e-9 * max(float(fine.max()), 1e-300)) * rw
        moment = mass[..., None] * fine_dirs
        summed = moment[0::2, 0::2] + moment[0::2, 1::2] + moment[1::2, 0::2] + moment[1::2, 1::2]
        dirs = summed / np.maximum(np.linalg.norm(summed, axis=-1, keepdims=True), 1e-300)
        out.append((img, dirs))
    return out


def environment_integral(env) -> np.ndarray:
    """``sum_texels L w`` (exact texel solid angles), RGB (3,): the integral of the map over the
    sphere, which ``Gamma(p, 0)`` equals."""
    img = _check_environment(env, "environment_integral")
    rw = _row_weights(env.height, env.width)
    return np.einsum("hwc,h->c", img, rw)


def _subdivided(image: np.ndarray, sub: int) -> tuple[np.ndarray, np.ndarray]:
    """The bilinear radiance at the centres of a ``sub``-times finer lat-long grid (each texel
    split into ``sub x sub`` cells equal in theta and phi), with those centres' directions."""
    h, w = image.shape[:2]
    dirs = quadrature.latlong_directions(h * sub, w * sub)
    values = _bilinear_map(image, dirs.reshape(-1, 3)).reshape(h * sub, w * sub, 3)
    return values, dirs


def _fit_map(img: np.ndarray, fit_height: int) -> np.ndarray:
    for level in _mip_chain(img):
        if level.shape[0] <= fit_height:
            return level
    return _mip_chain(img)[-1]


def _texels(level: np.ndarray):
    h, w = level.shape[:2]
    q = quadrature.latlong(h, w)
    return q.directions, q.weights, level.reshape(-1, 3)


def _irradiance_quadrature(normals, dirs, weights, values, chunk: int = 16384) -> np.ndarray:
    """``sum_s max(0, n.s) w_s L_s`` for each normal, (N, C), chunked over texels."""
    out = np.zeros((normals.shape[0], values.shape[1]))
    for a in range(0, dirs.shape[0], chunk):
        cosv = np.maximum(normals @ dirs[a:a + chunk].T, 0.0)
        out += cosv @ (weights[a:a + chunk, None] * values[a:a + chunk])
    return out


def _rel(err: np.ndarray, ref: np.ndarray) -> float:
    den = float(np.sqrt(np.sum(ref * ref)))
    return float(np.sqrt(np.sum(err * err)) / den) if den > 0.0 else float(np.sqrt(np.sum(err * err)))


# ------------------------------------------------------------------------------------------------
# diffuse fit


@dataclass
class EnvironmentSG:
    """An environment as an RGB SG mixture for the diffuse term.

    Attributes:
        mixture: lobes in the world frame (the environment's ``to_world`` applied): axes (K, 3),
            sharpness (K,), amplitude (K, 3) linear RGB radiance, float64.
        report: the fit's record: ``method``, ``lobe_count``, ``error_budget``, ``budget_metric``,
            ``budget_met``, ``radiance_error``, ``irradiance_error`` (SG clamped cosine, as the
            renderer), ``irradiance_error_max``, ``irradiance_fit_error`` (exact quadrature of the
            mixture), ``fit_shape``, ``cosine``, ``fit_s`` and ``by_lobe_count`` (the same errors
            for every lobe count tried).
    """

    mixture: sg.SGMixture
    report: dict = field(default_factory=dict)

    @property
    def lobe_count(self) -> int:
        return self.mixture.lobe_count

    def rotated(self, rotation) -> "EnvironmentSG":
        """The mixture turned by a world rotation (3, 3) (a rotating sky, eq. 7)."""
        return EnvironmentSG(self.mixture.rotated(rotation), dict(self.report))

    def irradiance(self, normals, cosine: str = "paper") -> np.ndarray:
        """``sum_k inner_product(lobe_k, clamped_cosine(n))`` (eq. 39-40 unshadowed), (N, 3).

        Args:
            normals: unit world normals (N, 3).
            cosine: clamped-cosine lobe, ``"paper"`` or ``"l2"`` (:func:`warpshade.basis.sg.clamped_cosine`).
        """
        return _sg_irradiance(self.mixture, np.asarray(normals, np.float64).reshape(-1, 3), cosine)

    def arrays(self) -> dict:
        return {"axes": self.mixture.axes, "sharpness": self.mixture.sharpness, "amplitude": self.mixture.amplitude}


def _sg_irradiance(mixture: sg.SGMixture, normals: np.ndarray, cosine: str) -> np.ndarray:
    n, lam_c, mu_c = sg.clamped_cosine(normals, cosine)
    w = sg.inner_product(mixture.axes[None], mixture.sharpness[None], 1.0, n[:, None], lam_c[:, None], mu_c[:, None])
    return w @ mixture.amplitude


def _mixture_values(axes, lam, amp, dirs) -> np.ndarray:
    return np.exp(lam * (dirs @ axes.T - 1.0)) @ amp


class _FitProblem:
    """The linear least-squares problem of the diffuse fit on the fit map (float64)."""

    def __init__(self, level: np.ndarray, irradiance_weight: float):
        self.dirs, self.weights, self.values = _texels(level)
        self.normals = quadrature.fibonacci(FIT_NORMALS).directions
        self.cw = np.maximum(self.normals @ self.dirs.T, 0.0) * self.weights[None, :]
        self.target_e = self.cw @ self.values
        self.beta = float(irradiance_weight)
        self.s_r2 = max(float(np.sum(self.weights[:, None] * self.values ** 2)), 1e-300)
        self.s_e2 = max(float(np.sum(self.target_e ** 2)), 1e-300)
        h = level.shape[0]
        self.max_sharpness = 1.0 / (math.pi / h) ** 2

    def candidates(self):
        lams = [LEVEL_FIRST]
        while lams[-1] * 2.0 < self.max_sharpness:
            lams.append(lams[-1] * 2.0)
        lams.append(self.max_sharpness)
        lum = self.values @ np.array([0.2126, 0.7152, 0.0722])
        bright = self.dirs[np.argsort(lum)[::-1][:CANDIDATE_BRIGHTEST]]
        axes = np.concatenate([quadrature.fibonacci(CANDIDATE_FIBONACCI).directions, bright])
        cand_axes = np.repeat(axes, len(lams), axis=0)
        cand_lams = np.tile(np.asarray(lams), axes.shape[0])
        return cand_axes, cand_lams

    def design(self, axes, lams):
        g = np.exp(lams[None, :] * (self.dirs @ axes.T - 1.0))  # (T, M)
        top = np.sqrt(self.weights)[:, None] * g / math.sqrt(self.s_r2)
        bottom = math.sqrt(self.beta) * (self.cw @ g) / math.sqrt(self.s_e2)
        return np.concatenate([top, bottom])

    def rhs(self):
        top = np.sqrt(self.weights)[:, None] * self.values / math.sqrt(self.s_r2)
        bottom = math.sqrt(self.beta) * self.target_e / math.sqrt(self.s_e2)
        return np.concatenate([top, bottom])  # (rows, 3)

    def loss_and_grad(self, params, k, scale):
        a = params[:3 * k].reshape(k, 3)
        ll = params[3 * k:4 * k]
        x = params[4 * k:].reshape(k, 3)
        norm = np.maximum(np.linalg.norm(a, axis=1), 1e-300)
        p = a / norm[:, None]
        lam = np.exp(ll)
        mu = x * scale[:, None]
        cosv = self.dirs @ p.T
        g = np.exp(lam[None, :] * (cosv - 1.0))
        f = g @ mu
        rr = f - self.values
        re = self.cw @ f - self.target_e
        loss = float(np.sum(self.weights[:, None] * rr * rr) / self.s_r2 + self.beta * np.sum(re * re) / self.s_e2)
        gf = 2.0 * self.weights[:, None] * rr / self.s_r2 + 2.0 * self.beta * (self.cw.T @ re) / self.s_e2
        d_mu = g.T @ gf
        m = (gf @ mu.T) * g
        d_lam = np.sum(m * (cosv - 1.0), axis=0)
        d_p = lam[:, None] * (m.T @ self.dirs)
        d_a = (d_p - p * np.sum(p * d_p, axis=1, keepdims=True)) / norm[:, None]
        grad = np.concatenate([d_a.reshape(-1), d_lam * lam, (d_mu * scale[:, None]).reshape(-1)])
        return loss, grad


def _greedy_nnls(problem: _FitProblem, max_lobes: int):
    """Yield (axes, sharpness, amplitude (K, 3)) for K = 1 .. max_lobes (greedy selection)."""
    from scipy.optimize import nnls

    cand_axes, cand_lams = problem.candidates()
    a = problem.design(cand_axes, cand_lams)
    b = problem.rhs()
    col_norm2 = np.maximum(np.sum(a * a, axis=0), 1e-300)
    selected: list[int] = []
    residual = b.copy()
    for _ in range(max_lobes):
        corr = np.maximum(a.T @ residual, 0.0)  # (M, 3)
        score = np.sum(corr * corr, axis=1) / col_norm2
        score[selected] = -1.0
        best = int(np.argmax(score))
        if score[best] <= 0.0:
            break  # nothing left that a non-negative lobe can reduce
        selected.append(best)
        sub = a[:, selected]
        amp = np.stack([nnls(sub, b[:, c], maxiter=50 * len(selected))[0] for c in range(3)], axis=1)
        residual = b - sub @ amp
        yield cand_axes[selected].copy(), cand_lams[selected].copy(), amp


def _refine_lbfgsb(problem: _FitProblem, axes, lams, amp):
    from scipy.optimize import minimize

    k = axes.shape[0]
    scale = np.maximum(amp.max(axis=1), 1e-12 * max(float(amp.max()), 1e-300))
    scale = np.where(scale > 0.0, scale, 1.0)
    x0 = np.concatenate([axes.reshape(-1), np.log(lams), (amp / scale[:, None]).reshape(-1)])
    bounds = ([(None, None)] * (3 * k) + [(math.log(MIN_FIT_SHARPNESS), math.log(problem.max_sharpness))] * k
              + [(0.0, None)] * (3 * k))
    res = minimize(problem.loss_and_grad, x0, args=(k, scale), jac=True, method="L-BFGS-B", bounds=bounds,
                   options={"maxiter": 3000, "ftol": 1e-15, "gtol": 1e-12})
    p = res.x
    a = p[:3 * k].reshape(k, 3)
    return (a / np.linalg.norm(a, axis=1, keepdims=True), np.exp(p[3 * k:4 * k]),
            p[4 * k:].reshape(k, 3) * scale[:, None], res)


def _metrics(axes, lams, amp, full, normals, e_true, cosine) -> dict:
    dirs, weights, values = full
    f = _mixture_values(axes, lams, amp, dirs)
    rad = _rel(np.sqrt(weights)[:, None] * (f - values), np.sqrt(weights)[:, None] * values)
    mixture = sg.SGMixture(axes, lams, amp)
    e_sg = _sg_irradiance(mixture, normals, cosine)
    e_fit = _irradiance_quadrature(normals, dirs, weights, f)
    per_normal = np.linalg.norm(e_sg - e_true, axis=1) / np.maximum(np.linalg.norm(e_true, axis=1), 1e-300)
    return {
        "lobe_count": int(axes.shape[0]),
        "radiance_error": rad,
        "irradiance_error": _rel(e_sg - e_true, e_true),
        "irradiance_error_max": float(per_normal.max()),
        "irradiance_fit_error": _rel(e_fit - e_true, e_true),
    }


def fit_environment(env, max_lobes: int = MAX_DIFFUSE_LOBES, error_budget: float | None = None,
                    method: str = "nnls", device=None, *, budget_metric: str = "irradiance_fit",
                    cosine: str = "paper", irradiance_weight: float = 1.0,
                    fit_height: int = FIT_HEIGHT) -> EnvironmentSG:
    """Fit an environment with fewer than 10 RGB SG lobes for the diffuse term (module docstring).

    Args:
        env: :class:`~warpshade.scene.lighting.Environment` (finite, non-negative radiance).
        max_lobes: most lobes, 1 .. :data:`MAX_DIFFUSE_LOBES`.
        error_budget: when given, the smallest lobe count (in the greedy order) whose
            ``budget_metric`` error is at most this (relative); the report says whether it was met.
            Without it, ``max_lobes`` lobes are fitted (fewer if further lobes cannot help).
        method: ``"nnls"`` (greedy selection + non-negative least squares) or ``"lbfgsb"``
            (that, then a joint L-BFGS-B refinement of every lobe parameter).
        device: accepted for the common call shape; the fit is float64 on the host.
        budget_metric: ``"irradiance_fit"`` (mixture vs environment irradiance, exact cosine),
            ``"irradiance"`` (with the SG clamped cosine ``cosine``) or ``"radiance"``.
        cosine: the clamped-cosine lobe of the reported ``irradiance_error`` (``"paper"``, ``"l2"``).
        irradiance_weight: weight of the irradiance term of the objective against the radiance term.
        fit_height: height of the (mip) map the fit runs on; errors are measured on the full map.

    Returns:
        :class:`EnvironmentSG` (world frame).

    Raises:
        ValueError: a bad environment (NaN, negative), ``max_lobes`` outside 1..9, an unknown
            ``method`` / ``budget_metric``, a non-positive ``error_budget``.
    """
    t0 = time.perf_counter()
    img = _check_environment(env, "fit_environment")
    if isinstance(max_lobes, bool) or not isinstance(max_lobes, (int, np.integer)) or not 1 <= max_lobes <= MAX_DIFFUSE_LOBES:
        raise ValueError(f"fit_environment: max_lobes must be an integer in 1..{MAX_DIFFUSE_LOBES} "
                         f"(the paper's 'fewer than 10'), got {max_lobes!r}")
    if method not in FIT_METHODS:
        raise ValueError(f"fit_environment: method must be one of {FIT_METHODS}, got {method!r}")
    if budget_metric not in BUDGET_METRICS:
        raise ValueError(f"fit_environment: budget_metric must be one of {BUDGET_METRICS}, got {budget_metric!r}")
    if error_budget is not None and not (np.isfinite(error_budget) and error_budget > 0.0):
        raise ValueError(f"fit_environment: error_budget must be finite and > 0, got {error_budget!r}")
    if not (np.isfinite(irradiance_weight) and irradiance_weight >= 0.0):
        raise ValueError(f"fit_environment: irradiance_weight must be finite and >= 0, got {irradiance_weight!r}")
    if not isinstance(fit_height, (int, np.integer)) or fit_height < 2:
        raise ValueError(f"fit_environment: fit_height must be an integer >= 2, got {fit_height!r}")
    sg.clamped_cosine(np.zeros((1, 3)), cosine)  # validates ``cosine``
    if device is not None:
        from ..._wp import resolve_device

        resolve_device(device)

    level = _fit_map(img, int(fit_height))
    problem = _FitProblem(level, irradiance_weight)
    full = _texels(img)
    normals = problem.normals
    e_true = _irradiance_quadrature(normals, *full)
    key = {"irradiance_fit": "irradiance_fit_error", "irradiance": "irradiance_error", "radiance": "radiance_error"}[budget_metric]

    history, chosen, refine_info = [], None, None
    for axes, lams, amp in _greedy_nnls(problem, int(max_lobes)):
        k = axes.shape[0]
        last = k == max_lobes
        want = error_budget is not None or last
        if method == "lbfgsb" and want:
            axes, lams, amp, res = _refine_lbfgsb(problem, axes, lams, amp)
            refine_info = {"iterations": int(res.nit), "loss": float(res.fun), "converged": bool(res.success)}
        m = _metrics(axes, lams, amp, full, normals, e_true, cosine)
        m["refined"] = bool(method == "lbfgsb" and want)
        history.append(m)
        chosen = (axes, lams, amp, m)
        if error_budget is not None and m[key] <= error_budget:
            break
    if chosen is None:  # a black environment: one zero lobe
        axes, lams, amp = np.array([[0.0, 0.0, 1.0]]), np.array([LEVEL_FIRST]), np.zeros((1, 3))
        m = _metrics(axes, lams, amp, full, normals, e_true, cosine)
        history.append(m)
        chosen = (axes, lams, amp, m)
    axes, lams, amp, m = chosen
    keep = np.any(amp > 0.0, axis=1)
    if keep.any() and not keep.all():
        axes, lams, amp = axes[keep], lams[keep], amp[keep]
    mixture = sg.SGMixture(axes, lams, amp).rotated(env.to_world)
    report = {
        "method": method,
        **m,
        "lobe_count": mixture.lobe_count,
        "error_budget": error_budget,
        "budget_metric": budget_metric,
        "budget_met": None if error_budget is None else bool(m[key] <= error_budget),
        "cosine": cosine,
        "fit_shape": list(level.shape[:2]),
        "fit_max_sharpness": problem.max_sharpness,
        "refinement": refine_info,
        "by_lobe_count": history,
        "fit_s": time.perf_counter() - t0,
    }
    return EnvironmentSG(mixture, report)


# ------------------------------------------------------------------------------------------------
# prefiltered environment


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


def _bilinear_map(image: np.ndarray, d_map: np.ndarray) -> np.ndarray:
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
        """Prefilter an environment with the Warp kernel :data:`.lighting_warp.prefilter_kernel`.

        Args:
            env: :class:`~warpshade.scene.lighting.Environment` (finite, non-negative).
            levels: sharpness values (increasing, > 0); default :func:`default_levels`.
            device: Warp device (None = Warp's default).
            progress: optional callable ``(done_levels, level_count)`` after each level.

        Returns:
            The table (host copies of the maps; :meth:`to_device` uploads them).
        """
        from ..._wp import launch_parallel, resolve_device, wp
        from .lighting_warp import prefilter_kernel

        t0 = time.perf_counter()
        img = _check_environment(env, "PrefilteredEnvironment.build")
        lv = _check_levels(default_levels(env) if levels is None else levels)
        dev = resolve_device(device)
        sources = _source_chain(img)
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
                    values, dirs = _subdivided(img, sub)
                sh, sw = values.shape[:2]
                src_cache[key] = (wp.array(values.astype(np.float32), dtype=wp.vec3, device=dev),
                                  wp.array(dirs.astype(np.float32), dtype=wp.vec3, device=dev),
                                  wp.array(_row_weights(sh, sw).astype(np.float32), dtype=float, device=dev))
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
            out[low] = (1 - t) * self.mean[None] + t * _bilinear_map(self.maps[0], d[low])
        if high.any():
            s = np.sqrt(lv[-1] / lam[high])[:, None]
            out[high] = s * _bilinear_map(self.maps[last], d[high]) + (1 - s) * _bilinear_map(self.maps[last + 1], d[high])
        if mid.any():
            ll = np.log(lam[mid])
            log_lv = np.log(lv)
            k = np.clip(np.searchsorted(log_lv, ll, side="right") - 1, 0, max(last - 1, 0))
            t = np.clip((ll - log_lv[k]) / (log_lv[k + 1] - log_lv[k]), 0.0, 1.0)[:, None]
            dm = d[mid]
            res = np.zeros((dm.shape[0], 3))
            for kk in np.unique(k):
                sel = k == kk
                a = np.maximum(_bilinear_map(self.maps[kk], dm[sel]), 0.0)
                b = np.maximum(_bilinear_map(self.maps[kk + 1], dm[sel]), 0.0)
                res[sel] = np.power(a, 1 - t[sel]) * np.power(b, t[sel])
            out[mid] = res
        return out

    # ---- device ------------------------------------------------------------------------------
    def to_device(self, device=None):
        """Upload as a :class:`.lighting_warp.PrefilteredTable` (float32) on ``device``."""
        from ..._wp import resolve_device, wp
        from .lighting_warp import PrefilteredTable

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
        """Host helper: :func:`.lighting_warp.gamma_lookup` at (N, 3) world axes -> (N, 3) float32."""
        from ..._wp import resolve_device, wp
        from .lighting_warp import gamma_lookup_kernel

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


def gamma_reference(env, p, lam) -> np.ndarray:
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
    _check_environment(env, "gamma_reference")
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


# ------------------------------------------------------------------------------------------------
# local lights (eq. 32-33)


def point_light_lobe(light: SphereLight, x, return_inside: bool = False):
    """The SG of a sphere light seen from receivers ``x`` (eq. 32), float64.

    Axis: unit vector from ``x`` to the centre (world). Sharpness ``f_a^-1(2 pi r^2 / d^2)``
    (eq. 3 inverse, epsilon 0.1). Amplitude (RGB): ``radiance * Omega / integral(G)`` with
    ``Omega = 2 pi (1 - cos alpha)``, ``sin alpha = r / d``, the sphere's solid angle, so that the
    lobe carries the sphere's emission as the ray-traced reference integrates it. A receiver
    inside the sphere (``d <= r``) sees the light in every direction: it gets the constant lobe
    (sharpness 0, amplitude ``radiance``, integral ``4 pi radiance``, exact), and a
    ``RuntimeWarning`` says how many receivers are inside.

    Args:
        light: the sphere light (world frame).
        x: receiver positions (N, 3), world frame.
        return_inside: also return the (N,) bool mask of receivers inside the sphere.

    Returns:
        ``(axis (N, 3), sharpness (N,), amplitude (N, 3))`` float64 [, ``inside (N,)``].
    """
    if not isinstance(light, SphereLight):
        raise ValueError(f"point_light_lobe: light must be a SphereLight, got {type(light).__name__}")
    x = np.asarray(x, np.float64)
    if x.ndim != 2 or x.shape[1] != 3 or not np.all(np.isfinite(x)):
        raise ValueError(f"point_light_lobe: x must be finite (N, 3) positions, got shape {x.shape}")
    offset = light.position[None] - x
    d = np.linalg.norm(offset, axis=1)
    inside = d <= light.radius
    axis = np.where(d[:, None] > 1e-300, offset / np.maximum(d, 1e-300)[:, None], np.array([0.0, 0.0, 1.0]))
    sin2 = np.where(inside, 1.0, (light.radius / np.where(inside, 1.0, d)) ** 2)
    solid = 2.0 * math.pi * sin2 / (1.0 + np.sqrt(np.maximum(0.0, 1.0 - sin2)))
    lam = np.where(inside, 0.0, sg.sharpness_for_area(2.0 * math.pi * sin2))
    amp = np.where(inside[:, None], light.radiance[None], light.radiance[None] * (solid / sg.integral(lam))[:, None])
    if inside.any():
        warnings.warn(f"point_light_lobe: {int(inside.sum())} of {x.shape[0]} receivers are inside sphere light "
                      f"{light.path or '<array>'} (radius {light.radius}); they get its radiance from every direction",
                      RuntimeWarning, stacklevel=2)
    return (axis, lam, amp, inside) if return_inside else (axis, lam, amp)


def directional_light_lobe(light: DistantLight):
    """The SG of a distant light (eq. 33), float64.

    Sharpness ``f_a^-1(2 pi r^2)`` with ``r`` the angular radius in radians (half of
    ``angle_deg``, raised to half of :data:`MIN_DISTANT_ANGLE_DEG` for narrower and delta
    lights); amplitude ``irradiance / integral(G)`` so that the lobe integrates to the light's
    irradiance (its radiance times its solid angle).

    Returns:
        ``(axis (3,), sharpness float, amplitude (3,))``, axis towards the light, world frame.
    """
    if not isinstance(light, DistantLight):
        raise ValueError(f"directional_light_lobe: light must be a DistantLight, got {type(light).__name__}")
    if not np.isfinite(light.angle_deg) or light.angle_deg < 0.0 or light.angle_deg >= 180.0:
        raise ValueError(f"directional_light_lobe: angle_deg must be in [0, 180), got {light.angle_deg!r}")
    if not np.all(np.isfinite(light.irradiance)) or not np.all(np.isfinite(light.direction)):
        raise ValueError("directional_light_lobe: direction and irradiance must be finite")
    radius = math.radians(max(float(light.angle_deg), MIN_DISTANT_ANGLE_DEG)) / 2.0
    lam = float(sg.sharpness_for_area(2.0 * math.pi * radius * radius))
    return light.direction.copy(), lam, light.irradiance / float(sg.integral(lam))


def inside_hull(points_of_mesh, light_position) -> bool:
    """Whether a point light lies inside the convex hull of a mesh's points (then precomputed
    visibility, which describes distant light, does not apply; sec. 7).

    Args:
        points_of_mesh: (M, 3) world positions.
        light_position: (3,) world position.

    Returns:
        True when inside (or on) the hull; False for a flat or degenerate point set (no volume).
    """
    from scipy.spatial import Delaunay, QhullError

    pts = np.asarray(points_of_mesh, np.float64)
    q = np.asarray(light_position, np.float64).reshape(-1)
    if pts.ndim != 2 or pts.shape[1] != 3 or not np.all(np.isfinite(pts)):
        raise ValueError(f"inside_hull: points_of_mesh must be finite (M, 3), got shape {pts.shape}")
    if q.shape != (3,) or not np.all(np.isfinite(q)):
        raise ValueError(f"inside_hull: light_position must be a finite (3,) point, got {light_position!r}")
    if pts.shape[0] < 4:
        return False
    try:
        tri = Delaunay(pts)
    except QhullError:
        return False
    return bool(tri.find_simplex(q[None])[0] >= 0)
