"""Reflectance product operators (Nowrouzezahrai et al. 2009, sec. 4 and 6): one BRDF as k light and
view factors in SH, and how they are made.

A BRDF ``f(w, wo)`` of :mod:`warpshade.scene._materials` (local frame, +z the normal) is tabulated
as the matrix ``B_ij = integral_H f(wo_i, s) y_j(s) s_z ds`` over a grid of view directions
``wo_i`` (:func:`~warpshade.scene._materials.brdf_matrix`: the cosine-weighted BRDF, the paper's
choice, or the BRDF alone with the cosine applied at run time through the product matrix ``C`` of
eq. 14) and factored by SVD, ``B ~ U~ S~ V~`` keeping ``k`` singular pairs
(:func:`~warpshade.scene._materials.factorize`). The light factors are already SH (the rows of
``V~``: ``u_b``, eq. 10); the view factors ``W_b(wo)`` (the columns of ``U~ S~``, sampled on the
view grid) are fitted with SH ``w_b`` by least squares over the upper hemisphere, the only half
where a view exists. The paper fits them at the order n of everything else; their fit is then the
largest error term (GGX roughness 0.5, n = 4, k = 8: 11 % on the view grid, 6.5 % of the unshadowed
radiance), so the view factors have an order of their own, ``view_order`` (default
:data:`VIEW_ORDER` = 6: 0.3 % and 1.0 %, the rank-8 truncation then dominating). The operator of factor b is the SH product matrix of its light factor,
``(M_b)_ij = sum_k (u_b)_k Gamma_ijk`` (eq. 10, exact Gaunt integrals), and the outgoing radiance
under local-frame lighting ``l`` and local-frame SH visibility ``v`` is (eq. 11)::

    L(wo) = sum_b (w_b . y(wo)) l . (M_b v)
          = l . (F(wo) * v),     F(wo) = sum_b (w_b . y(wo)) u_b

with ``*`` the order-n SH product (``M_b v = u_b * v``). The second form needs one product per
vertex whatever k is; :mod:`._kernels` evaluates either form (``evaluation = "gaunt"`` or
``"matrices"``).

Storage per BRDF: ``u_b`` and ``w_b`` (``2 k n^2`` floats) and, for the matrix form, the ``M_b``
(``k n^4``), within the paper's ``k n^2 (1 + n^2)`` for the light factor and its matrix.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from ...basis import sh
from ...scene import _materials as materials

__all__ = [
    "COSINE_MODES",
    "VIEW_ORDER",
    "fit_view_factors",
    "product_matrices",
]

#: Where the cosine ``max(0, n.s)`` goes: "brdf" (tabulated with the BRDF, the paper's choice) or
#: "product" (the BRDF alone is factored; the cosine is multiplied onto the visibility at run
#: time by the product matrix of eq. 14).
COSINE_MODES = ("brdf", "product")

#: Hemisphere quadrature of the light integral of the BRDF table (Gauss-Legendre nodes in
#: cos(theta) times azimuths). Against a 96 x 192 rule the tabulated matrix of a GGX lobe of
#: roughness 0.2 is off by < 1e-3 relative (tests/test_rpo.py); sharper lobes need more.
Z_NODES, PHI_NODES = 32, 64

#: Default SH order of the view factors (see the module docstring).
VIEW_ORDER = 6


def product_matrices(light_sh) -> np.ndarray:
    """``M_b = sum_k (u_b)_k Gamma_::k`` for each light factor (eq. 10), (k, n*n, n*n) float64."""
    return sh.product_matrix(np.asarray(light_sh, np.float64))


def fit_view_factors(views, values, order: int, ridge: float = 1e-6) -> tuple[np.ndarray, float]:
    """SH fit of view-factor samples over the upper hemisphere.

    Args:
        views: (m, 3) unit view directions (z > 0), area-uniform.
        values: (m, k) factor values at those views.
        order: SH order of the fit.
        ridge: Tikhonov weight relative to the largest eigenvalue of the normal matrix (the
            half-sphere leaves the SH fit slightly ill-conditioned).

    Returns:
        ``(w, rel_error)``: coefficients (k, order*order) and the relative RMS error of the fit
        on the samples.
    """
    y = sh.basis(np.asarray(views, np.float64), order)
    vals = np.asarray(values, np.float64)
    ata = y.T @ y
    lam = ridge * float(np.max(np.linalg.eigvalsh(ata)))
    w = np.linalg.solve(ata + lam * np.eye(ata.shape[0]), y.T @ vals).T
    resid = y @ w.T - vals
    err = float(np.sqrt(np.sum(resid**2) / max(np.sum(vals**2), 1e-300)))
    return w, err


@dataclass
class ReflectanceOperator:
    """One BRDF as k reflectance product operators (float64 on the host).

    Attributes:
        order: SH order n of visibility, lighting and light factors.
        light_sh: ``u_b``, (k, n*n): the light factors (the rows kept by the SVD).
        view_sh: ``w_b``, (k, m*m): the view factors' SH fit (order m = view_order) over the
            upper hemisphere.
        cosine: "brdf" or "product" (:data:`COSINE_MODES`).
        singular_values: all singular values of the tabulated matrix, descending.
        view_fit_error: relative RMS error of the view factors' SH fit on the view grid.
        brdf: the BRDF's description (``BRDF.describe()``).
        build_s: seconds the build took.
    """

    order: int
    light_sh: np.ndarray
    view_sh: np.ndarray
    cosine: str
    singular_values: np.ndarray
    view_fit_error: float
    brdf: dict
    build_s: float = 0.0
    _matrices: np.ndarray | None = field(default=None, repr=False)

    @property
    def rank(self) -> int:
        return int(self.light_sh.shape[0])

    @property
    def view_order(self) -> int:
        return int(round(np.sqrt(self.view_sh.shape[1])))

    def truncation_error(self) -> float:
        """Relative Frobenius error of the rank-k table (the SVD's share of the error)."""
        s2 = np.asarray(self.singular_values, np.float64) ** 2
        return float(np.sqrt(s2[self.rank:].sum() / max(s2.sum(), 1e-300)))

    def matrices(self) -> np.ndarray:
        """The operators ``M_b`` (k, n*n, n*n) (eq. 10), built on first use."""
        if self._matrices is None:
            self._matrices = product_matrices(self.light_sh)
        return self._matrices

    def storage_floats(self, evaluation: str = "gaunt") -> int:
        """Floats kept per BRDF: ``k (n^2 + m^2)`` (factors), plus ``k n^4`` for the matrix form."""
        k, n2 = self.light_sh.shape
        return k * (n2 + self.view_sh.shape[1]) + (k * n2 * n2 if evaluation == "matrices" else 0)

    def view_weights(self, views) -> np.ndarray:
        """``w_b . y(wo)`` at local view directions (..., 3) -> (..., k)."""
        return sh.basis(np.asarray(views, np.float64), self.view_order) @ self.view_sh.T

    def local_transfer(self, views, visibility) -> np.ndarray:
        """``F(wo) * v`` (the vector dotted with the local lighting), (..., n*n) float64.

        Args:
            views: (V, 3) local view directions; visibility: (V, n*n) local SH visibility (the
                cosine already applied for ``cosine = "product"``: see :meth:`prepare_visibility`).
        """
        f = self.view_weights(views) @ self.light_sh
        return sh.product(f, np.asarray(visibility, np.float64))

    def prepare_visibility(self, visibility) -> np.ndarray:
        """The visibility the operators act on: ``v`` itself, or ``C v`` (eq. 14) when the
        cosine was left out of the BRDF table."""
        v = np.asarray(visibility, np.float64)
        if self.cosine == "brdf":
            return v
        return sh.product(v, np.broadcast_to(sh.clamped_cosine_sh(self.order), v.shape))

    def shade_local(self, views, visibility, light_local) -> np.ndarray:
        """Eq. 11 per receiver, float64: views (V, 3) local, visibility (V, n*n) local, light
        (V, C, n*n) local (C channels) or (C, n*n) shared -> (V, C)."""
        t = self.local_transfer(views, self.prepare_visibility(visibility))
        lo = np.asarray(light_local, np.float64)
        if lo.ndim == 2:
            return t @ lo.T
        return np.einsum("vi,vci->vc", t, lo)

    def shade_matrices(self, views, visibility, light_local) -> np.ndarray:
        """Eq. 11 literally: ``sum_b (w_b . y(wo)) l . (M_b v)`` (the oracle of the "gaunt" form)."""
        v = self.prepare_visibility(visibility)
        mv = np.einsum("bij,vj->vbi", self.matrices(), v)
        t = np.einsum("vb,vbi->vi", self.view_weights(views), mv)
        lo = np.asarray(light_local, np.float64)
        return t @ lo.T if lo.ndim == 2 else np.einsum("vi,vci->vc", t, lo)

    def arrays(self) -> dict:
        return {"light_sh": self.light_sh, "view_sh": self.view_sh, "singular_values": self.singular_values,
                "cosine": np.array(self.cosine), "view_fit_error": np.array(self.view_fit_error)}

    @classmethod
    def from_arrays(cls, arrays: dict, brdf: dict | None = None) -> "ReflectanceOperator":
        """Rebuild and check (shapes, finiteness); ValueError for anything else."""
        try:
            u = np.asarray(arrays["light_sh"], np.float64)
            w = np.asarray(arrays["view_sh"], np.float64)
            cosine = str(arrays["cosine"])
        except KeyError as exc:
            raise ValueError(f"rpo: not an operator (missing {exc})") from None
        if u.ndim != 2 or w.ndim != 2 or u.shape[0] != w.shape[0]:
            raise ValueError(f"rpo: light_sh {u.shape} and view_sh {w.shape} must be (k, n*n) and (k, m*m) arrays")
        order = int(round(np.sqrt(u.shape[1])))
        if order * order != u.shape[1] or int(round(np.sqrt(w.shape[1]))) ** 2 != w.shape[1]:
            raise ValueError(f"rpo: {u.shape[1]} / {w.shape[1]} coefficients are not square SH sizes")
        if cosine not in COSINE_MODES:
            raise ValueError(f"rpo: cosine must be one of {COSINE_MODES}, got {cosine!r}")
        if not (np.all(np.isfinite(u)) and np.all(np.isfinite(w))):
            raise ValueError("rpo: operator factors contain NaN or infinite values")
        return cls(order, u, w, cosine, np.asarray(arrays.get("singular_values", np.zeros(0)), np.float64),
                   float(arrays.get("view_fit_error", 0.0)), brdf or {})


def build_operator(brdf: materials.BRDF, order: int, rank: int, cosine: str = "brdf", resolution: int = 32,
                   view_order: int = VIEW_ORDER, z_nodes: int = Z_NODES, phi_nodes: int = PHI_NODES) -> ReflectanceOperator:
    """Tabulate, factor and project one BRDF (sec. 6, steps 1-4).

    Args:
        brdf: a :class:`~warpshade.scene._materials.BRDF` (analytic or tabulated).
        order: SH order n (1..8).
        rank: factors kept, k (1..n*n).
        cosine: :data:`COSINE_MODES`.
        resolution: view grid (resolution x resolution on the concentric square).
        view_order: SH order of the view factors (1..8).
        z_nodes, phi_nodes: hemisphere quadrature of the light integral.

    Raises:
        ValueError: a bad order, rank or cosine mode, or a BRDF whose table is not finite.
    """
    if cosine not in COSINE_MODES:
        raise ValueError(f"rpo: cosine must be one of {COSINE_MODES}, got {cosine!r}")
    if not 1 <= int(order) <= 8:
        raise ValueError(f"rpo: order must be in 1..8, got {order!r}")
    if not 1 <= int(rank) <= order * order:
        raise ValueError(f"rpo: rank k must be in 1..{order * order} for order {order}, got {rank!r}")
    if not 1 <= int(view_order) <= 8:
        raise ValueError(f"rpo: view_order must be in 1..8, got {view_order!r}")
    t0 = time.perf_counter()
    views = materials.view_grid(resolution)
    table = materials.brdf_matrix(brdf, order, views, z_nodes, phi_nodes, cosine=(cosine == "brdf"))
    if not np.all(np.isfinite(table)):
        raise ValueError(f"rpo: the BRDF {brdf.describe()} has non-finite values")
    fac = materials.factorize(brdf, order, rank, resolution, z_nodes, phi_nodes, matrix=table)
    w, err = fit_view_factors(views, fac.view_factors.reshape(-1, rank), int(view_order))
    return ReflectanceOperator(int(order), fac.rows.copy(), w, cosine, fac.singular_values, err, brdf.describe(),
                               time.perf_counter() - t0)


class OperatorCache:
    """Operators already built, by BRDF description and settings (most recent ``capacity``), so
    that swapping back to a material costs nothing and gives the same floats."""

    def __init__(self, capacity: int = 32):
        self.capacity = int(capacity)
        self._items: OrderedDict = OrderedDict()
        self.hits = 0
        self.misses = 0

    def get(self, brdf: materials.BRDF, order: int, rank: int, cosine: str = "brdf", resolution: int = 32,
            view_order: int = VIEW_ORDER) -> ReflectanceOperator:
        from ..._hashing import hash_json

        key = hash_json({"brdf": brdf.describe(), "order": int(order), "rank": int(rank), "cosine": cosine,
                         "resolution": int(resolution), "view_order": int(view_order)})
        op = self._items.get(key)
        if op is not None:
            self._items.move_to_end(key)
            self.hits += 1
            return op
        self.misses += 1
        op = build_operator(brdf, order, rank, cosine, resolution, view_order)
        self._items[key] = op
        while len(self._items) > self.capacity:
            self._items.popitem(last=False)
        return op
