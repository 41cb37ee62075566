"""Measured anisotropic materials (Wang et al. 2009, sec. 4.2): the 2-D microfacet NDF and the 1-D
shadowing factor of eq. 13 extracted from a tabulated anisotropic BRDF
(:mod:`warpshade.scene._tabulated_aniso`), the NDF fitted with free-axis SG lobes. Float64 NumPy/SciPy.

Eq. 13 with an anisotropic NDF, in the local frame (+x the tangent)::

    rho(o, i) = F(|i.h|, eta) S(theta_o) S(theta_i) D(theta_h, phi_h) / (pi (n.i)(n.o))

with the Cook-Torrance Fresnel ``F`` of a fixed index, a shadowing factor ``S`` over the polar angle
alone (the paper's 1-D factor; a real surface's masking may depend on the azimuth too, which the fit
then averages) and ``D`` over the half vector's polar angle and azimuth. As
:mod:`._measured` does for isotropic tables, the logarithm of each valid cell's ``pi (n.i)(n.o) rho /
F`` is ``log D + log S(theta_o) + log S(theta_i)``: linear in the unknowns, here ``log D`` at the
table's own (theta_h, phi_h) cell centres (one unknown per cell column, so the 2-D NDF keeps the
table's resolution) and ``log S`` at :data:`~._measured.SHADOW_KNOTS` uniform knots over [0, pi/2]
(piecewise linear). Cells are weighted by the square root of their value (the peak dominates the
noise floor); second-difference penalties smooth ``log S`` and, along theta_h, ``log D`` where the
table has few data; the normal equations are solved densely (the unknowns number n_theta_h n_phi_h +
knots). The scale ambiguity is fixed as in :mod:`._measured` (``S = 1`` on average within 45
degrees); ``S`` is clipped to [0, 1], ``D`` to >= 0.

:class:`AnisotropicMeasured` holds the result: :meth:`~AnisotropicMeasured.ndf` interpolates D
(bilinear in the table's cell-index space of theta_h, periodic in phi_h over [0, pi));
:meth:`~AnisotropicMeasured.fit_lobes` fits it with the fewest free-axis SG lobes
(:func:`._ndf.fit_ndf`, L-BFGS-B) whose relative L2 error meets a budget; its
:meth:`~AnisotropicMeasured.parameters` are the eq.-13 remaining factor's (``eta``, ``shadow_values``)
that :func:`._lobes_warp.upload_lobes` takes for the ``tabulated-ndf`` lobe model, so the per-pixel SG
shading of the anisotropic dish (tangent frames, per-lobe warp) shades it unchanged.
:func:`aniso_measured_material` reads a file and extracts; :func:`aniso_reference_table` is what the
glossy reference shades for it (the table itself, "linear").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix

from ._brdf import COS_FLOOR, fresnel_cook_torrance
from ._measured import D_SMOOTHING, NORMAL_CONE, SHADOW_KNOTS, SMOOTHING, VALUE_FLOOR

__all__ = ["AnisotropicMeasured", "aniso_measured_material", "aniso_reference_table", "extract_anisotropic",
           "stage_material", "stage_reference_table"]


@dataclass
class AnisotropicMeasured:
    """Eq. 13's factors of an anisotropic table.

    Attributes:
        theta_h: polar angles of the NDF samples (the table's theta_h cell centres), (n_th,).
        phi_h: azimuths of the NDF samples over [0, pi) (cell centres), (n_ph,).
        ndf_values: D at (theta_h, phi_h), >= 0, (n_th, n_ph).
        theta: knots of S, uniform over [0, pi/2], (K,); shadow: S there, in [0, 1].
        eta: the Fresnel index; residual: RMS of the log-domain fit over the used cells; cells: their count.
    """

    theta_h: np.ndarray
    phi_h: np.ndarray
    ndf_values: np.ndarray
    theta: np.ndarray
    shadow: np.ndarray
    eta: float
    residual: float
    cells: int
    source: str = "<array>"
    _fits: dict = field(default_factory=dict, repr=False)

    def ndf(self, h) -> np.ndarray:
        """D at local half vectors (..., 3): bilinear over the samples (clamped in theta_h, periodic in
        phi_h), 0 below the horizon."""
        h = np.asarray(h, np.float64)
        theta = np.arctan2(np.hypot(h[..., 0], h[..., 1]), h[..., 2])
        phi = np.mod(np.arctan2(h[..., 1], h[..., 0]), np.pi)
        n_th, n_ph = self.ndf_values.shape
        u = np.clip(np.sqrt(np.clip(theta, 0.0, 0.5 * np.pi) / (0.5 * np.pi)) * n_th - 0.5, 0.0, n_th - 1.0)
        i0 = np.minimum(np.floor(u).astype(np.int64), max(n_th - 2, 0))
        i1 = np.minimum(i0 + 1, n_th - 1)
        ti = np.clip(u - i0, 0.0, 1.0)
        w = phi / np.pi * n_ph - 0.5
        f = np.floor(w)
        tj = w - f
        j0 = np.mod(f.astype(np.int64), n_ph)
        j1 = np.mod(j0 + 1, n_ph)
        d = self.ndf_values
        out = ((1 - ti) * ((1 - tj) * d[i0, j0] + tj * d[i0, j1]) + ti * ((1 - tj) * d[i1, j0] + tj * d[i1, j1]))
        return np.where(h[..., 2] > 0.0, out, 0.0)

    def shadowing(self, cos_theta) -> np.ndarray:
        return np.interp(np.arccos(np.clip(np.asarray(cos_theta, np.float64), -1.0, 1.0)), self.theta, self.shadow)

    def evaluate(self, view, light) -> np.ndarray:
        """Eq. 13 with the extracted factors at local unit directions (1/sr), 0 below the horizon."""
        o, i = np.broadcast_arrays(np.asarray(view, np.float64), np.asarray(light, np.float64))
        h = o + i
        h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
        f = fresnel_cook_torrance(np.abs(np.sum(i * h, axis=-1)), self.eta)
        co, ci = np.maximum(o[..., 2], COS_FLOOR), np.maximum(i[..., 2], COS_FLOOR)
        val = f * self.shadowing(o[..., 2]) * self.shadowing(i[..., 2]) * self.ndf(h) / (np.pi * co * ci)
        return np.where((o[..., 2] > 0.0) & (i[..., 2] > 0.0), val, 0.0)

    def parameters(self) -> dict:
        """The eq.-13 remaining factor's parameters (:func:`._lobes_warp.upload_lobes`, model ``tabulated-ndf``)."""
        return {"eta": self.eta, "shadow_theta": self.theta, "shadow_values": self.shadow}

    def fit_lobes(self, lobes: int | None = None, budget: float = 0.15, max_lobes: int = 8):
        """The NDF as free-axis SG lobes: ``lobes`` when given, else the fewest (up to ``max_lobes``)
        whose relative L2 error (:func:`._ndf.fit_ndf`) meets ``budget`` (the best one when none does).
        Returns ``(SGMixture, report)``; fits are cached per lobe count."""
        from ._ndf import fit_ndf

        counts = [int(lobes)] if lobes is not None else range(1, int(max_lobes) + 1)
        best, tried = None, []
        for k in counts:
            if k not in self._fits:
                self._fits[k] = fit_ndf(self.ndf, k, axes="free")
            fit = self._fits[k]
            tried.append({"lobes": k, "fit_error": round(float(fit.relative_error), 5)})
            if best is None or fit.relative_error < best.relative_error:
                best = fit
            if lobes is None and fit.relative_error <= budget:
                best = fit
                break
        met = lobes is not None or best.relative_error <= budget
        report = {"model": "tabulated-anisotropic", "source": self.source, "lobes": int(best.mixture.lobe_count),
                  "fit_error": float(best.relative_error), "budget": float(budget), "budget_met": bool(met),
                  "tried": tried, "extraction_residual": round(self.residual, 5), "eta": self.eta}
        return best.mixture, report


def _hat(angle, knots: int):
    x = np.clip(angle, 0.0, 0.5 * np.pi) / (0.5 * np.pi) * (knots - 1)
    i = np.clip(np.floor(x).astype(np.int64), 0, knots - 2)
    return i, x - i


def extract_anisotropic(table: np.ndarray, eta: float = 1.33, shadow_knots: int = SHADOW_KNOTS,
                        source: str = "<array>") -> AnisotropicMeasured:
    """Eq. 13's ``D(theta_h, phi_h)`` and ``S(theta)`` of a one-channel table (n_theta_h, n_phi_h,
    n_theta_d, n_phi_d) in the layout of :mod:`warpshade.scene._tabulated_aniso` (module docstring).

    Raises:
        ValueError: a bad table shape or eta, or fewer usable cells than unknowns.
    """
    from ...scene._tabulated import half_diff_directions
    from ...scene._tabulated_aniso import aniso_cell_centres

    t = np.asarray(table, np.float64)
    if t.ndim != 4:
        raise ValueError(f"extract_anisotropic: table must be 4-D (n_theta_h, n_phi_h, n_theta_d, n_phi_d), got {t.shape}")
    if not (math.isfinite(eta) and eta > 1.0) or shadow_knots < 4:
        raise ValueError(f"extract_anisotropic: eta must be > 1 and shadow_knots >= 4, got {eta!r}, {shadow_knots!r}")
    n_th, n_ph = t.shape[:2]
    th, ph, td, pd = aniso_cell_centres(t.shape)
    gh, gp, gd, gq = np.meshgrid(th, ph, td, pd, indexing="ij")
    o, i = half_diff_directions(gh, gd, gq, gp)
    col = np.broadcast_to((np.arange(n_th)[:, None] * n_ph + np.arange(n_ph)[None, :])[:, :, None, None], t.shape)
    rho = t.reshape(-1)
    o, i, col = o.reshape(-1, 3), i.reshape(-1, 3), col.reshape(-1)
    peak = float(rho.max(initial=0.0))
    use = np.isfinite(rho) & (rho > VALUE_FLOOR * peak) & (o[:, 2] > 1e-3) & (i[:, 2] > 1e-3)
    nd = n_th * n_ph
    if use.sum() < nd + shadow_knots:
        raise ValueError(f"extract_anisotropic: {int(use.sum())} usable cells for {nd + shadow_knots} unknowns")
    o, i, rho, col = o[use], i[use], rho[use], col[use]
    h = o + i
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    y = np.log(np.pi * o[:, 2] * i[:, 2] * rho / np.maximum(fresnel_cook_torrance(np.sum(i * h, axis=1), eta), 1e-300))
    w = np.sqrt(rho / peak)
    n = len(y)
    rows, cols, vals = [np.arange(n)], [col], [w]
    for angle in (np.arccos(np.clip(o[:, 2], -1, 1)), np.arccos(np.clip(i[:, 2], -1, 1))):
        k, f = _hat(angle, shadow_knots)
        rows += [np.arange(n), np.arange(n)]
        cols += [nd + k, nd + k + 1]
        vals += [w * (1.0 - f), w * f]
    total = nd + shadow_knots
    a = coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, total)).tocsr()
    keep = np.array([c for c in range(total) if c != nd])  # log S at knot 0 held at 0 (the scale is set below)
    a = a[:, keep]
    m = total - 1
    lam = SMOOTHING * math.sqrt(float(np.sum(w * w)) / m)
    pr, pc, pv = [], [], []
    r = 0
    second = ((0, 1.0), (1, -2.0), (2, 1.0))
    # log D along theta_h, per phi_h column; log S (unknowns nd .. nd + knots - 2 stand for knots 1..)
    triples = [([(k + off) * n_ph + jcol for off, _ in second], D_SMOOTHING) for jcol in range(n_ph) for k in range(n_th - 2)]
    triples += [([nd + k + off for off, _ in second], 1.0) for k in range(shadow_knots - 3)]
    for cols3, strength in triples:
        for c, (_, v) in zip(cols3, second):
            pr.append(r)
            pc.append(c)
            pv.append(strength * lam * v)
        r += 1
    pen = coo_matrix((pv, (pr, pc)), shape=(r, m)).tocsr()
    normal = (a.T @ a + pen.T @ pen).toarray()
    sol = np.linalg.lstsq(normal, a.T @ (w * y), rcond=None)[0]
    log_d = sol[:nd].reshape(n_th, n_ph)
    # D columns without a usable cell (the BRDF under VALUE_FLOOR of its peak for every theta_d, phi_d)
    # are 0, not the smoothing's extrapolation
    empty = (np.bincount(col, minlength=nd) == 0).reshape(n_th, n_ph)
    log_s = np.concatenate([[0.0], sol[nd:]])
    theta = np.linspace(0.0, 0.5 * np.pi, shadow_knots)
    ref = float(np.mean(log_s[theta <= NORMAL_CONE]))
    log_s -= ref
    log_d += 2.0 * ref
    resid = (a @ sol) / np.maximum(w, 1e-300) - y
    return AnisotropicMeasured(th, ph, np.where(empty, 0.0, np.exp(np.minimum(log_d, 700.0))), theta,
                               np.clip(np.exp(log_s), 0.0, 1.0), float(eta), float(np.sqrt(np.mean(resid**2))), int(n),
                               source)


def aniso_measured_material(path, eta: float = 1.33) -> AnisotropicMeasured:
    """Eq. 13's factors of an ``.anisobrdf`` file (its luminance, the one channel of a grey table)."""
    from ...scene._tabulated_aniso import read_anisotropic_table

    brdf = read_anisotropic_table(path)
    return extract_anisotropic(brdf.scalar_table(), eta, source=str(path))


def aniso_reference_table(path):
    """What the glossy reference shades for a measured anisotropic material: the table itself (its
    luminance), looked up "linear"; the stage's specular colour multiplies it."""
    from ...scene._tabulated_aniso import read_anisotropic_table

    return read_anisotropic_table(path, channel="luminance", interpolation="linear")


def stage_material(brdf: str, path, eta: float):
    """The eq.-13 factors ``sg.shade`` reads for ``brdf`` = "tabulated-ndf" (a MERL-layout file,
    :func:`._measured.measured_material`) or "tabulated-aniso" (an ``.anisobrdf``, :func:`aniso_measured_material`)."""
    from ._measured import measured_material

    return (aniso_measured_material if brdf == "tabulated-aniso" else measured_material)(path, eta=eta)


def stage_reference_table(brdf: str, path):
    """What the glossy reference shades for ``sg.shade``'s measured ``brdf``: the table
    (:func:`._measured.reference_table`), the anisotropic table (:func:`aniso_reference_table`) or the
    SVBRDF texture (:func:`warpshade.scene._svbrdf.svbrdf_material`)."""
    from ...scene._svbrdf import svbrdf_material
    from ._measured import reference_table

    read = {"tabulated-aniso": aniso_reference_table, "svbrdf": svbrdf_material}.get(brdf, reference_table)
    return read(path)
