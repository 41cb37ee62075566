"""The BRDF models of :mod:`warpshade.scene._materials` on the Warp device: evaluation, lobe
sampling and its pdf.

:func:`upload_brdf` turns a :class:`~warpshade.scene._materials.BRDF` into a :class:`BRDFParams`
``@wp.struct``; the ``@wp.func`` helpers take it with a unit normal ``n``, the unit direction
towards the viewer ``v`` and towards the light ``s``, all in world space (the models are
isotropic, so only dot products with ``n`` matter):

* :func:`brdf_eval` -- ``b(v, s)`` in 1/sr without the cosine factor, 0 when ``v`` or ``s`` is
  below the horizon: the float32 counterpart of ``BRDF.evaluate`` in the local frame of ``n``.
* :func:`brdf_sample` -- a direction ``s`` drawn from the model's lobe: the cosine lobe about
  ``n`` (Lambert); ``cos^p`` about the mirror direction ``r = 2 (n.v) n - v`` (Phong, pdf
  ``(p + 1) / (2 pi) cos^p``); a half vector ``h`` from ``cos^p theta_h`` (Blinn-Phong) or
  from ``D(h) cos theta_h`` (GGX: ``tan^2 theta_h = alpha^2 u / (1 - u)``; Beckmann:
  ``tan^2 theta_h = -alpha^2 ln(1 - u)``) reflected about ``h``, with the solid-angle pdf
  ``pdf_h / (4 |v.h|)``. Samples may fall below the horizon (their ``b`` is 0).
* :func:`brdf_pdf` -- that pdf for any ``s``.

Anisotropic models (:data:`ANISOTROPIC_MODELS`): anisotropic Ward (``ward``), the specular lobe
of Ashikhmin and Shirley (``ashikhmin-shirley``) and the anisotropic Beckmann microfacet BRDF
(``beckmann-anisotropic``: :class:`~warpshade.scene._materials.AnisotropicMicrofacet`) are
evaluated in the tangent frame ``(t, n x t, n)`` of a tangent direction ``b.tangent`` (world;
projected on the tangent plane of ``n`` and normalised inside, an orthonormal-basis tangent
where it is parallel to ``n``), which a receiver may override (:func:`brdf_with_tangent`). All
three sample a half vector from the anisotropic Beckmann slope distribution
(``phi_h = atan2(a_y sin 2 pi u2, a_x cos 2 pi u2)``, ``tan^2 theta_h = -ln(1 - u1) /
(cos^2 phi_h / a_x^2 + sin^2 phi_h / a_y^2)``, density ``D_B(h) cos theta_h``), with Ward's and
Beckmann's own ``a_x, a_y`` and, for Ashikhmin-Shirley, ``a = sqrt(2 / (n + 2))`` of its exponents.

Tabulated isotropic BRDFs (:class:`~warpshade.scene._tabulated.TabulatedBRDF`, model ``tabulated``):
one channel of the table in the MERL half/difference layout, flattened in ``table`` (invalid cells
negative), looked up "nearest" or "linear" exactly as the float64 class does (``table_dims``: the
three sizes and the interpolation). The angles come from world vectors: ``theta_h`` the angle of
``h`` from ``n``, ``d = (s . x_h, s . y_h, s . h)`` with ``y_h = (n x h) / |n x h|`` and
``x_h = y_h x h`` (the rotated frame ``R_z(phi_h) R_y(theta_h)`` of the module
:mod:`~warpshade.scene._tabulated`), ``phi_d`` folded into [0, pi). Sampling is a mixture: with
probability ``f0`` a GGX half vector of alpha ``roughness`` (a fit of the table's specular peak,
:func:`table_lobe`) reflected about ``h``, else the cosine lobe; the pdf is the mixture's, positive
wherever the table can be, so every estimator stays unbiased whatever the fit.
:func:`upload_brdf_passes` splits a colour table into one device BRDF per channel. Tabulated anisotropic
BRDFs (model ``tabulated-anisotropic``, code 9) are :mod:`~warpshade.scene._tabulated_aniso_warp`'s.

Spatially varying microfacet roughness: :func:`brdf_with_roughness` is a copy of a
:class:`BRDFParams` with its ``roughness`` replaced (a per-receiver value read from an array),
and :func:`check_roughness` validates such an array on the host (only the GGX and Beckmann
models have a roughness, :data:`ROUGH_MODELS`).
"""

from __future__ import annotations

import numpy as np

from .._wp import wp
from . import _materials as materials
from ._tabulated_aniso_warp import (ANISO_LOBE_WEIGHT, ANISO_TABLE_MODEL, aniso_table_eval, aniso_table_pdf,
                                   aniso_table_sample, clamped_axis, table_lobe_aniso, tangent_frame_from)

__all__ = [
    "ANISOTROPIC_MODELS",
    "BRDF_MODELS",
    "BRDFParams",
    "ROUGHNESS_MAX",
    "ROUGH_MODELS",
    "brdf_eval",
    "brdf_pdf",
    "brdf_sample",
    "brdf_with_roughness",
    "brdf_with_tangent",
    "check_reference_brdf",
    "check_roughness",
    "concentric_footprint",
    "hemisphere_to_concentric",
    "table_lobe",
    "upload_brdf",
    "upload_brdf_passes",
]

wp.set_module_options({"enable_backward": False})

#: Model codes of :class:`BRDFParams` (``model`` field), in this order.
BRDF_MODELS = ("lambert", "phong", "blinn-phong", "ggx", "beckmann", "ward", "ashikhmin-shirley", "beckmann-anisotropic",
               "tabulated", "tabulated-anisotropic", "svbrdf")
#: Model code of a tabulated BRDF (one channel of a MERL-layout table).
TABULATED_MODEL = 8
#: Model codes evaluated in a tangent frame (``roughness``/``roughness_y`` or ``exponent``/``exponent_y``).
ANISOTROPIC_MODELS = (5, 6, 7, ANISO_TABLE_MODEL)
#: Model codes whose ``roughness`` (microfacet alpha) a per-receiver array may override.
ROUGH_MODELS = (3, 4)
#: Valid microfacet alpha, as :class:`~warpshade.scene._materials.Microfacet` accepts it: (0, 2].
ROUGHNESS_MAX = 2.0


@wp.struct
class BRDFParams:
    """A BRDF on the device.

    Fields:
        model: index into :data:`BRDF_MODELS`.
        scale: the model's overall factor (Lambert albedo, ``specular`` of the others).
        exponent: Phong / Blinn-Phong exponent.
        roughness: microfacet alpha (Ward, anisotropic Beckmann: along the tangent);
        f0: Schlick's reflectance at normal incidence (Ashikhmin-Shirley: ``rs``).
        roughness_y: Ward's / anisotropic Beckmann's alpha along the bitangent.
        exponent_y: Ashikhmin-Shirley's ``nv`` (``exponent`` its ``nu``).
        tangent: the tangent direction of the anisotropic models, world (per receiver:
            :func:`brdf_with_tangent`).
        table: tabulated model: the address of one channel's BRDF values, float32, flat
            (n_theta_h * n_theta_d * n_phi_d,), phi_d fastest, negative = invalid cell (0 for the
            analytic models; an address, not an array, keeps the struct the analytic models pass
            around small); the host object holds the array as ``table_array``.
        table_dims: tabulated model: (n_theta_h, n_theta_d, n_phi_d, 1 for "linear" else 0).
        (The tabulated model samples with ``roughness`` its GGX alpha and ``f0`` the lobe's
        probability in its mixture with the cosine lobe.)
    """

    model: int
    scale: float
    exponent: float
    roughness: float
    f0: float
    roughness_y: float
    exponent_y: float
    tangent: wp.vec3
    table: wp.uint64
    table_dims: wp.vec4i


def upload_brdf(brdf: materials.BRDF, device=None) -> BRDFParams:
    """The :class:`BRDFParams` of a :mod:`~warpshade.scene._materials` BRDF, or of a one-channel
    :class:`~warpshade.scene._tabulated.TabulatedBRDF` (channel "r", "g", "b", or "luminance" when
    its channels share their invalid cells), whose table goes to ``device`` (None: Warp's default).

    Raises:
        ValueError: an unsupported BRDF, non-finite parameters, or a colour table (``channel =
            "rgb"``: :func:`upload_brdf_passes` gives one BRDF per channel).
    """
    from ._tabulated import TabulatedBRDF
    from ._tabulated_aniso import AnisotropicTable

    if isinstance(brdf, (TabulatedBRDF, AnisotropicTable)):
        passes = upload_brdf_passes(brdf, device)
        if len(passes) != 1:
            raise ValueError(f"upload_brdf: the table {brdf.source} is shaded per channel (channel {brdf.channel!r}); "
                             "use upload_brdf_passes")
        return passes[0][0]
    p = BRDFParams()
    p.exponent, p.roughness, p.f0 = 0.0, 1.0, 0.0
    p.roughness_y, p.exponent_y, p.tangent = 0.0, 0.0, wp.vec3(1.0, 0.0, 0.0)
    name = getattr(brdf, "name", "")
    if isinstance(brdf, materials.AnisotropicMicrofacet):
        p.model, p.scale, p.f0 = 7, float(brdf.specular), float(brdf.f0)
        p.roughness, p.roughness_y = float(brdf.roughness), float(brdf.roughness_y)
    elif name == "ward" and hasattr(brdf, "alpha_x"):
        # warpshade.methods.sg._brdf.Ward (a layer above: recognised by its attributes)
        p.model, p.scale = 5, float(brdf.specular)
        p.roughness, p.roughness_y = float(brdf.alpha_x), float(brdf.alpha_y)
    elif name == "ashikhmin-shirley" and hasattr(brdf, "nu"):
        p.model, p.scale, p.f0 = 6, float(brdf.specular), float(brdf.rs)
        p.exponent, p.exponent_y = float(brdf.nu), float(brdf.nv)
    elif isinstance(brdf, materials.Lambert):
        p.model, p.scale = 0, float(brdf.albedo)
    elif isinstance(brdf, materials.Phong):
        p.model, p.scale, p.exponent = 1, float(brdf.specular), float(brdf.exponent)
    elif isinstance(brdf, materials.BlinnPhong):
        p.model, p.scale, p.exponent = 2, float(brdf.specular), float(brdf.exponent)
    elif isinstance(brdf, materials.Microfacet):
        p.model = 3 if brdf.distribution == "ggx" else 4
        p.scale, p.roughness, p.f0 = float(brdf.specular), float(brdf.roughness), float(brdf.f0)
    else:
        raise ValueError(f"upload_brdf: unsupported BRDF {type(brdf).__name__} (models: {', '.join(BRDF_MODELS)})")
    if not all(np.isfinite([p.scale, p.exponent, p.roughness, p.f0, p.roughness_y, p.exponent_y])):
        raise ValueError(f"upload_brdf: non-finite parameters in {brdf!r}")
    p.table = wp.uint64(0)
    p.table_dims = wp.vec4i(0, 0, 0, 0)
    return p


def check_reference_brdf(brdf) -> None:
    """Raise ValueError saying why ``brdf`` has no device form (what the ray-traced reference
    shades: the models of :data:`BRDF_MODELS` and tabulated BRDFs), from the host alone: an
    analytic BRDF's :func:`upload_brdf` touches no device."""
    from ._tabulated import TabulatedBRDF
    from ._tabulated_aniso import AnisotropicTable

    if isinstance(brdf, (TabulatedBRDF, AnisotropicTable)):
        return
    try:
        upload_brdf(brdf)
    except ValueError as exc:
        raise ValueError(f"the ray-traced glossy reference does not shade BRDF "
                         f"{getattr(brdf, 'name', type(brdf).__name__)!r}: {exc}") from None


#: Largest probability of the fitted GGX lobe in a tabulated BRDF's sampling mixture (the rest is
#: the cosine lobe, which keeps the pdf positive over the hemisphere) and the smallest.
TABLE_LOBE_WEIGHT = (0.1, 0.9)
#: Range of the fitted GGX alpha of a tabulated BRDF's sampling lobe.
TABLE_LOBE_ALPHA = (0.01, 1.0)
#: theta_d below which the table's cells are taken as the specular peak's profile D(theta_h) (radians).
TABLE_FIT_THETA_D = np.radians(10.0)


def table_lobe(table: np.ndarray) -> tuple[float, float]:
    """``(alpha, weight)`` of the sampling mixture of one channel of a MERL-layout table
    (n_theta_h, n_theta_d, n_phi_d), float64, invalid cells negative.

    Near the specular configuration (``theta_d`` below :data:`TABLE_FIT_THETA_D`, ``v ~ s ~ h``) a
    microfacet BRDF is ``D(theta_h) F G / (4 cos^2 theta_h)``, so the profile ``f(theta_h)`` of those
    cells (mean over valid phi_d) less its floor (the smallest value, a diffuse part), times
    ``cos^2 theta_h``, is taken as the NDF. A Beckmann fit ``log D = c - tan^2 theta_h / alpha^2``
    (weighted least squares, cells above 1e-3 of the peak, weights the values) gives ``alpha``;
    ``weight`` is the lobe's share of the normal-incidence albedo of the profile, both clamped
    (:data:`TABLE_LOBE_ALPHA`, :data:`TABLE_LOBE_WEIGHT`). Only the variance depends on them.
    """
    from ._tabulated import merl_cell_centres

    table = np.asarray(table, np.float64)
    dims = table.shape
    theta_h, theta_d, _ = merl_cell_centres(dims)
    rows = np.nonzero(theta_d < TABLE_FIT_THETA_D)[0]
    rows = rows if rows.size else np.array([0])
    cells = table[:, rows, :]
    valid = cells >= 0.0
    count = valid.sum(axis=(1, 2))
    profile = np.where(count > 0, np.where(valid, cells, 0.0).sum(axis=(1, 2)) / np.maximum(count, 1), np.nan)
    # cells whose mirror direction at normal view (2 theta_h) stays above the horizon
    ok = np.isfinite(profile) & (theta_h < np.radians(44.0))
    lo_w, hi_w = TABLE_LOBE_WEIGHT
    lo_a, hi_a = TABLE_LOBE_ALPHA
    if ok.sum() < 2:
        return 0.5, lo_w
    th, f = theta_h[ok], profile[ok]
    floor = float(f.min())
    lobe = np.maximum(f - floor, 0.0)
    ndf = lobe * np.cos(th) ** 2
    keep = ndf > 1e-3 * ndf.max() if ndf.max() > 0.0 else np.zeros(ndf.shape, bool)
    if keep.sum() < 2:
        return 0.5, lo_w
    x, y, w = np.tan(th[keep]) ** 2, np.log(ndf[keep]), ndf[keep]
    xm, ym = np.average(x, weights=w), np.average(y, weights=w)
    var = np.average((x - xm) ** 2, weights=w)
    slope = np.average((x - xm) * (y - ym), weights=w) / var if var > 0.0 else -np.inf
    alpha = float(np.clip(np.sqrt(-1.0 / slope), lo_a, hi_a)) if slope < 0.0 else lo_a
    # normal-incidence albedo of the profile: s = the mirror of n about h, at 2 theta_h
    edges = (np.arange(dims[0] + 1) / dims[0]) ** 2 * (np.pi / 2.0)  # cell edges of the sqrt mapping
    width = np.diff(edges)[ok]
    jac = np.cos(2.0 * th) * 4.0 * np.cos(th) * 2.0 * np.pi * np.sin(th) * width
    total = float(np.sum(f * jac))
    weight = float(np.sum(lobe * jac)) / total if total > 0.0 else lo_w
    return alpha, float(np.clip(weight, lo_w, hi_w))


def _channel_tables(brdf) -> list[tuple[np.ndarray, np.ndarray]]:
    """(one-channel table, RGB output weights) per pass of a TabulatedBRDF."""
    from ._tabulated import LUMINANCE_WEIGHTS

    t = brdf.table
    if brdf.channel == "rgb":
        return [(t[c], np.eye(3)[c]) for c in range(3)]
    if brdf.channel in ("r", "g", "b"):
        return [(t["rgb".index(brdf.channel)], np.ones(3))]
    invalid = t < 0.0
    if np.array_equal(invalid[0], invalid[1]) and np.array_equal(invalid[0], invalid[2]):
        # the same cells valid in every channel: the luminance of the values is the luminance table
        lum = np.tensordot(np.asarray(LUMINANCE_WEIGHTS), np.maximum(t, 0.0), axes=1)
        return [(np.where(invalid[0], -1.0, lum), np.ones(3))]
    return [(t[c], np.full(3, LUMINANCE_WEIGHTS[c])) for c in range(3)]


def _upload_aniso_table(brdf, device=None) -> list:
    """``[(BRDFParams, (1, 1, 1))]``: the one device pass of an
    :class:`~warpshade.scene._tabulated_aniso.AnisotropicTable` (its :meth:`scalar_table`)."""
    from .._wp import resolve_device

    dev = resolve_device(device)
    values = brdf.scalar_table()
    ax, ay = table_lobe_aniso(values)
    p = BRDFParams()
    p.model, p.scale, p.exponent, p.exponent_y = ANISO_TABLE_MODEL, 1.0, 1.0 if brdf.interpolation == "linear" else 0.0, 0.0
    p.roughness, p.roughness_y, p.f0, p.tangent = ax, ay, ANISO_LOBE_WEIGHT, wp.vec3(1.0, 0.0, 0.0)
    array = wp.array(np.ascontiguousarray(values, np.float32).reshape(-1), dtype=float, device=dev)
    p.table = wp.uint64(array.ptr)
    p.table_dims = wp.vec4i(*brdf.dims)
    object.__setattr__(p, "table_array", array)  # the device table lives as long as the params
    return [(p, np.ones(3))]


def upload_brdf_passes(brdf: materials.BRDF, device=None) -> list[tuple[BRDFParams, np.ndarray]]:
    """The device BRDFs whose shadings, times their RGB weights and summed, shade ``brdf``:
    ``[(upload_brdf(brdf), (1, 1, 1))]`` for an analytic BRDF; for a
    :class:`~warpshade.scene._tabulated.TabulatedBRDF` one pass per table channel it needs
    (``"rgb"``: the three channels, weights the unit RGB vectors; one channel: that one, weights
    1; ``"luminance"``: the luminance table, or the three channels weighted by
    :data:`~warpshade.scene._tabulated.LUMINANCE_WEIGHTS` when their invalid cells differ).
    Each table pass has its own sampling lobe (:func:`table_lobe`)."""
    from .._wp import resolve_device
    from ._tabulated import TabulatedBRDF
    from ._tabulated_aniso import AnisotropicTable

    if isinstance(brdf, AnisotropicTable):  # tabulated anisotropic: one pass (tabulated_aniso_warp)
        return _upload_aniso_table(brdf, device)
    if not isinstance(brdf, TabulatedBRDF):
        return [(upload_brdf(brdf), np.ones(3))]
    dev = resolve_device(device)
    n_th, n_td, n_pd = brdf.dims
    out = []
    for values, weights in _channel_tables(brdf):
        alpha, weight = table_lobe(values)
        p = BRDFParams()
        p.model, p.scale, p.exponent, p.roughness, p.f0 = TABULATED_MODEL, 1.0, 0.0, alpha, weight
        p.roughness_y, p.exponent_y, p.tangent = 0.0, 0.0, wp.vec3(1.0, 0.0, 0.0)
        array = wp.array(np.ascontiguousarray(values, np.float32).reshape(-1), dtype=float, device=dev)
        p.table = wp.uint64(array.ptr)
        p.table_dims = wp.vec4i(n_th, n_td, n_pd, 1 if brdf.interpolation == "linear" else 0)
        object.__setattr__(p, "table_array", array)  # the device table lives as long as the params
        out.append((p, np.asarray(weights, np.float64)))
    return out


def check_roughness(values, count: int, brdf: BRDFParams, name: str, caller: str) -> np.ndarray:
    """Validate per-receiver microfacet roughness on the host.

    Args:
        values: alpha per receiver, array-like or wp.array(float) of shape (count,).
        count: the number of receivers (points) the array is indexed like.
        brdf: the uploaded BRDF whose roughness the values override (GGX or Beckmann).
        name, caller: the parameter and function named in error messages.

    Returns:
        The values as a contiguous float32 array of shape (count,).

    Raises:
        ValueError: the BRDF has no roughness, the shape is not (count,), or a value is not
            finite or outside (0, 2].
    """
    if brdf.model not in ROUGH_MODELS:
        raise ValueError(f"{caller}: {name} overrides a microfacet roughness, but the BRDF is "
                         f"{BRDF_MODELS[brdf.model]!r} (models with a roughness: ggx, beckmann)")
    arr = values.numpy() if isinstance(values, wp.array) else np.asarray(values)
    if arr.shape != (count,):
        raise ValueError(f"{caller}: {name} must have shape ({count},), got {arr.shape}")
    arr = np.ascontiguousarray(arr, dtype=np.float32)
    bad = ~(np.isfinite(arr) & (arr > 0.0) & (arr <= ROUGHNESS_MAX))
    if np.any(bad):
        first = int(np.argmax(bad))
        raise ValueError(f"{caller}: {name} must be finite and in (0, {ROUGHNESS_MAX:g}]; "
                         f"{int(bad.sum())} values are not (first: [{first}] = {arr[first]!r})")
    return arr


@wp.func
def brdf_with_roughness(b: BRDFParams, roughness: float) -> BRDFParams:
    """A copy of ``b`` with its microfacet alpha replaced by ``roughness`` (every other field kept)."""
    out = BRDFParams()
    out.model = b.model
    out.scale = b.scale
    out.exponent = b.exponent
    out.roughness = roughness
    out.f0 = b.f0
    out.roughness_y = b.roughness_y
    out.exponent_y = b.exponent_y
    out.tangent = b.tangent
    out.table = b.table
    out.table_dims = b.table_dims
    return out


@wp.func
def brdf_with_tangent(b: BRDFParams, tangent: wp.vec3) -> BRDFParams:
    """A copy of ``b`` with its tangent direction (anisotropic models) replaced."""
    out = brdf_with_roughness(b, b.roughness)
    out.tangent = tangent
    return out


@wp.func
def tangent_frame(b: BRDFParams, n: wp.vec3) -> wp.mat33:
    """Rows (t, n x t, n): ``b.tangent`` projected on the tangent plane of ``n``, normalised (an
    orthonormal-basis tangent where it is parallel to ``n``)."""
    return tangent_frame_from(b.tangent, n)


@wp.func
def _slope_alphas(b: BRDFParams) -> wp.vec2:
    """(a_x, a_y) of the anisotropic Beckmann slope distribution the anisotropic models sample."""
    if b.model == 6:
        return wp.vec2(wp.sqrt(2.0 / (b.exponent + 2.0)), wp.sqrt(2.0 / (b.exponent_y + 2.0)))
    return wp.vec2(b.roughness, b.roughness_y)


@wp.func
def _beckmann_aniso_d(h: wp.vec3, ax: float, ay: float) -> float:
    """Anisotropic Beckmann ``exp(-(h_x^2 / a_x^2 + h_y^2 / a_y^2) / h_z^2) / (pi a_x a_y h_z^4)`` (local h)."""
    z = h[2]
    if z <= 1.0e-6:
        return 0.0
    z2 = z * z
    q = (h[0] * h[0] / (ax * ax) + h[1] * h[1] / (ay * ay)) / z2
    return wp.exp(-q) / (wp.pi * ax * ay * z2 * z2)


@wp.func
def _beckmann_aniso_lambda(w: wp.vec3, ax: float, ay: float) -> float:
    """Smith's Lambda of the anisotropic Beckmann distribution (rational fit) for a local direction."""
    c = wp.clamp(w[2], 1.0e-6, 1.0)
    s2 = wp.max(1.0 - c * c, 0.0)
    if s2 <= 0.0:
        return 0.0
    alpha = wp.sqrt((w[0] * w[0] * ax * ax + w[1] * w[1] * ay * ay) / s2)
    a = c / (alpha * wp.sqrt(s2))
    if a >= 1.6:
        return 0.0
    return (1.0 - 1.259 * a + 0.396 * a * a) / (3.535 * a + 2.181 * a * a)


@wp.func
def _anisotropic_eval(b: BRDFParams, n: wp.vec3, v: wp.vec3, s: wp.vec3) -> float:
    """Models 5-7 (``v``, ``s`` above the horizon of ``n``)."""
    frame = tangent_frame(b, n)
    vl = frame * v
    sl = frame * s
    h = vl + sl
    hl = wp.length(h)
    if hl <= 1.0e-12:
        return 0.0
    h = h / hl
    co = wp.max(vl[2], 1.0e-6)
    ci = wp.max(sl[2], 1.0e-6)
    if b.model == 5:
        if h[2] <= 0.0:
            return 0.0
        q = (h[0] * h[0] / (b.roughness * b.roughness) + h[1] * h[1] / (b.roughness_y * b.roughness_y)) / (h[2] * h[2])
        return b.scale * wp.exp(-q) / (4.0 * wp.pi * b.roughness * b.roughness_y * wp.sqrt(co * ci))
    oh = wp.clamp(wp.dot(vl, h), 0.0, 1.0)
    if b.model == 6:
        z = wp.clamp(h[2], 0.0, 1.0)
        if z <= 0.0:
            return 0.0
        r2 = h[0] * h[0] + h[1] * h[1]
        e = 0.5 * (b.exponent + b.exponent_y)
        if r2 > 1.0e-12:
            e = (b.exponent * h[0] * h[0] + b.exponent_y * h[1] * h[1]) / r2
        norm = b.scale * wp.sqrt((b.exponent + 1.0) * (b.exponent_y + 1.0)) / (8.0 * wp.pi)
        x = 1.0 - oh
        x2 = x * x
        f = b.f0 + (1.0 - b.f0) * x2 * x2 * x
        return norm * wp.exp(e * wp.log(z)) * f / (wp.max(oh, 1.0e-6) * wp.max(co, ci))
    d = _beckmann_aniso_d(h, b.roughness, b.roughness_y)
    fresnel = b.f0 + (1.0 - b.f0) * wp.pow(1.0 - oh, 5.0)
    g = 1.0 / ((1.0 + _beckmann_aniso_lambda(vl, b.roughness, b.roughness_y)) *
               (1.0 + _beckmann_aniso_lambda(sl, b.roughness, b.roughness_y)))
    return b.scale * d * fresnel * g / (4.0 * co * ci)


@wp.func
def _anisotropic_half(b: BRDFParams, n: wp.vec3, u1: float, u2: float) -> wp.vec3:
    """A world half vector from the anisotropic Beckmann slope distribution of :func:`_slope_alphas`."""
    al = _slope_alphas(b)
    ang = 2.0 * wp.pi * u2
    phi = wp.atan2(al[1] * wp.sin(ang), al[0] * wp.cos(ang))
    cp = wp.cos(phi)
    sp = wp.sin(phi)
    tan2 = -wp.log(wp.max(1.0 - u1, 1.0e-30)) / (cp * cp / (al[0] * al[0]) + sp * sp / (al[1] * al[1]))
    cos_t = 1.0 / wp.sqrt(1.0 + tan2)
    sin_t = wp.sqrt(wp.max(0.0, 1.0 - cos_t * cos_t))
    frame = tangent_frame(b, n)
    return wp.normalize(wp.transpose(frame) * wp.vec3(sin_t * cp, sin_t * sp, cos_t))


@wp.func
def _anisotropic_half_pdf(b: BRDFParams, n: wp.vec3, h: wp.vec3) -> float:
    """Density per steradian of :func:`_anisotropic_half` at the world half vector ``h``."""
    al = _slope_alphas(b)
    hl = tangent_frame(b, n) * h
    return _beckmann_aniso_d(hl, al[0], al[1]) * wp.max(hl[2], 0.0)


# ---- tabulated (MERL-layout) BRDFs ------------------------------------------------------------


@wp.func
def _table_cell(b: BRDFParams, i: int, j: int, k: int) -> float:
    values = wp.array(ptr=b.table, shape=(b.table_dims[0] * b.table_dims[1] * b.table_dims[2],), dtype=float)
    return values[(i * b.table_dims[1] + j) * b.table_dims[2] + k]


@wp.func
def _tabulated_eval(b: BRDFParams, n: wp.vec3, v: wp.vec3, s: wp.vec3) -> float:
    """One channel of a tabulated BRDF (``v``, ``s`` above the horizon of ``n``): the
    :class:`~warpshade.scene._tabulated.TabulatedBRDF` lookup, "nearest" or "linear"."""
    h = v + s
    hl = wp.length(h)
    if hl <= 1.0e-12:
        h = n
    else:
        h = h / hl
    c = wp.cross(n, h)
    sin_h = wp.length(c)
    theta_h = wp.atan2(sin_h, wp.dot(n, h))
    yh = wp.vec3(0.0)
    if sin_h > 1.0e-12:
        yh = c / sin_h
    else:  # h on the normal: phi_h = 0 of an orthonormal basis (any azimuth, as the table is isotropic)
        sign = wp.where(n[2] >= 0.0, 1.0, -1.0)
        a = -1.0 / (sign + n[2])
        yh = wp.vec3(n[0] * n[1] * a, sign + n[1] * n[1] * a, -n[1])
    xh = wp.cross(yh, h)
    dx = wp.dot(s, xh)
    dy = wp.dot(s, yh)
    theta_d = wp.atan2(wp.sqrt(dx * dx + dy * dy), wp.dot(s, h))
    phi_d = wp.atan2(dy, dx)
    if phi_d < 0.0:
        phi_d += wp.pi
    n_th = b.table_dims[0]
    n_td = b.table_dims[1]
    n_pd = b.table_dims[2]
    half_pi = 0.5 * wp.pi
    ui = wp.sqrt(wp.max(theta_h, 0.0) / half_pi) * float(n_th)
    uj = theta_d / half_pi * float(n_td)
    uk = phi_d / wp.pi * float(n_pd)
    if b.table_dims[3] == 0:
        i = wp.clamp(int(wp.floor(ui)), 0, n_th - 1)
        j = wp.clamp(int(wp.floor(uj)), 0, n_td - 1)
        k = wp.clamp(int(wp.floor(uk)), 0, n_pd - 1)
        return b.scale * wp.max(_table_cell(b, i, j, k), 0.0)
    ai = clamped_axis(ui - 0.5, n_th)
    aj = clamped_axis(uj - 0.5, n_td)
    fk = wp.floor(uk - 0.5)
    tk = uk - 0.5 - fk
    k0 = int(fk) % n_pd
    if k0 < 0:
        k0 += n_pd
    k1 = (k0 + 1) % n_pd
    num = float(0.0)
    den = float(0.0)
    for ci in range(2):
        i = int(ai[ci])
        wi = wp.where(ci == 0, 1.0 - ai[2], ai[2])
        for cj in range(2):
            j = int(aj[cj])
            wj = wp.where(cj == 0, 1.0 - aj[2], aj[2])
            for ck in range(2):
                k = wp.where(ck == 0, k0, k1)
                w = wi * wj * wp.where(ck == 0, 1.0 - tk, tk)
                val = _table_cell(b, i, j, k)
                if val >= 0.0:  # invalid cells are left out of the blend
                    num += w * val
                    den += w
    if den > 0.0:
        return b.scale * num / den
    return 0.0


@wp.func
def _ggx_half_pdf(alpha: float, cos_h: float) -> float:
    """``D_GGX(h) cos theta_h`` (per steradian of the half vector); 0 below the horizon."""
    if cos_h <= 0.0:
        return 0.0
    a2 = alpha * alpha
    c2 = cos_h * cos_h
    t = c2 * (a2 - 1.0) + 1.0
    return a2 / (wp.pi * t * t) * cos_h


@wp.func
def _tabulated_sample(b: BRDFParams, n: wp.vec3, v: wp.vec3, u1: float, u2: float) -> wp.vec3:
    """The tabulated model's mixture: the GGX lobe with probability ``b.f0``, else the cosine lobe."""
    phi = 2.0 * wp.pi * u2
    w = b.f0
    if u1 < w:
        u = u1 / w
        a2 = b.roughness * b.roughness
        tan2 = a2 * u / wp.max(1.0 - u, 1.0e-12)
        h = _about(n, 1.0 / wp.sqrt(1.0 + tan2), phi)
        return wp.normalize(2.0 * wp.dot(v, h) * h - v)
    u = (u1 - w) / (1.0 - w)
    return _about(n, wp.sqrt(wp.clamp(1.0 - u, 0.0, 1.0)), phi)


@wp.func
def _tabulated_pdf(b: BRDFParams, n: wp.vec3, v: wp.vec3, s: wp.vec3) -> float:
    """Solid-angle pdf of :func:`_tabulated_sample`."""
    pdf = (1.0 - b.f0) * wp.max(wp.dot(n, s), 0.0) / wp.pi
    h = v + s
    hl = wp.length(h)
    if hl > 1.0e-12:
        h = h / hl
        vh = wp.abs(wp.dot(v, h))
        if vh > 1.0e-12:
            pdf += b.f0 * _ggx_half_pdf(b.roughness, wp.dot(n, h)) / (4.0 * vh)
    return pdf


@wp.func
def _distribution(b: BRDFParams, cos_h: float) -> float:
    """Normal distribution D(h) of the microfacet models."""
    a2 = b.roughness * b.roughness
    c2 = wp.clamp(cos_h, 1.0e-6, 1.0)
    c2 = c2 * c2
    if b.model == 3:
        t = c2 * (a2 - 1.0) + 1.0
        return a2 / (wp.pi * t * t)
    tan2 = (1.0 - c2) / c2
    return wp.exp(-tan2 / a2) / (wp.pi * a2 * c2 * c2)


@wp.func
def _smith_lambda(b: BRDFParams, cos_w: float) -> float:
    c = wp.clamp(cos_w, 1.0e-6, 1.0)
    tan2 = (1.0 - c * c) / (c * c)
    if b.model == 3:
        return 0.5 * (wp.sqrt(1.0 + b.roughness * b.roughness * tan2) - 1.0)
    if tan2 <= 0.0:
        return 0.0
    a = 1.0 / (b.roughness * wp.sqrt(tan2))
    if a >= 1.6:
        return 0.0
    return (1.0 - 1.259 * a + 0.396 * a * a) / (3.535 * a + 2.181 * a * a)


@wp.func
def brdf_eval(b: BRDFParams, n: wp.vec3, v: wp.vec3, s: wp.vec3) -> float:
    """``b(v, s)`` (1/sr, no cosine) about the unit normal ``n``; 0 below either horizon."""
    nv = wp.dot(n, v)
    ns = wp.dot(n, s)
    if nv <= 0.0 or ns <= 0.0:
        return 0.0
    if b.model == 0:
        return b.scale / wp.pi
    if b.model == 1:
        r = 2.0 * nv * n - v
        c = wp.max(wp.dot(r, s), 0.0)
        return b.scale * (b.exponent + 2.0) / (2.0 * wp.pi) * wp.pow(c, b.exponent)
    if b.model >= 5:
        if b.model == 8:
            return _tabulated_eval(b, n, v, s)
        if b.model == ANISO_TABLE_MODEL:
            return aniso_table_eval(b.table, b.table_dims, b.exponent, b.tangent, n, v, s)
        return _anisotropic_eval(b, n, v, s)
    h = v + s
    hl = wp.length(h)
    if hl <= 1.0e-12:
        return 0.0
    h = h / hl
    nh = wp.max(wp.dot(n, h), 0.0)
    if b.model == 2:
        return b.scale * (b.exponent + 8.0) / (8.0 * wp.pi) * wp.pow(nh, b.exponent)
    vh = wp.clamp(wp.dot(v, h), 0.0, 1.0)
    fresnel = b.f0 + (1.0 - b.f0) * wp.pow(1.0 - vh, 5.0)
    g = 1.0 / ((1.0 + _smith_lambda(b, nv)) * (1.0 + _smith_lambda(b, ns)))
    return b.scale * _distribution(b, nh) * fresnel * g / (4.0 * wp.max(nv, 1.0e-6) * wp.max(ns, 1.0e-6))


@wp.func
def _about(axis: wp.vec3, cos_t: float, phi: float) -> wp.vec3:
    """Unit direction at polar angle acos(cos_t) and azimuth phi about a unit axis."""
    sign = wp.where(axis[2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + axis[2])
    bb = axis[0] * axis[1] * a
    t = wp.vec3(1.0 + sign * axis[0] * axis[0] * a, sign * bb, -sign * axis[0])
    u = wp.cross(axis, t)
    sin_t = wp.sqrt(wp.max(0.0, 1.0 - cos_t * cos_t))
    return wp.normalize(sin_t * wp.cos(phi) * t + sin_t * wp.sin(phi) * u + cos_t * axis)


@wp.func
def _half_cos(b: BRDFParams, u1: float) -> float:
    """cos theta_h of a half vector drawn from the model's distribution (models 2-4)."""
    if b.model == 2:
        return wp.pow(wp.max(u1, 1.0e-30), 1.0 / (b.exponent + 1.0))
    a2 = b.roughness * b.roughness
    tan2 = float(0.0)
    if b.model == 3:
        tan2 = a2 * u1 / wp.max(1.0 - u1, 1.0e-12)
    else:
        tan2 = -a2 * wp.log(wp.max(1.0 - u1, 1.0e-30))
    return 1.0 / wp.sqrt(1.0 + tan2)


@wp.func
def _half_pdf(b: BRDFParams, cos_h: float) -> float:
    """Density of the half vector per steradian (models 2-4)."""
    if b.model == 2:
        return (b.exponent + 1.0) / (2.0 * wp.pi) * wp.pow(wp.max(cos_h, 0.0), b.exponent)
    return _distribution(b, cos_h) * wp.max(cos_h, 0.0)


@wp.func
def brdf_sample(b: BRDFParams, n: wp.vec3, v: wp.vec3, u1: float, u2: float) -> wp.vec3:
    """A direction from the model's lobe (see module docstring); u1, u2 uniform in [0, 1)."""
    phi = 2.0 * wp.pi * u2
    if b.model == 0:
        return _about(n, wp.sqrt(wp.max(0.0, 1.0 - u1)), phi)
    if b.model == 1:
        r = 2.0 * wp.dot(n, v) * n - v
        return _about(wp.normalize(r), wp.pow(wp.max(u1, 1.0e-30), 1.0 / (b.exponent + 1.0)), phi)
    if b.model >= 5:
        if b.model == 8:
            return _tabulated_sample(b, n, v, u1, u2)
        if b.model == ANISO_TABLE_MODEL:
            return aniso_table_sample(b.roughness, b.roughness_y, b.f0, b.tangent, n, v, u1, u2)
        ha = _anisotropic_half(b, n, u1, u2)
        return wp.normalize(2.0 * wp.dot(v, ha) * ha - v)
    h = _about(n, _half_cos(b, u1), phi)
    return wp.normalize(2.0 * wp.dot(v, h) * h - v)


@wp.func
def brdf_pdf(b: BRDFParams, n: wp.vec3, v: wp.vec3, s: wp.vec3) -> float:
    """Solid-angle pdf of :func:`brdf_sample` at ``s``."""
    if b.model == 0:
        return wp.max(wp.dot(n, s), 0.0) / wp.pi
    if b.model == 1:
        r = wp.normalize(2.0 * wp.dot(n, v) * n - v)
        c = wp.max(wp.dot(r, s), 0.0)
        return (b.exponent + 1.0) / (2.0 * wp.pi) * wp.pow(c, b.exponent)
    h = v + s
    hl = wp.length(h)
    if hl <= 1.0e-12:
        return 0.0
    h = h / hl
    vh = wp.abs(wp.dot(v, h))
    if vh <= 1.0e-12:
        return 0.0
    if b.model >= 5:
        # the tabulated model's cosine part is 0 where the early returns above fire (s = -v, below
        # the horizon of a viewer above it), so it may branch here, off the analytic models' path
        if b.model == 8:
            return _tabulated_pdf(b, n, v, s)
        if b.model == ANISO_TABLE_MODEL:
            return aniso_table_pdf(b.roughness, b.roughness_y, b.f0, b.tangent, n, v, s)
        return _anisotropic_half_pdf(b, n, h) / (4.0 * vh)
    return _half_pdf(b, wp.dot(n, h)) / (4.0 * vh)


@wp.func
def hemisphere_to_concentric(d: wp.vec3) -> wp.vec2:
    """A unit local direction -> the concentric square ``[-1, 1]^2``: the Warp mirror of
    :func:`warpshade.scene._materials.hemisphere_to_concentric` (the lower hemisphere is clamped to
    the horizon)."""
    z = wp.clamp(d[2], 0.0, 1.0)
    r = wp.sqrt(1.0 - z)
    phi = wp.atan2(d[1], d[0])
    quarter = 0.25 * wp.pi
    if phi < -quarter:
        phi += 2.0 * wp.pi
    a = float(0.0)
    b = float(0.0)
    if phi < quarter:
        a = r
        b = r * phi / quarter
    elif phi < 3.0 * quarter:
        b = r
        a = r * (0.5 * wp.pi - phi) / quarter
    elif phi < 5.0 * quarter:
        a = -r
        b = -r * (phi - wp.pi) / quarter
    else:
        b = -r
        a = -r * (1.5 * wp.pi - phi) / quarter
    return wp.vec2(a, b)


@wp.func
def concentric_footprint(ab: wp.vec2, res: int) -> wp.vec4:
    """The bilinear footprint of a point ``ab`` of the concentric square on a ``res`` x ``res``
    texture whose texel centres are ``(i + 0.5) / res * 2 - 1`` (``res >= 2``): ``(ia, ib, ta,
    tb)`` with texels ``ia, ia + 1`` along ``a`` and ``ib, ib + 1`` along ``b`` (as floats) and
    their weights ``ta``, ``tb`` in [0, 1], clamped at the edges."""
    fa = (ab[0] + 1.0) * 0.5 * float(res) - 0.5
    fb = (ab[1] + 1.0) * 0.5 * float(res) - 0.5
    ia = wp.clamp(int(wp.floor(fa)), 0, res - 2)
    ib = wp.clamp(int(wp.floor(fb)), 0, res - 2)
    return wp.vec4(float(ia), float(ib), wp.clamp(fa - float(ia), 0.0, 1.0), wp.clamp(fb - float(ib), 0.0, 1.0))
