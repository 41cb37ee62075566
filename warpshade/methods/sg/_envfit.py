"""SG lighting (Wang et al. 2009, sec. 6), the diffuse term: the environment as a few SG lobes.
Float64 fitting and its error report.

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
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ...basis import quadrature, sg
from ._envmap import check_environment, mip_chain

__all__ = [
    "BUDGET_METRICS",
    "CANDIDATE_BRIGHTEST",
    "CANDIDATE_FIBONACCI",
    "CANDIDATE_FIRST_SHARPNESS",
    "FIT_HEIGHT",
    "FIT_METHODS",
    "FIT_NORMALS",
    "MAX_DIFFUSE_LOBES",
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
#: Sharpness of the broadest candidate lobes (doubled up to what the fit map resolves).
CANDIDATE_FIRST_SHARPNESS = 0.5
#: Diffuse fit methods.
FIT_METHODS = ("nnls", "lbfgsb")
#: Budget metrics accepted by :func:`fit_environment`.
BUDGET_METRICS = ("irradiance_fit", "irradiance", "radiance")
#: Smallest sharpness L-BFGS-B may reach (a lobe this broad is nearly constant).
MIN_FIT_SHARPNESS = 0.05


def _fit_map(img: np.ndarray, fit_height: int) -> np.ndarray:
    for level in mip_chain(img):
        if level.shape[0] <= fit_height:
            return level
    return mip_chain(img)[-1]


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
        lams = [CANDIDATE_FIRST_SHARPNESS]
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
        env: :class:`~warpshade.scene._lighting.Environment` (finite, non-negative radiance).
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
    img = check_environment(env, "fit_environment")
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
        axes, lams, amp = np.array([[0.0, 0.0, 1.0]]), np.array([CANDIDATE_FIRST_SHARPNESS]), np.zeros((1, 3))
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
