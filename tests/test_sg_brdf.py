"""SG reflectance (Wang et al. 2009, sec. 4): exact models, NDF lobes, fits, the spherical warp and
its Warp mirror.

Oracles: Gauss-Legendre quadrature of the exact NDFs and slices, the existing
``scene.materials.Microfacet`` (Beckmann), the s/p-polarised Fresnel equations with Snell's law,
synthetic SG mixtures with known parameters, and the float64 ``view_slice`` for the kernel.
"""

import math

import numpy as np
import pytest

from warpshade._wp import wp
from warpshade.basis.sg import SGMixture
from warpshade.methods.sg import _brdf as brdf, _slices as slices
from warpshade.methods.sg import _ndf as sg_ndf
from warpshade.methods.sg import _brdf_warp as brdf_warp
from warpshade.scene._materials import Microfacet, hemisphere_quadrature

# M_o * D against Microfacet.evaluate: the same float64 products in another order (measured 4e-13).
RTOL_FACTORISATION = 1e-12
# Products that underflow into float64 subnormals (< 2.2e-308) lose relative precision: absolute floor.
ATOL_SUBNORMAL = 1e-300
# Closed-form lobes against the exact NDFs, relative L2 over the hemisphere of h, per unit of the
# parameter's square (measured: CT 0.103 m^2, Beckmann "normalized" 0.47 a^2, Ward 0.92 alpha^2,
# Blinn-Phong 0.61 / p; 25 % margin). Valid for m, a, alpha <= 0.5 and p >= 10.
CT_ERR_PER_M2 = 0.13
BECKMANN_ERR_PER_A2 = 0.6
WARD_ERR_PER_A2 = 1.15
BLINN_ERR_TIMES_P = 0.77
# Fitting a mixture to an exactly representable target: L-BFGS-B / LM stop far below this.
EXACT_FIT_REL = 1e-4
# Recovered parameters of an exactly representable target (relative; axes absolute).
RECOVER_RTOL = 1e-3
# Slice error (times cosine) at normal view for moderate roughness (measured 0.044 CT m = 0.2,
# 0.059 Beckmann a = 0.2, 0.021 Blinn-Phong p = 50, 0.022 Ward alpha = 0.2).
SLICE_ERR_NORMAL = 0.08
# Blinn-Phong p = 1e4 against the sharp-lobe limit of the slice error (measured 1e-3 relative at
# 75 deg, 1e-5 at 30 deg; the residue is the lobe's finite width).
SHARP_FLOOR_RTOL = 5e-3
# Independent quadratures of the same slice error agree to this (both converged to ~1e-4).
QUADRATURE_ATOL = 2e-3
# float32 kernel against float64: axes (unit vectors) absolute; sharpness and amplitude relative
# (Schlick's (1 - c)^5 and the Smith rational in float32; measured 6e-6). The relative bound is
# looser than the shared tolerances.RTOL_FLOAT32 (2e-5): near grazing, 1 - c and the Smith
# rational's small denominators lose float32 digits that O(1) kernels keep.
ATOL_AXIS_FLOAT32 = 1e-6
RTOL_BRDF_FLOAT32 = 5e-5


def _view(theta_deg, phi_deg=0.0):
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def _random_hemisphere(rng, count, min_z=0.0):
    v = rng.normal(size=(count, 3))
    v[:, 2] = np.abs(v[:, 2]) + min_z
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _isotropic_l2_error(model, params, nodes=800, upper=0.5 * np.pi):
    """Relative L2 error of the closed-form lobe against the exact NDF over the cap theta_h <= upper
    (default the hemisphere; 1-D Gauss-Legendre in theta_h, split at 12 lobe widths; both
    functions are isotropic)."""
    lobes = sg_ndf.ndf_lobes(model, **params)
    assert lobes.lobe_count == 1 and np.allclose(lobes.axes, [[0, 0, 1]])
    x, w = np.polynomial.legendre.leggauss(nodes)
    split = min(upper, 12.0 / math.sqrt(lobes.sharpness[0]))
    t, wt = [], []
    for lo, hi in ((0.0, split), (split, upper)):
        if hi - lo > 1e-9:
            t.append(lo + 0.5 * (hi - lo) * (x + 1.0))
            wt.append(0.5 * (hi - lo) * w)
    t, wt = np.concatenate(t), np.concatenate(wt) * 2.0 * np.pi * np.sin(np.concatenate(t))
    h = np.stack([np.sin(t), np.zeros_like(t), np.cos(t)], -1)
    if model == "cook-torrance":  # its D is defined over the whole sphere: exp(-(theta / m)^2)
        d = np.exp(-((t / params["m"]) ** 2))
    else:
        d = brdf.ndf_exact(model, h, **params)
    return math.sqrt(wt @ (lobes.evaluate(h) - d) ** 2 / (wt @ d**2))


# ---- exact models and the factorisation rho = M_o D -------------------------------------------


@pytest.mark.parametrize("roughness", [0.05, 0.3, 1.2])
def test_beckmann_factor_reproduces_microfacet(rng, roughness):
    o, i = _random_hemisphere(rng, 2000), _random_hemisphere(rng, 2000)
    h = (o + i) / np.linalg.norm(o + i, axis=1, keepdims=True)
    params = {"roughness": roughness, "f0": 0.08, "specular": 0.7}
    ref = Microfacet(roughness=roughness, distribution="beckmann", f0=0.08, specular=0.7).evaluate(o, i)
    mine = brdf.remaining_factor("beckmann", o, i, **params) * brdf.ndf_exact("beckmann", h, **params)
    np.testing.assert_allclose(mine, ref, rtol=RTOL_FACTORISATION, atol=ATOL_SUBNORMAL)


@pytest.mark.parametrize("model,params", [
    ("cook-torrance", {"m": 0.2, "eta": 1.5}), ("blinn-phong", {"exponent": 40.0}),
    ("ward", {"alpha_x": 0.1, "alpha_y": 0.3}), ("ashikhmin-shirley", {"nu": 75.0, "nv": 1200.0}),
    ("tabulated-ndf", {"theta_h": np.linspace(0, np.pi / 2, 46), "ndf_values": np.exp(-np.linspace(0, 9, 46))}),
])
def test_models_factor_exactly(rng, model, params):
    o, i = _random_hemisphere(rng, 500), _random_hemisphere(rng, 500)
    h = (o + i) / np.linalg.norm(o + i, axis=1, keepdims=True)
    b = brdf.microfacet_brdf(model, **params)
    val = b.evaluate(o, i)
    assert np.all(np.isfinite(val)) and np.all(val >= 0.0)
    np.testing.assert_allclose(brdf.remaining_factor(model, o, i, **params) * brdf.ndf_exact(model, h, **params), val,
                               rtol=RTOL_FACTORISATION, atol=ATOL_SUBNORMAL)
    below = i * np.array([1.0, 1.0, -1.0])
    assert np.all(b.evaluate(o, below) == 0.0)


def test_cook_torrance_known_values():
    """At o = i = n: h = n, D = 1, S = 1, F = F(1) = ((eta-1)/(eta+1))^2, so rho = F / pi."""
    z = np.array([0.0, 0.0, 1.0])
    b = brdf.CookTorrance(m=0.3, eta=1.5)
    assert b.evaluate(z, z) == pytest.approx(0.04 / np.pi, rel=1e-12)
    assert brdf.CookTorrance(m=0.3, f0=0.04).eta == pytest.approx(1.5, rel=1e-12)
    # V-groove shadowing: 1 at normal incidence, 2 (n.h)(n.i)/(o.h) when i is grazing
    assert brdf.shadowing_cook_torrance(1.0, 1.0, 1.0, 1.0) == 1.0
    assert brdf.shadowing_cook_torrance(0.9, 0.8, 0.1, 0.5) == pytest.approx(2 * 0.9 * 0.1 / 0.5)


def test_ward_isotropic_is_ward_1992():
    b = brdf.Ward(alpha_x=0.2)
    o, i = _view(20.0), _view(35.0, 180.0)
    h = (o + i) / np.linalg.norm(o + i)
    tan2 = (1 - h[2] ** 2) / h[2] ** 2
    ref = math.exp(-tan2 / 0.04) / (4 * math.pi * 0.04 * math.sqrt(o[2] * i[2]))
    assert b.evaluate(o, i) == pytest.approx(ref, rel=1e-12)


def _fresnel_polarised(c, eta):
    """Oracle: average of the s and p Fresnel reflectances with Snell's law (incidence cosine c)."""
    s = math.sqrt(max(0.0, 1 - c * c)) / eta
    ct = math.sqrt(1 - s * s)
    rs = ((c - eta * ct) / (c + eta * ct)) ** 2
    rp = ((ct - eta * c) / (ct + eta * c)) ** 2
    return 0.5 * (rs + rp)


@pytest.mark.parametrize("eta", [1.33, 1.5, 2.4])
def test_fresnel_eq14(eta):
    assert brdf.fresnel_cook_torrance(1.0, eta) == pytest.approx(((eta - 1) / (eta + 1)) ** 2, rel=1e-12)
    assert brdf.fresnel_cook_torrance(0.0, eta) == pytest.approx(1.0, abs=1e-12)
    c = np.linspace(1e-3, 1.0, 60)
    f = brdf.fresnel_cook_torrance(c, eta)
    np.testing.assert_allclose(f, [_fresnel_polarised(x, eta) for x in c], rtol=1e-10)
    assert np.all(np.diff(f) < 0.0)  # rises monotonically towards grazing
    assert brdf.fresnel_cook_torrance(1e-6, eta) > 0.999


# ---- closed-form NDF lobes ---------------------------------------------------------------------


@pytest.mark.parametrize("m", [0.05, 0.1, 0.2, 0.3, 0.5])
def test_cook_torrance_lobe_eq12(m):
    lobes = sg_ndf.ndf_lobes("cook-torrance", m=m)
    assert lobes.sharpness[0] == pytest.approx(2 / m**2) and lobes.amplitude[0] == 1.0
    assert _isotropic_l2_error("cook-torrance", {"m": m}) <= CT_ERR_PER_M2 * m * m


@pytest.mark.parametrize("a", [0.05, 0.1, 0.2, 0.3, 0.5])
def test_beckmann_lobe_forms(a):
    errors = {f: _isotropic_l2_error("beckmann", {"roughness": a, "form": f}) for f in brdf.BECKMANN_FORMS}
    assert errors["normalized"] <= BECKMANN_ERR_PER_A2 * a * a
    # the default is the best closed form on the whole range (the measurement that chose it)
    assert errors["normalized"] < errors["paper"] < errors["taylor"]
    lam, mu = sg_ndf.beckmann_lobe(a)
    # the projected-area normalisation it keeps: integral over H of mu e^(lam(z-1)) z = 1
    x, w = np.polynomial.legendre.leggauss(400)
    z = 0.5 * (x + 1)
    assert 2 * np.pi * mu * np.sum(0.5 * w * np.exp(lam * (z - 1)) * z) == pytest.approx(1.0, rel=1e-10)


@pytest.mark.parametrize("p", [10.0, 100.0, 1000.0])
def test_blinn_phong_lobe(p):
    assert _isotropic_l2_error("blinn-phong", {"exponent": p}) <= BLINN_ERR_TIMES_P / p


@pytest.mark.parametrize("alpha", [0.05, 0.2, 0.5])
def test_ward_isotropic_lobe(alpha):
    assert _isotropic_l2_error("ward", {"alpha_x": alpha}) <= WARD_ERR_PER_A2 * alpha * alpha


# ---- fits --------------------------------------------------------------------------------------


def test_lbfgsb_recovers_synthetic_mixture():
    axes = np.array([[0.1, 0.0, 1.0], [-0.05, 0.08, 1.0], [0.0, 0.0, 1.0]])
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    target = SGMixture(axes, np.array([40.0, 150.0, 600.0]), np.array([0.5, 1.0, 0.8]))
    fit = sg_ndf.fit_ndf(target.evaluate, 3, axes="free", azimuth_nodes=96)
    assert fit.relative_error < EXACT_FIT_REL < fit.initial_error
    np.testing.assert_allclose(fit.mixture.sharpness, target.sharpness, rtol=RECOVER_RTOL)
    np.testing.assert_allclose(fit.mixture.amplitude, target.amplitude, rtol=RECOVER_RTOL)
    np.testing.assert_allclose(fit.mixture.axes, target.axes, atol=RECOVER_RTOL)


def test_lm_recovers_synthetic_mixture_about_z():
    target = SGMixture(np.tile([0.0, 0.0, 1.0], (2, 1)), np.array([20.0, 300.0]), np.array([0.7, 0.3]))
    fit = sg_ndf.fit_ndf(target.evaluate, 2, axes="fixed")
    one = sg_ndf.fit_ndf(target.evaluate, 1, axes="fixed")
    assert fit.relative_error < EXACT_FIT_REL < one.relative_error
    np.testing.assert_allclose(fit.mixture.sharpness, [20.0, 300.0], rtol=RECOVER_RTOL)
    np.testing.assert_allclose(fit.mixture.amplitude, [0.7, 0.3], rtol=RECOVER_RTOL)


def test_lm_tabulated_beckmann_beats_its_start():
    a = 0.3
    t = np.linspace(0.0, 0.5 * np.pi, 91)
    d = np.exp(-np.tan(t) ** 2 / a**2) / (np.pi * a * a * np.cos(t) ** 4)
    fit = sg_ndf.fit_ndf(brdf.tabulated_ndf(t, d), 1, axes="fixed")
    assert fit.relative_error < 0.6 * fit.initial_error
    closed = _isotropic_l2_error("beckmann", {"roughness": a})
    # the least-squares lobe is at least as good as the best closed form (on the fitting cap)
    assert fit.relative_error <= closed * 1.01
    lobes = sg_ndf.ndf_lobes("tabulated-ndf", theta_h=t, ndf_values=d, lobes=2)
    assert lobes.lobe_count == 2 and np.all(np.diff(lobes.sharpness) >= 0.0)


def test_lbfgsb_anisotropic_more_lobes_less_error():
    b = brdf.AshikhminShirley(nu=75.0, nv=1200.0)
    one = sg_ndf.fit_ndf(b.ndf, 1, azimuth_nodes=128)
    four = sg_ndf.fit_ndf(b.ndf, 4, azimuth_nodes=128)
    assert four.relative_error < 0.5 * one.relative_error
    assert four.relative_error < four.initial_error
    assert np.all(np.diff(four.mixture.sharpness) >= 0.0)  # sorted by sharpness
    # the lobes spread along the broad (nu, +x) direction of the NDF
    assert np.ptp(four.mixture.axes[:, 0]) > 5 * np.ptp(four.mixture.axes[:, 1])
    w = brdf.Ward(alpha_x=0.1, alpha_y=0.3)
    three, single = (sg_ndf.fit_ndf(w.ndf, k, azimuth_nodes=128) for k in (3, 1))
    assert three.relative_error < single.relative_error


# ---- the spherical warp ------------------------------------------------------------------------


def _warped_ndf_error(model, params, view, nodes=(200, 256)):
    """Brute-force reflection of the exact NDF, D(h(i)) with h(i) = (o + i)/|o + i|, against the
    warped lobes without M (eq. 18-21), relative L2 over the sphere of i."""
    ndf = sg_ndf.ndf_lobes(model, **params)
    sl = slices.view_slice(model, view, **params)
    dirs, w = hemisphere_quadrature(*nodes)
    dirs = np.concatenate([dirs, dirs * [1, 1, -1]])
    w = np.concatenate([w, w])
    h = view + dirs
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    exact = brdf.ndf_exact(model, h, **params)
    warped = SGMixture(sl.axes, sl.sharpness, ndf.amplitude).evaluate(dirs)
    return math.sqrt(w @ (warped - exact) ** 2 / (w @ exact**2))


def test_warp_matches_brute_force_reflection():
    params = {"m": 0.4}
    errors = [_warped_ndf_error("cook-torrance", params, _view(t)) for t in (0.0, 30.0, 60.0, 80.0)]
    # At o = z the exact reflection is exp(-(theta_i / 2m)^2) (h_z = cos(theta_i / 2)) and the warped
    # lobe is exp(2 / (2m)^2 (cos theta_i - 1)): exactly the eq. 12 lobe of roughness 2m, over the sphere.
    doubled = _isotropic_l2_error("cook-torrance", {"m": 2 * params["m"]}, upper=np.pi)
    assert errors[0] == pytest.approx(doubled, rel=1e-3)
    assert errors[0] < errors[1] < errors[2] < errors[3]  # the isotropic warp degrades with obliquity


def test_view_slice_eq18_to_22():
    o = _view(40.0, 25.0)
    params = {"roughness": 0.25, "f0": 0.05}
    sl = slices.view_slice("beckmann", o, **params)
    lam, mu = sg_ndf.beckmann_lobe(0.25)
    np.testing.assert_allclose(sl.axes[0], [-o[0], -o[1], o[2]], atol=1e-15)  # 2 (o.z) z - o
    assert sl.sharpness[0] == pytest.approx(lam / (4 * o[2]), rel=1e-14)
    assert sl.amplitude[0] == pytest.approx(mu * brdf.remaining_factor("beckmann", o, sl.axes[0], **params), rel=1e-14)
    assert not sl.culled.any()


@pytest.mark.parametrize("model,params", [
    ("beckmann", {"roughness": 0.2}), ("cook-torrance", {"m": 0.2}),
    ("blinn-phong", {"exponent": 50.0}), ("ward", {"alpha_x": 0.2}),
])
def test_slice_error_grows_towards_grazing(model, params):
    exact = brdf.microfacet_brdf(model, **params)
    errors = [slices.slice_error(exact, model, params, _view(t)) for t in (0.0, 30.0, 60.0, 85.0, 89.5)]
    assert errors[0] < SLICE_ERR_NORMAL
    assert errors[0] < errors[2] < errors[3]
    assert all(math.isfinite(e) for e in errors)  # grazing: large (documented), never NaN


@pytest.mark.parametrize("theta", [30.0, 60.0, 75.0])
def test_sharp_slice_error_is_the_isotropic_warp_floor(theta):
    """Sharp lobes: M_o and the cosine are constant over the lobe and the NDF lobe is exact, so the
    slice error is the analytic distance between the anisotropic exact reflection and the
    isotropic warped lobe (slices.isotropic_warp_floor)."""
    params = {"exponent": 1e4}
    err = slices.slice_error(brdf.microfacet_brdf("blinn-phong", **params), "blinn-phong", params, _view(theta))
    assert err == pytest.approx(float(slices.isotropic_warp_floor(math.cos(math.radians(theta)))), rel=SHARP_FLOOR_RTOL)
    assert slices.isotropic_warp_floor(1.0) == 0.0


def test_slice_error_independent_quadrature():
    model, params, view = "cook-torrance", {"m": 0.35, "eta": 1.4}, _view(35.0)
    exact = brdf.microfacet_brdf(model, **params)
    sl = slices.view_slice(model, view, **params)
    dirs, w = hemisphere_quadrature(400, 800)
    ref = exact.evaluate(np.broadcast_to(view, dirs.shape), dirs) * dirs[:, 2]
    approx = sl.evaluate(dirs) * dirs[:, 2]
    oracle = math.sqrt(w @ (approx - ref) ** 2 / (w @ ref**2))
    assert slices.slice_error(exact, model, params, view) == pytest.approx(oracle, abs=QUADRATURE_ATOL)


def test_anisotropic_slice_and_culling():
    params = {"nu": 75.0, "nv": 1200.0, "lobes": 4}
    exact = brdf.microfacet_brdf("ashikhmin-shirley", **params)
    normal = slices.slice_error(exact, "ashikhmin-shirley", params, _view(0.0))
    assert normal < 0.3
    sl = slices.view_slice("ashikhmin-shirley", _view(89.0), **params)
    assert np.all(np.isfinite(sl.amplitude)) and np.all(np.isfinite(sl.sharpness))
    assert sl.culled.any() and np.all(sl.amplitude[sl.culled] == 0.0)  # reported, zeroed
    below = slices.view_slice("cook-torrance", np.array([0.3, 0.0, -0.5]), m=0.2)
    assert below.culled.all() and np.all(below.amplitude == 0.0)


@pytest.mark.parametrize("m", [0.01, 1.5])
def test_extreme_roughness_is_finite(m):
    exact = brdf.CookTorrance(m=m)
    for t in (0.0, 45.0, 89.9):
        sl = slices.view_slice("cook-torrance", _view(t), m=m)
        assert np.all(np.isfinite(sl.sharpness)) and np.all(np.isfinite(sl.amplitude))
        err = slices.slice_error(exact, "cook-torrance", {"m": m}, _view(t))
        assert math.isfinite(err)
    # mirror-like: at normal view the single lobe is nearly exact
    if m == 0.01:
        assert slices.slice_error(exact, "cook-torrance", {"m": m}, _view(0.0)) < 0.01


# ---- bad input ---------------------------------------------------------------------------------


@pytest.mark.parametrize("call,match", [
    (lambda: brdf.CookTorrance(m=-0.1), "m must"),
    (lambda: brdf.CookTorrance(m=0.2, eta=0.9), "eta"),
    (lambda: brdf.CookTorrance(m=0.2, f0=1.5), "f0"),
    (lambda: brdf.Ward(alpha_x=0.1, alpha_y=float("nan")), "alpha_y"),
    (lambda: brdf.AshikhminShirley(nu=0.0), "nu"),
    (lambda: sg_ndf.ndf_lobes("phong", exponent=3), "model"),
    (lambda: sg_ndf.ndf_lobes("ward", alpha_x=0.1, alpha=0.2), "alpha"),
    (lambda: sg_ndf.ndf_lobes("blinn-phong", exponent=-1.0), "exponent"),
    (lambda: sg_ndf.ndf_lobes("beckmann", roughness=0.2, form="exact"), "form"),
    (lambda: sg_ndf.ndf_lobes("beckmann", roughness=0.9, form="taylor"), "roughness"),
    (lambda: sg_ndf.ndf_lobes("ward", alpha_x=0.1, alpha_y=0.3, lobes=0), "lobes"),
    (lambda: sg_ndf.ndf_lobes("tabulated-ndf", theta_h=[0, 1], ndf_values=[1, 0], lobes=3), "lobes"),
    (lambda: brdf.tabulated_ndf([0.0, 0.5, 0.4], [1, 1, 1]), "theta_h"),
    (lambda: brdf.tabulated_ndf([0.0, 0.5], [1, -1]), "values"),
    (lambda: sg_ndf.fit_ndf(lambda h: np.zeros(h.shape[:-1]), 1), "zero"),
    (lambda: sg_ndf.fit_ndf(lambda h: h[..., 2], 1, axes="loose"), "axes"),
    (lambda: slices.view_slice("cook-torrance", [0.0, 0.0, 0.0], m=0.2), "view_local"),
    (lambda: slices.view_slice("cook-torrance", [0.0, 0.0, np.nan], m=0.2), "view_local"),
    (lambda: slices.slice_error(brdf.CookTorrance(), "cook-torrance", {}, [0.0, 0.6, -0.8]), "view_local"),
    (lambda: brdf_warp.specular_slices([[0, 0, 1]], "ggx", 0.2), "model"),
    (lambda: brdf_warp.specular_slices([[0, 0, 1]], "ward", 1.5), "roughness"),
    (lambda: brdf_warp.specular_slices([[0, 0, 1]], "beckmann", 0.2, f0=1.0), "f0"),
])
def test_bad_parameters_raise(call, match):
    with pytest.raises(ValueError, match=match):
        call()


# ---- Warp mirror -------------------------------------------------------------------------------


@wp.kernel
def _factor_kernel(views: wp.array(dtype=wp.vec3), lights: wp.array(dtype=wp.vec3), model: int, roughness: float,
                   f0: float, out: wp.array(dtype=float), fresnel: wp.array(dtype=float)):
    i = wp.tid()
    out[i] = brdf_warp.remaining_factor(model, views[i], lights[i], roughness, f0)
    fresnel[i] = brdf_warp.fresnel_cook_torrance(views[i][2], brdf_warp.eta_from_f0(f0))


@pytest.mark.parametrize("model,roughness", [("beckmann", 0.3), ("cook-torrance", 0.2), ("blinn-phong", 80.0),
                                             ("ward", 0.15), ("beckmann", 0.01), ("cook-torrance", 1.5)])
def test_kernel_slice_matches_float64(device, rng, model, roughness):
    views = np.concatenate([_random_hemisphere(rng, 300, min_z=0.05), [[0.0, 0.0, 1.0], _view(85.0, 40.0)]])
    axes, lam, amp = brdf_warp.specular_slices(views, model, roughness, f0=0.05, device=device)
    r_axes, r_lam, r_amp = brdf_warp.specular_slices_f64(views, model, roughness, f0=0.05)
    np.testing.assert_allclose(axes, r_axes, atol=ATOL_AXIS_FLOAT32)
    np.testing.assert_allclose(lam, r_lam, rtol=RTOL_BRDF_FLOAT32)
    np.testing.assert_allclose(amp[:, 0], r_amp, rtol=RTOL_BRDF_FLOAT32)
    assert np.all(amp[:, 0] == amp[:, 1]) and np.all(amp[:, 1] == amp[:, 2])  # grey


def test_kernel_extremes_finite(device):
    views = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1e-7], [1.0, 0.0, 0.0], [0.2, 0.1, -1.0]])
    for model, r in (("beckmann", 0.01), ("beckmann", 2.0), ("cook-torrance", 0.01), ("ward", 1.0),
                     ("blinn-phong", 1e5)):
        axes, lam, amp = brdf_warp.specular_slices(views, model, r, device=device)
        assert np.all(np.isfinite(axes)) and np.all(np.isfinite(lam)) and np.all(np.isfinite(amp))
        assert np.all(amp[2:] == 0.0)  # at / below the horizon: culled


@pytest.mark.parametrize("model,params", [("beckmann", {"roughness": 0.3, "f0": 0.05}),
                                          ("cook-torrance", {"m": 0.3, "f0": 0.05}),
                                          ("blinn-phong", {"exponent": 30.0}), ("ward", {"alpha_x": 0.3})])
def test_kernel_remaining_factor_and_fresnel(device, rng, model, params):
    o, i = _random_hemisphere(rng, 400, 0.05), _random_hemisphere(rng, 400, 0.05)
    rough = params.get("roughness", params.get("m", params.get("exponent", params.get("alpha_x"))))
    f0 = params.get("f0", 0.05)
    out = wp.zeros(len(o), dtype=float, device=device)
    fres = wp.zeros(len(o), dtype=float, device=device)
    wp.launch(_factor_kernel, dim=len(o), device=device,
              inputs=[wp.array(o.astype(np.float32), dtype=wp.vec3, device=device),
                      wp.array(i.astype(np.float32), dtype=wp.vec3, device=device),
                      brdf_warp.MODEL_IDS[model], float(rough), float(f0)], outputs=[out, fres])
    np.testing.assert_allclose(out.numpy(), brdf.remaining_factor(model, o, i, **params), rtol=RTOL_BRDF_FLOAT32)
    eta = float(brdf.eta_from_f0(f0))
    np.testing.assert_allclose(fres.numpy(), brdf.fresnel_cook_torrance(o[:, 2], eta), rtol=RTOL_BRDF_FLOAT32)
