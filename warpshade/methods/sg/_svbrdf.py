"""Spatially varying measured materials (Wang et al. 2009, sec. 4.2): a texture of eq.-13
microfacet materials, each texel's NDF fitted with a few SG lobes about the normal and the
texels' 1-D shadowing curves compressed together by PCA. Float64 NumPy/SciPy.

Eq. 13 at texel ``x``: ``rho_s(o, i) = F(|i.h|, eta) S_x(theta_o) S_x(theta_i) D_x(theta_h) /
(pi (n.i)(n.o))``, ``F`` the Cook-Torrance Fresnel (eq. 14) of one index ``eta`` for the texture.

The texture as stored (the ``.svbrdf`` file, :class:`~warpshade.scene._svbrdf.SVBRDFTable`), its
texel look-up and the exact material it describes are scene data (:mod:`warpshade.scene._svbrdf`);
this module fits it. ``D`` is the NDF with F, S and the cosines taken out, as :mod:`._measured`
extracts it.

Fitting (:func:`fit_svbrdf`):

* NDF: every texel's ``D`` by ``K`` SG lobes about z+, ``sum_k mu_k exp(lambda_k (cos theta -
  1))``, all texels at once: the best one or two lobes on a grid of sharpness (amplitudes in
  closed form, non-negative), further lobes added greedily on the residual, then a batched
  Levenberg-Marquardt refinement of every texel's ``(log lambda_k, mu_k)``. The error is the
  relative L2 error over the hemisphere, ``||D* - D|| / ||D||`` (``sin theta`` weights);
  ``K`` is the fewest (up to ``max_lobes``) whose worst texel meets ``ndf_error_budget``. Lobes
  are sorted by increasing sharpness (the paper's order for texture interpolation).
* Shadowing: the texels' curves ``S_x`` as rows of a (texels, samples) matrix, minus their mean,
  by SVD; the rank is the fewest terms (up to ``max_terms``; the paper: 8) whose RMS
  reconstruction error over all texels and angles meets ``shadow_error_budget``.

:class:`SVBRDFTexture` holds the result: per-texel lobes (H, W, K), the PCA mean (samples,),
basis (R, samples) and per-texel coefficients (H, W, R), with the fit report. Look-ups are
nearest-texel (``u`` repeats, ``v`` is clamped): :meth:`SVBRDFTexture.texel_of`, the scene's
:func:`~warpshade.scene._svbrdf.nearest_texel_f64`. The Warp side is
:mod:`._svbrdf_warp`; :func:`svbrdf_slices_f64` and :meth:`SVBRDFTexture.shadow_at` are its
float64 mirror.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...scene._svbrdf import SVBRDFTable, nearest_texel_f64, read_svbrdf
from ._brdf import COS_FLOOR, MAX_SHARPNESS, fresnel_cook_torrance
from ._slices import duff_frame_f64

__all__ = [
    "SVBRDFTexture",
    "eq13_quadrature_f64",
    "fit_svbrdf",
    "fit_texel_ndfs",
    "over_budget",
    "read_and_fit",
    "shadow_pca",
    "svbrdf_slices_f64",
]

#: Sharpness grid of the lobes' initial search (log-spaced) and the bounds of the refinement.
SHARPNESS_GRID = np.geomspace(0.5, 2.0e4, 48)
SHARPNESS_MIN = 0.05
#: Most lobes per texel (the paper: 1-2 for isotropic measured materials).
MAX_LOBES = 4
#: Levenberg-Marquardt iterations of the batched refinement.
LM_ITERATIONS = 40


# ------------------------------------------------------------------------------------------------
# per-texel NDF lobes


def _weights(theta: np.ndarray) -> np.ndarray:
    """Trapezoid weights of ``sin theta d theta`` over the samples (the hemisphere's measure / 2 pi)."""
    dt = np.diff(theta)
    w = np.zeros_like(theta)
    w[:-1] += 0.5 * dt
    w[1:] += 0.5 * dt
    return w * np.sin(theta)


@dataclass
class TexelLobes:
    """Per-texel SG lobes about z+: ``sharpness``, ``amplitude`` (T, K), sorted by increasing
    sharpness; ``error`` (T,) the relative L2 error of each texel's fit; ``tried`` the lobe counts
    tried with their worst and mean errors."""

    sharpness: np.ndarray
    amplitude: np.ndarray
    error: np.ndarray
    tried: list = field(default_factory=list)

    @property
    def lobes(self) -> int:
        return int(self.sharpness.shape[1])


def _closed_form(basis, d, wq):
    """Non-negative least-squares amplitudes of each texel on given lobes, batched.

    basis (T, K, N) lobe values; d (T, N); wq (N,) weights -> (amplitudes (T, K), cost (T,))."""
    g = np.einsum("tkn,tln,n->tkl", basis, basis, wq)
    b = np.einsum("tkn,tn,n->tk", basis, d, wq)
    k = basis.shape[1]
    mu = np.linalg.solve(g + 1e-12 * np.eye(k)[None] * np.trace(g, axis1=1, axis2=2)[:, None, None], b[..., None])[..., 0]
    mu = np.maximum(mu, 0.0)
    r = np.einsum("tk,tkn->tn", mu, basis) - d
    return mu, np.einsum("tn,tn,n->t", r, r, wq)


def _grid_start(cos_m1, d, wq, lobes: int):
    """Initial lobes: the best single and pair from :data:`SHARPNESS_GRID`, further ones greedily."""
    t = d.shape[0]
    grid = SHARPNESS_GRID
    e = np.exp(grid[:, None] * cos_m1[None, :])  # (G, N)
    gram = np.einsum("gn,hn,n->gh", e, e, wq)
    proj = np.einsum("gn,tn,n->tg", e, d, wq)
    dd = np.einsum("tn,tn,n->t", d, d, wq)
    # one lobe: mu = <e, d> / <e, e> (>= 0)
    mu1 = np.maximum(proj, 0.0) / np.diag(gram)[None]
    cost1 = dd[:, None] - mu1 * proj
    best1 = np.argmin(cost1, axis=1)
    lam = grid[best1][:, None]
    cost = cost1[np.arange(t), best1]
    if lobes >= 2:
        gi, gj = np.triu_indices(len(grid), 1)
        a, b, c = gram[gi, gi], gram[gi, gj], gram[gj, gj]
        det = a * c - b * b
        p, q = proj[:, gi], proj[:, gj]
        m1 = (c * p - b * q) / det
        m2 = (a * q - b * p) / det
        cost2 = dd[:, None] - (m1 * p + m2 * q)
        cost2 = np.where((m1 >= 0.0) & (m2 >= 0.0), cost2, np.inf)
        best2 = np.argmin(cost2, axis=1)
        better = cost2[np.arange(t), best2] < cost
        pair = np.stack([grid[gi[best2]], grid[gj[best2]]], 1)
        lam = np.where(better[:, None], pair, np.concatenate([lam, lam * 4.0], 1))
    for _ in range(2, lobes):
        basis = np.exp(lam[:, :, None] * cos_m1[None, None, :])
        mu, _ = _closed_form(basis, d, wq)
        resid = d - np.einsum("tk,tkn->tn", mu, basis)
        proj_r = np.einsum("gn,tn,n->tg", e, resid, wq)
        gain = np.maximum(proj_r, 0.0) ** 2 / np.diag(gram)[None]
        lam = np.concatenate([lam, grid[np.argmax(gain, axis=1)][:, None]], 1)
    basis = np.exp(lam[:, :, None] * cos_m1[None, None, :])
    mu, cost = _closed_form(basis, d, wq)
    return lam, mu


def _refine(cos_m1, d, wq, lam, mu, iterations: int = LM_ITERATIONS):
    """Batched Levenberg-Marquardt on ``(log lambda_k, mu_k)`` of every texel (weighted least squares)."""
    t, k = lam.shape
    sw = np.sqrt(wq)
    x = np.concatenate([np.log(lam), mu], 1)
    lo = np.concatenate([np.full(k, np.log(SHARPNESS_MIN)), np.zeros(k)])
    hi = np.concatenate([np.full(k, np.log(MAX_SHARPNESS)), np.full(k, np.inf)])

    def residual(x):
        e = np.exp(np.exp(x[:, :k, None]) * cos_m1[None, None, :])  # (T, K, N)
        return (np.einsum("tk,tkn->tn", x[:, k:], e) - d) * sw, e

    r, e = residual(x)
    cost = np.sum(r * r, axis=1)
    damp = np.full(t, 1e-3)
    for _ in range(iterations):
        lamv = np.exp(x[:, :k])
        jl = (x[:, k:, None] * lamv[:, :, None] * cos_m1[None, None, :] * e) * sw  # d r / d log lambda
        je = e * sw  # d r / d mu
        jac = np.concatenate([jl, je], 1)  # (T, 2K, N)
        jtj = np.einsum("tpn,tqn->tpq", jac, jac)
        g = np.einsum("tpn,tn->tp", jac, r)
        diag = np.einsum("tpp->tp", jtj) + 1e-300
        a = jtj + damp[:, None, None] * (diag[:, :, None] * np.eye(2 * k)[None])
        try:
            step = np.linalg.solve(a, -g[..., None])[..., 0]
        except np.linalg.LinAlgError:
            step = -g / (diag * (1.0 + damp[:, None]))
        xn = np.clip(x + step, lo, hi)
        rn, en = residual(xn)
        cn = np.sum(rn * rn, axis=1)
        ok = np.isfinite(cn) & (cn < cost)
        x = np.where(ok[:, None], xn, x)
        r = np.where(ok[:, None], rn, r)
        e = np.where(ok[:, None, None], en, e)
        cost = np.where(ok, cn, cost)
        damp = np.clip(np.where(ok, damp * 0.3, damp * 10.0), 1e-9, 1e9)
    return np.exp(x[:, :k]), x[:, k:], cost


def _fit_count(theta, d, lobes: int):
    cos_m1 = np.cos(theta) - 1.0
    wq = _weights(theta)
    lam, mu = _grid_start(cos_m1, d, wq, lobes)
    lam, mu, cost = _refine(cos_m1, d, wq, lam, mu)
    norm = np.einsum("tn,tn,n->t", d, d, wq)
    err = np.where(norm > 0.0, np.sqrt(np.maximum(cost, 0.0) / np.maximum(norm, 1e-300)), 0.0)
    order = np.argsort(lam, axis=1)
    lam = np.take_along_axis(lam, order, 1)
    mu = np.take_along_axis(mu, order, 1)
    # a texel with no NDF (all zero): lobes of zero amplitude
    zero = norm <= 0.0
    lam[zero], mu[zero] = 1.0, 0.0
    return lam, mu, err


def fit_texel_ndfs(theta, ndf, lobes: int | None = None, error_budget: float = 0.1, max_lobes: int = 2) -> TexelLobes:
    """SG lobes about z+ of every texel's NDF (module docstring).

    Args:
        theta: the samples' polar angles, increasing in [0, pi/2], (N,).
        ndf: ``D`` at them, (T, N) (or (H, W, N), flattened), finite and >= 0.
        lobes: a fixed lobe count, or None: the fewest (up to ``max_lobes``) whose worst texel's
            relative error is <= ``error_budget`` (the best tried when none is).
    """
    t = np.asarray(theta, np.float64).reshape(-1)
    d = np.asarray(ndf, np.float64).reshape(-1, t.size)
    if not np.all(np.isfinite(d)) or np.any(d < 0.0):
        raise ValueError("fit_texel_ndfs: NDF values must be finite and >= 0")
    if lobes is not None and not 1 <= int(lobes) <= MAX_LOBES:
        raise ValueError(f"fit_texel_ndfs: lobes must be in 1..{MAX_LOBES}, got {lobes!r}")
    if not 1 <= int(max_lobes) <= MAX_LOBES or not error_budget > 0.0:
        raise ValueError(f"fit_texel_ndfs: max_lobes must be in 1..{MAX_LOBES} and error_budget > 0, "
                         f"got {max_lobes!r}, {error_budget!r}")
    counts = [int(lobes)] if lobes is not None else range(1, int(max_lobes) + 1)
    best, tried = None, []
    for k in counts:
        lam, mu, err = _fit_count(t, d, k)
        tried.append({"lobes": k, "max_error": float(err.max()), "mean_error": float(err.mean())})
        if best is None or err.max() < best.error.max():
            best = TexelLobes(lam, mu, err)
        if err.max() <= error_budget:
            best = TexelLobes(lam, mu, err)
            break
    best.tried = tried
    return best


# ------------------------------------------------------------------------------------------------
# shadowing PCA


@dataclass
class ShadowPCA:
    """The texels' shadowing curves ``S ~ mean + coeffs @ basis``: mean (N,), basis (R, N)
    orthonormal rows, coeffs (T, R); ``rms`` and ``max_error`` of the reconstruction (before the
    clip to [0, 1] a look-up applies); ``curve`` the RMS error for 0..max_terms terms."""

    mean: np.ndarray
    basis: np.ndarray
    coeffs: np.ndarray
    rms: float
    max_error: float
    curve: np.ndarray

    def reconstruct(self) -> np.ndarray:
        return self.mean[None] + self.coeffs @ self.basis


def shadow_pca(shadow, error_budget: float = 0.002, max_terms: int = 8) -> ShadowPCA:
    """PCA of the texels' shadowing curves (T, N) with the fewest terms (0..``max_terms``) whose
    RMS reconstruction error is <= ``error_budget`` (``max_terms`` when none is)."""
    s = np.asarray(shadow, np.float64)
    s = s.reshape(-1, s.shape[-1])
    if not np.all(np.isfinite(s)):
        raise ValueError("shadow_pca: shadowing values must be finite")
    if not error_budget > 0.0 or not 1 <= int(max_terms) <= s.shape[1]:
        raise ValueError(f"shadow_pca: error_budget must be > 0 and max_terms in 1..{s.shape[1]}, "
                         f"got {error_budget!r}, {max_terms!r}")
    mean = s.mean(0)
    _, sv, vt = np.linalg.svd(s - mean, full_matrices=False)
    tail = np.concatenate([np.cumsum((sv**2)[::-1])[::-1], [0.0]])  # energy left after r terms
    curve = np.sqrt(np.maximum(tail, 0.0) / s.size)[: int(max_terms) + 1]
    meets = np.flatnonzero(curve <= error_budget)
    r = int(meets[0]) if meets.size else int(max_terms)
    r = min(r, vt.shape[0])
    basis = vt[:r]
    coeffs = (s - mean) @ basis.T
    err = mean[None] + coeffs @ basis - s
    return ShadowPCA(mean, basis, coeffs, float(np.sqrt(np.mean(err**2))), float(np.abs(err).max()), curve)


# ------------------------------------------------------------------------------------------------
# the fitted texture


@dataclass
class SVBRDFTexture:
    """A fitted texture of eq.-13 materials (module docstring).

    Attributes:
        sharpness, amplitude: per-texel NDF lobes about z+, (H, W, K), increasing sharpness.
        shadow_mean (N,), shadow_basis (R, N), shadow_coeffs (H, W, R): the shadowing PCA over
            N uniform polar angles in [0, pi/2].
        eta: Fresnel index. report: the fit's numbers (lobes, errors, PCA terms and errors).
    """

    sharpness: np.ndarray
    amplitude: np.ndarray
    shadow_mean: np.ndarray
    shadow_basis: np.ndarray
    shadow_coeffs: np.ndarray
    eta: float
    report: dict = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.sharpness.shape[0]), int(self.sharpness.shape[1])

    @property
    def lobes(self) -> int:
        return int(self.sharpness.shape[2])

    @property
    def terms(self) -> int:
        return int(self.shadow_basis.shape[0])

    def texel_of(self, uv) -> np.ndarray:
        """Nearest texel (row, column) of UVs (..., 2): ``u`` repeats, ``v`` is clamped; row 0 at ``v = 1``."""
        return nearest_texel_f64(uv, self.shape)

    def shadow_at(self, texels, cos_theta) -> np.ndarray:
        """``S`` of texels (..., 2) (row, column) at cosines (...,): the PCA reconstruction at the
        two nearest samples, linearly interpolated in theta, clipped to [0, 1]."""
        rc = np.asarray(texels, np.int64)
        c = np.asarray(cos_theta, np.float64)
        n = self.shadow_mean.size
        x = np.arccos(np.clip(c, 0.0, 1.0)) / (0.5 * np.pi) * (n - 1)
        i = np.clip(np.floor(x).astype(np.int64), 0, n - 2)
        f = np.clip(x - i, 0.0, 1.0)
        coef = self.shadow_coeffs[rc[..., 0], rc[..., 1]]  # (..., R)
        s0 = self.shadow_mean[i] + np.einsum("...r,r...->...", coef, self.shadow_basis[:, i])
        s1 = self.shadow_mean[i + 1] + np.einsum("...r,r...->...", coef, self.shadow_basis[:, i + 1])
        return np.clip((1.0 - f) * s0 + f * s1, 0.0, 1.0)

    def remaining_factor(self, texels, view, light) -> np.ndarray:
        """``F(|i.h|, eta) S(o) S(i) / (pi (n.i)(n.o))`` at local directions (..., 3); 0 below either horizon."""
        o = np.asarray(view, np.float64)
        i = np.asarray(light, np.float64)
        h = o + i
        h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
        oh = np.sum(o * h, axis=-1)
        co, ci = o[..., 2], i[..., 2]
        val = (fresnel_cook_torrance(oh, self.eta) * self.shadow_at(texels, co) * self.shadow_at(texels, ci)
               / (np.pi * np.maximum(co, COS_FLOOR) * np.maximum(ci, COS_FLOOR)))
        return np.where((co > 0.0) & (ci > 0.0), val, 0.0)

    def ndf_at(self, texels, cos_theta_h) -> np.ndarray:
        """The texels' fitted NDF ``sum_k mu_k exp(lambda_k (cos theta_h - 1))``."""
        rc = np.asarray(texels, np.int64)
        lam = self.sharpness[rc[..., 0], rc[..., 1]]
        mu = self.amplitude[rc[..., 0], rc[..., 1]]
        return np.sum(mu * np.exp(lam * (np.asarray(cos_theta_h, np.float64)[..., None] - 1.0)), axis=-1)


def fit_svbrdf(table: SVBRDFTable, lobes: int | None = None, ndf_error_budget: float = 0.1, max_lobes: int = 2,
               shadow_error_budget: float = 0.002, max_terms: int = 8) -> SVBRDFTexture:
    """Fit a texture of eq.-13 materials: per-texel NDF lobes (:func:`fit_texel_ndfs`) and the
    shadowing PCA (:func:`shadow_pca`)."""
    h, w = table.shape
    theta = table.theta
    fit = fit_texel_ndfs(theta, table.ndf.reshape(h * w, -1), lobes, ndf_error_budget, max_lobes)
    pca = shadow_pca(table.shadow.reshape(h * w, -1), shadow_error_budget, min(int(max_terms), table.ndf.shape[2]))
    k, r = fit.lobes, pca.basis.shape[0]
    report = {"texels": h * w, "size": [h, w], "samples": int(theta.size), "lobes": k,
              "ndf_error_max": float(fit.error.max()), "ndf_error_mean": float(fit.error.mean()),
              "ndf_budget": float(ndf_error_budget), "ndf_budget_met": bool(fit.error.max() <= ndf_error_budget),
              "ndf_tried": fit.tried, "shadow_terms": r, "shadow_rms": pca.rms, "shadow_max_error": pca.max_error,
              "shadow_budget": float(shadow_error_budget), "shadow_budget_met": bool(pca.rms <= shadow_error_budget)}
    return SVBRDFTexture(fit.sharpness.reshape(h, w, k), fit.amplitude.reshape(h, w, k), pca.mean, pca.basis,
                         pca.coeffs.reshape(h, w, r), table.eta, report)


def over_budget(report: dict) -> str | None:
    """Why a fit's report misses its budgets (None when it meets both)."""
    if report["ndf_budget_met"] and report["shadow_budget_met"]:
        return None
    return (f"fit over budget (NDF worst texel {report['ndf_error_max']:.3f} with {report['lobes']} lobes, budget "
            f"{report['ndf_budget']:g}; shadowing RMS {report['shadow_rms']:.2e} with {report['shadow_terms']} terms, "
            f"budget {report['shadow_budget']:g})")


def read_and_fit(path, lobes: int | None, ndf_error_budget: float, max_lobes: int, shadow_error_budget: float,
                 max_terms: int) -> SVBRDFTexture:
    """The texture at ``path`` read (:func:`read_svbrdf`) and fitted (:func:`fit_svbrdf`, at most
    :data:`MAX_LOBES` lobes); a RuntimeWarning naming the file when the fit misses its budgets."""
    fitted = fit_svbrdf(read_svbrdf(path), lobes, ndf_error_budget, min(max_lobes, MAX_LOBES), shadow_error_budget,
                        max_terms)
    why = over_budget(fitted.report)
    if why:
        import warnings

        warnings.warn(f"SVBRDF texture {str(path)!r}: {why}", RuntimeWarning, stacklevel=3)
    return fitted


def svbrdf_slices_f64(texture: SVBRDFTexture, texels, views):
    """Float64 mirror of :func:`._svbrdf_warp.svbrdf_slices`: each texel's NDF lobes warped to a
    local view (eq. 18-22, as :func:`._lobes_warp.warped_lobe` for lobes about z+).

    Args:
        texels: (P, 2) int (row, column). views: local unit views (P, 3), +z the normal.

    Returns:
        (axes (P, K, 3), sharpness (P, K), amplitude (P, K)); culled lobes as the kernel writes
        them (axis z+, sharpness 1, amplitude 0).
    """
    rc = np.asarray(texels, np.int64).reshape(-1, 2)
    o = np.asarray(views, np.float64).reshape(-1, 3)
    o = o / np.linalg.norm(o, axis=1, keepdims=True)
    k = texture.lobes
    op = o[:, 2]
    pw = np.stack([-o[:, 0], -o[:, 1], o[:, 2]], 1)  # 2 (o.z) z - o
    live = (op > 0.0)
    lam = texture.sharpness[rc[:, 0], rc[:, 1]] / (4.0 * np.maximum(np.abs(op), 1e-6))[:, None]
    lam = np.minimum(lam, MAX_SHARPNESS)
    m = texture.remaining_factor(rc, o, pw)
    amp = texture.amplitude[rc[:, 0], rc[:, 1]] * m[:, None]
    axes = np.where(live[:, None, None], np.repeat(pw[:, None], k, 1), np.array([0.0, 0.0, 1.0]))
    return axes, np.where(live[:, None], lam, 1.0), np.where(live[:, None], amp, 0.0)


def eq13_quadrature_f64(normals, views, materials, eta: float, radiance_fn, occluded_fn=None, z_nodes: int = 128,
                        phi_nodes: int = 256) -> np.ndarray:
    """Specular radiance ``integral_H L(i) V(i) rho(o, i) (n.i) di`` of eq.-13 materials by
    quadrature (float64): the oracle of the SVBRDF shading, independent of its fits.

    Args:
        normals: unit world normals (P, 3); views: unit world directions toward the eye (P, 3).
        materials: per point ``(ndf_fn, shadow_fn)``, callables of polar angles (radians) giving
            that point's exact ``D(theta_h)`` and ``S(theta)``.
        eta: the Fresnel index. radiance_fn: world directions (M, 3) -> RGB (M, 3).
        occluded_fn: optional ``(point index, world directions (M, 3)) -> bool (M,)``: blocked directions.
        z_nodes, phi_nodes: :func:`warpshade.scene._materials.hemisphere_quadrature` nodes.

    Returns:
        (P, 3) radiance, ``ks = 1``.
    """
    from ...scene._materials import hemisphere_quadrature

    dirs, w = hemisphere_quadrature(z_nodes, phi_nodes)
    n_all = np.asarray(normals, np.float64).reshape(-1, 3)
    v_all = np.asarray(views, np.float64).reshape(-1, 3)
    out = np.zeros((len(n_all), 3))
    ti = np.arccos(np.clip(dirs[:, 2], -1.0, 1.0))
    for p, (n, v) in enumerate(zip(n_all, v_all)):
        frame = duff_frame_f64(n / np.linalg.norm(n))
        o = frame @ (v / np.linalg.norm(v))
        if o[2] <= 0.0:
            continue
        ndf_fn, shadow_fn = materials[p]
        world = dirs @ frame
        h = dirs + o[None]
        h /= np.linalg.norm(h, axis=1, keepdims=True)
        rho = (fresnel_cook_torrance(np.sum(dirs * h, axis=1), eta)
               * shadow_fn(np.array([np.arccos(min(o[2], 1.0))]))[0] * shadow_fn(ti)
               * ndf_fn(np.arccos(np.clip(h[:, 2], -1.0, 1.0))) / (np.pi * o[2] * np.maximum(dirs[:, 2], COS_FLOOR)))
        weight = w * rho * dirs[:, 2]
        if occluded_fn is not None:
            weight = np.where(occluded_fn(p, world), 0.0, weight)
        out[p] = weight @ np.asarray(radiance_fn(world), np.float64).reshape(-1, 3)
    return out
