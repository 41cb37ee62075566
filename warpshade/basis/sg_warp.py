"""Spherical Gaussians as Warp functions: the kernel-side mirror of :mod:`warpshade.basis.sg`.

A lobe is the struct :class:`SG` (``axis`` unit vec3, ``sharpness`` float32, ``amplitude`` RGB
vec3). Functions (usable inside any kernel; float32, the float64 oracle is :mod:`.sg`):

* ``sg_make(axis, sharpness, amplitude: vec3) -> SG``;
* ``sg_eval(g, v) -> vec3`` -- ``mu exp(lambda (v.p - 1))`` (eq. 2);
* ``sg_integral(g) -> vec3`` -- over the sphere;
* ``sg_product(a, b) -> SG`` -- eq. 5, exact (amplitudes multiply per channel);
* ``sg_inner(a, b) -> vec3`` -- eq. 4 in the overflow-free form of :func:`.sg.inner_product`;
* ``sg_rotate(g, R: mat33) -> SG``;
* ``sg_sharpness_for_area(area) -> float`` -- ``f_a^-1`` (eq. 3, epsilon 0.1);
* ``sg_visible_fraction(theta_d, lambda) -> float`` -- ``f_h(theta_d, lambda) / f_h(pi/2, lambda)``
  by the erf form (eq. 31);
* ``sg_hemisphere_integral(theta_d, lambda) -> float`` -- ``f_h`` (eq. 30), erf form;
* ``sg_times_visibility(g, theta_d) -> SG`` -- eq. 31: the lobe with its amplitude scaled so that
  it integrates to the lobe's integral over the reconstructed visible hemisphere.

Kernels for tests and batch use: :data:`evaluate_kernel`, :data:`product_kernel`,
:data:`inner_kernel`, :data:`fh_kernel` (flat arrays, one thread per element).
"""

from __future__ import annotations

from .._wp import wp
from .sg import AREA_EPSILON, ERF_SHAPE

wp.set_module_options({"enable_backward": False})

__all__ = [
    "SG",
    "evaluate_kernel",
    "fh_kernel",
    "inner_kernel",
    "product_kernel",
    "sg_eval",
    "sg_hemisphere_integral",
    "sg_inner",
    "sg_integral",
    "sg_make",
    "sg_product",
    "sg_rotate",
    "sg_sharpness_for_area",
    "sg_times_visibility",
    "sg_visible_fraction",
]

_TWO_PI = 6.283185307179586
_FOUR_PI = 12.566370614359172
_ERF_A = wp.constant(float(ERF_SHAPE[0]))
_ERF_B = wp.constant(float(ERF_SHAPE[1]))
# -2 pi ln(eps): area = _AREA_K / lambda
_AREA_K = wp.constant(float(-_TWO_PI * __import__("math").log(AREA_EPSILON)))


@wp.struct
class SG:
    axis: wp.vec3
    sharpness: float
    amplitude: wp.vec3


@wp.func
def sg_make(axis: wp.vec3, sharpness: float, amplitude: wp.vec3):
    g = SG()
    g.axis = axis
    g.sharpness = sharpness
    g.amplitude = amplitude
    return g


@wp.func
def sg_eval(g: SG, v: wp.vec3):
    return g.amplitude * wp.exp(g.sharpness * (wp.dot(v, g.axis) - 1.0))


@wp.func
def _one_minus_exp_over(x: float, scale: float):
    # (1 - exp(-scale x)) / x, finite as x -> 0
    if x < 1.0e-4:
        return scale * (1.0 - 0.5 * scale * x)
    return (1.0 - wp.exp(-scale * x)) / x


@wp.func
def sg_integral(g: SG):
    return g.amplitude * (_TWO_PI * _one_minus_exp_over(g.sharpness, 2.0))


@wp.func
def _excess(a: SG, b: SG, length: float):
    # |l1 p1 + l2 p2| - l1 - l2 given the length, in a form without cancellation
    return -2.0 * a.sharpness * b.sharpness * (1.0 - wp.dot(a.axis, b.axis)) / (length + a.sharpness + b.sharpness + 1.0e-30)


@wp.func
def sg_product(a: SG, b: SG):
    u = a.sharpness * a.axis + b.sharpness * b.axis
    lam = wp.length(u)
    axis = a.axis
    if lam > 1.0e-20:
        axis = u / lam
    # |u| - l1 - l2 = -2 l1 l2 (1 - p1.p2) / (|u| + l1 + l2): no cancellation in float32 for sharp lobes
    scale = wp.exp(_excess(a, b, lam))
    return sg_make(axis, lam, wp.cw_mul(a.amplitude, b.amplitude) * scale)


@wp.func
def sg_inner(a: SG, b: SG):
    d = wp.length(a.sharpness * a.axis + b.sharpness * b.axis)
    # exp(d - l1 - l2) (1 - e^-2d) / (2d)
    w = wp.exp(_excess(a, b, d)) * 0.5 * _one_minus_exp_over(d, 2.0)
    return wp.cw_mul(a.amplitude, b.amplitude) * (_FOUR_PI * w)


@wp.func
def sg_rotate(g: SG, rotation: wp.mat33):
    return sg_make(rotation * g.axis, g.sharpness, g.amplitude)


@wp.func
def sg_sharpness_for_area(area: float):
    return _AREA_K / wp.max(area, 1.0e-30)


@wp.func
def _erf_fraction(theta_d: float, lam: float):
    # f_h / (integral over the sphere), the erf form of basis.sg
    r = wp.sqrt(lam)
    s = wp.sqrt(0.5 * lam) * wp.tanh(_ERF_A * r + _ERF_B * lam)
    t = wp.clamp(theta_d, -1.5707963267948966, 1.5707963267948966)
    st = wp.sin(t)
    shape = st
    if s > 1.0e-6:
        shape = wp.erf(s * st) / wp.erf(s)
    pole = 1.0 / (1.0 + wp.exp(-lam))
    return 0.5 + (pole - 0.5) * shape


@wp.func
def sg_hemisphere_integral(theta_d: float, lam: float):
    return _TWO_PI * _one_minus_exp_over(lam, 2.0) * _erf_fraction(theta_d, lam)


@wp.func
def sg_visible_fraction(theta_d: float, lam: float):
    # F / f_h(pi/2) = (1 - e^-2l) / (1 - e^-l) = 1 + e^-l
    return (1.0 + wp.exp(-lam)) * _erf_fraction(theta_d, lam)


@wp.func
def sg_times_visibility(g: SG, theta_d: float):
    return sg_make(g.axis, g.sharpness, g.amplitude * sg_visible_fraction(theta_d, g.sharpness))


@wp.kernel
def evaluate_kernel(dirs: wp.array(dtype=wp.vec3), axes: wp.array(dtype=wp.vec3), sharpness: wp.array(dtype=float),
                    amplitude: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = sg_eval(sg_make(axes[i], sharpness[i], amplitude[i]), dirs[i])


@wp.kernel
def product_kernel(axes1: wp.array(dtype=wp.vec3), sharpness1: wp.array(dtype=float), amplitude1: wp.array(dtype=wp.vec3),
                   axes2: wp.array(dtype=wp.vec3), sharpness2: wp.array(dtype=float), amplitude2: wp.array(dtype=wp.vec3),
                   axes: wp.array(dtype=wp.vec3), sharpness: wp.array(dtype=float), amplitude: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    g = sg_product(sg_make(axes1[i], sharpness1[i], amplitude1[i]), sg_make(axes2[i], sharpness2[i], amplitude2[i]))
    axes[i] = g.axis
    sharpness[i] = g.sharpness
    amplitude[i] = g.amplitude


@wp.kernel
def inner_kernel(axes1: wp.array(dtype=wp.vec3), sharpness1: wp.array(dtype=float), amplitude1: wp.array(dtype=wp.vec3),
                 axes2: wp.array(dtype=wp.vec3), sharpness2: wp.array(dtype=float), amplitude2: wp.array(dtype=wp.vec3),
                 out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = sg_inner(sg_make(axes1[i], sharpness1[i], amplitude1[i]), sg_make(axes2[i], sharpness2[i], amplitude2[i]))


@wp.kernel
def fh_kernel(theta_d: wp.array(dtype=float), sharpness: wp.array(dtype=float), out: wp.array(dtype=float)):
    i = wp.tid()
    out[i] = sg_hemisphere_integral(theta_d[i], sharpness[i])
