"""Measured materials (Wang et al. 2009, sec. 4.2): the microfacet NDF and the 1-D shadowing factor
of eq. 13 extracted from a tabulated isotropic BRDF, then fitted with SG lobes. Float64 NumPy/SciPy.

Eq. 13 models a measured BRDF as ``rho(o, i) = F(|i.h|, eta) S(o) S(i) D(h) / (pi (n.i)(n.o))``
with the Cook-Torrance Fresnel ``F`` of a fixed index (the paper: 1.33), an isotropic shadowing
``S(theta)`` and an isotropic NDF ``D(theta_h)``. Taking logarithms of the table's valid cells::

    log(pi (n.i)(n.o) rho / F) = log D(theta_h) + log S(theta_o) + log S(theta_i)

is linear in the unknowns ``log D`` and ``log S`` sampled at knots (piecewise-linear in the angle,
:func:`extract_microfacet`): a sparse least-squares problem (dense SVD least squares, LSQR for full-size tables), each
cell weighted by its value so the peak dominates over cells at the table's noise floor, with the
scale ambiguity (``D c^2`` and ``S / c`` give the same BRDF) fixed by ``S = 1`` on average within
45 degrees of the normal (where a surface is not shadowed and the table has the most cells), and
a small second-difference penalty on both curves where the table has few or no data. ``S`` is clipped to [0, 1]
(a shadowing factor) and ``D`` to >= 0.

:func:`measured_material` reads a file in the MERL binary layout
(:func:`warpshade.scene._tabulated.read_merl`), extracts ``D`` and ``S`` and returns the
:class:`._brdf.TabulatedMicrofacet` parameters the SG shading takes (``theta_h``, ``ndf_values``,
``shadow_theta``, ``shadow_values`` on uniform angles over [0, pi/2], ``eta``), with the fit's
residual; :func:`._ndf.ndf_lobes` (``tabulated-ndf``) fits its NDF with 1-2 lobes about z+.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix, vstack
from scipy.sparse.linalg import lsqr

from ._brdf import fresnel_cook_torrance

__all__ = ["MeasuredMicrofacet", "extract_microfacet", "measured_material", "reference_table"]

#: Knots of the extracted D (uniform over [0, pi/2]); the curves returned are sampled there (the
#: paper packs S into 90-D vectors).
KNOTS = 91
#: Knots of S while fitting (resampled to KNOTS afterwards). Measured on the bundled 24 x 12 x 24
#: table: 91 knots recover D to 0.034 of its peak; 46 or 31 knots let D absorb S's error (0.10-0.12).
SHADOW_KNOTS = 91
#: Cells below this fraction of the table's largest value are left out (the log is noise there).
VALUE_FLOOR = 1e-6
#: Weight of the second-difference penalty on log S relative to the data's (smooths where data are thin).
SMOOTHING = 0.1
#: The same on log D, relative to S's (log D of a sharp lobe curves by ~1 per knot, which a strong
#: penalty would flatten). Measured: S's penalty 0.1 with D's 0.01 x that: D within 0.034 of its
#: peak, S within 0.16 below 1 rad (1e-3 on both: 0.032 and 0.23).
D_SMOOTHING = 0.01
#: Polar angle (radians) within which a surface is taken to be unshadowed: S averages 1 there.
NORMAL_CONE = np.pi / 4
#: Largest least-squares matrix (rows x unknowns) solved densely (SVD); larger ones by LSQR.
DENSE_LIMIT = 4e7


@dataclass
class MeasuredMicrofacet:
    """Eq. 13's factors extracted from a table.

    Attributes:
        theta: the knots, uniform over [0, pi/2], (KNOTS,), radians.
        ndf: ``D`` at the knots (theta_h), >= 0, (KNOTS,) (the table's units: 1/sr with F, S, cosines removed).
        shadow: ``S`` at the knots (theta of o or i), in [0, 1], 1 on average within 45 degrees, (KNOTS,).
        eta: the Fresnel index used.
        residual: RMS of the log-domain fit over the used cells (0: the table is exactly eq. 13).
        cells: valid cells used.
    """

    theta: np.ndarray
    ndf: np.ndarray
    shadow: np.ndarray
    eta: float
    residual: float
    cells: int

    def parameters(self) -> dict:
        """The :class:`._brdf.TabulatedMicrofacet` / ``tabulated-ndf`` parameters."""
        return {"theta_h": self.theta, "ndf_values": self.ndf, "shadow_theta": self.theta, "shadow_values": self.shadow,
                "eta": self.eta}


def _hat(angle: np.ndarray, knots: int):
    """Piecewise-linear interpolation weights of angles over uniform knots on [0, pi/2]: (rows, cols, weights)."""
    x = np.clip(angle, 0.0, 0.5 * np.pi) / (0.5 * np.pi) * (knots - 1)
    i = np.clip(np.floor(x).astype(np.int64), 0, knots - 2)
    f = x - i
    return i, f


def extract_microfacet(view, light, values, eta: float = 1.33, knots: int = KNOTS,
                       shadow_knots: int = SHADOW_KNOTS) -> MeasuredMicrofacet:
    """Eq. 13's ``D(theta_h)`` and ``S(theta)`` from BRDF samples (module docstring).

    Args:
        view, light: local unit directions of the samples, (N, 3) each (+z the normal).
        values: the BRDF at them, (N,), 1/sr (<= 0, non-finite or below the horizon: left out).
        eta: the Fresnel index of eq. 14 (> 1). knots: samples of D (>= 4); shadow_knots: of S (>= 4).

    Raises:
        ValueError: bad shapes or eta, or fewer usable samples than unknowns.
    """
    o = np.asarray(view, np.float64).reshape(-1, 3)
    i = np.asarray(light, np.float64).reshape(-1, 3)
    rho = np.asarray(values, np.float64).reshape(-1)
    if o.shape != i.shape or rho.shape[0] != o.shape[0]:
        raise ValueError(f"extract_microfacet: view {o.shape}, light {i.shape} and values {rho.shape} do not match")
    if not (np.isfinite(eta) and eta > 1.0) or knots < 4 or shadow_knots < 4:
        raise ValueError(f"extract_microfacet: eta must be > 1 and knots >= 4, got {eta!r}, {knots!r}")
    finite = np.isfinite(rho)
    peak = float(np.max(rho[finite], initial=0.0))
    use = finite & (rho > VALUE_FLOOR * peak) & (o[:, 2] > 1e-3) & (i[:, 2] > 1e-3)
    if use.sum() < knots + shadow_knots:
        raise ValueError(f"extract_microfacet: {int(use.sum())} usable samples for {knots + shadow_knots} unknowns")
    o, i, rho = o[use], i[use], rho[use]
    h = o + i
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    f = fresnel_cook_torrance(np.sum(i * h, axis=1), eta)
    y = np.log(np.pi * o[:, 2] * i[:, 2] * rho / np.maximum(f, 1e-300))
    w = np.sqrt(rho / peak)  # relative weight: the lobe's cells over the floor's
    n = len(y)
    rows, cols, vals = [], [], []
    for block, count, angle in ((0, knots, np.arccos(np.clip(h[:, 2], -1, 1))),
                                (knots, shadow_knots, np.arccos(np.clip(o[:, 2], -1, 1))),
                                (knots, shadow_knots, np.arccos(np.clip(i[:, 2], -1, 1)))):
        k, t = _hat(angle, count)
        rows += [np.arange(n), np.arange(n)]
        cols += [block + k, block + k + 1]
        vals += [w * (1.0 - t), w * t]
    total = knots + shadow_knots
    a = coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, total)).tocsr()
    # log S at knot 0 held at 0 (its column dropped; the scale is set below), a second-difference penalty on both curves
    a = a[:, [c for c in range(total) if c != knots]]
    m = total - 1
    lam = SMOOTHING * np.sqrt(float(np.sum(w * w)) / m)
    pen_rows, pen_cols, pen_vals = [], [], []
    r = 0
    for start, count, strength in ((0, knots, D_SMOOTHING), (knots - 1, shadow_knots - 1, 1.0)):
        for k in range(count - 2):
            for off, v in ((0, 1.0), (1, -2.0), (2, 1.0)):
                pen_rows.append(r)
                pen_cols.append(start + k + off)
                pen_vals.append(strength * lam * v)
            r += 1
    pen = coo_matrix((pen_vals, (pen_rows, pen_cols)), shape=(r, m)).tocsr()
    full = vstack([a, pen]).tocsr()
    rhs = np.concatenate([w * y, np.zeros(r)])
    if full.shape[0] * full.shape[1] <= DENSE_LIMIT:
        sol = np.linalg.lstsq(full.toarray(), rhs, rcond=None)[0]
    else:  # a full-size table: iteratively
        sol = lsqr(full, rhs, atol=1e-14, btol=1e-14, conlim=1e12, iter_lim=100000)[0]
    log_d = sol[:knots]
    log_s = np.concatenate([[0.0], sol[knots:]])
    # the scale: S is 1 on average within NORMAL_CONE of the normal (no shadowing there), D takes the rest
    theta = np.linspace(0.0, 0.5 * np.pi, knots)
    log_s = np.interp(theta, np.linspace(0.0, 0.5 * np.pi, shadow_knots), log_s)
    ref = float(np.mean(log_s[theta <= NORMAL_CONE]))
    log_s -= ref
    log_d += 2.0 * ref
    resid = (a @ sol) / np.maximum(w, 1e-300) - y
    return MeasuredMicrofacet(theta, np.maximum(np.exp(log_d), 0.0), np.clip(np.exp(log_s), 0.0, 1.0), float(eta),
                              float(np.sqrt(np.mean(resid**2))), int(n))


def measured_material(path, eta: float = 1.33, channel: str = "luminance") -> MeasuredMicrofacet:
    """Eq. 13's factors of a file in the MERL binary layout: its valid cells at their centres
    (:func:`~warpshade.scene._tabulated.merl_cell_centres`), ``channel`` of each (luminance by default)."""
    from ...scene._tabulated import half_diff_directions, merl_cell_centres, read_merl

    brdf = read_merl(path, channel=channel)
    th, td, pd = merl_cell_centres(brdf.dims)
    gh, gd, gp = np.meshgrid(th, td, pd, indexing="ij")
    v, s = half_diff_directions(gh, gd, gp)
    table = brdf.table
    weights = {"luminance": np.array([0.2126, 0.7152, 0.0722]), "r": np.eye(3)[0], "g": np.eye(3)[1], "b": np.eye(3)[2]}
    values = np.tensordot(weights[brdf.channel], np.where(table < 0.0, np.nan, table), axes=1)
    return extract_microfacet(v.reshape(-1, 3), s.reshape(-1, 3), values.reshape(-1), eta)


def reference_table(path):
    """What the glossy reference shades for a measured material: the table itself, its luminance
    (the channel the NDF and shadowing are extracted from) looked up "linear" (the smooth
    reconstruction of the cells the extraction fits); the stage's specular colour multiplies it."""
    import dataclasses

    from ...scene._tabulated import read_merl

    return dataclasses.replace(read_merl(path), channel="luminance", interpolation="linear")
