"""Real spherical harmonics as Warp functions and kernels, generated per SH order.

``sh_kernels(order)`` returns an :class:`SHKernels` bundle whose ``@wp.func`` members operate on
a fixed-length Warp vector of ``order**2`` float32 coefficients (``bundle.vec``). The loops over
bands are compile-time constants, so Warp unrolls them and the code is specialised to the
order; bundles are cached per order, and each kernel lives in its own Warp module so that
creating the bundle for one order never recompiles another.

Convention (see :mod:`warpshade.basis.sh`): real, orthonormal SH, coefficient index
``l*l + l + m``, with the Condon-Shortley phase of Sloan's "Stupid SH Tricks"
(``y(1,-1) = -0.488603 y``, ``y(1,0) = 0.488603 z``, ``y(1,1) = -0.488603 x``).

Functions in a bundle (all usable inside other kernels):

* ``eval(d: vec3) -> vec`` -- all ``order**2`` basis functions at a unit direction;
* ``dot(a: vec, b: vec) -> float``;
* ``zh_to_sh(axis: vec3, g: bands) -> vec`` -- the ZH rotation rule
  ``f_lm = sqrt(4 pi / (2l + 1)) * g_l * y_lm(axis)``;
* ``zh_from_sh_about_axis(f: vec, axis: vec3) -> bands`` -- projection of f onto the zonal
  functions about ``axis``: ``g_l = sqrt(4 pi / (2l + 1)) * sum_m f_lm y_lm(axis)``;
* ``scale_bands(f: vec, alpha: bands) -> vec`` -- ``f_lm * alpha_l`` (windows, convolutions);
* ``product(f: vec, g: vec, tables: SHTables) -> vec`` -- order-n truncated SH product
  ``(f * g)_i = sum_jk Gamma_ijk f_j g_k`` over the sparse Gaunt tensor held in ``tables``;
* ``square(f: vec, tables: SHTables) -> vec``;
* ``rotate_z(f: vec, angle: float) -> vec`` -- coefficients of ``f(Rz(angle)^-1 s)``;
* ``rotate(f: vec, r: mat33, tables: SHTables) -> vec`` -- coefficients of ``f(R^-1 s)`` by the
  "zxzxz" factorisation ``R = Rz(alpha) Rx(-90) Rz(beta) Rx(90) Rz(gamma)`` (ZYZ Euler angles,
  constant per-band 90-degree x-rotation blocks from ``tables``, analytic z rotations);
* ``load(a: array2d(float32), row: int) -> vec`` / ``store(a, row, v)`` -- move one row of a
  (count, order**2) coefficient array in and out of a register vector;
* kernels, one thread per row: ``basis_kernel(dirs: array(vec3), out: array2d(float32))``,
  ``product_kernel(f, g, tables, out)``, ``product_matrix_kernel(f, tables, out: array3d)``,
  ``rotate_kernel(f, rotations: array(mat33), tables, out)``,
  ``zh_to_sh_kernel(axes: array(vec3), zh: array2d, out)``,
  ``zh_from_sh_kernel(f, axes: array(vec3), out)``.

Functions that need constant tables (the Gaunt tensor, the x-rotation blocks) take an
:class:`SHTables` struct of device arrays, obtained once per order and device with
``bundle.tables(device)`` and passed to kernels as an argument.

SH exponential and logarithm (SHEXP paper, secs. 4-5; maths and float64 mirrors in
:mod:`warpshade.basis._shexp`, Warp code in :mod:`warpshade.basis._shexp_warp`):

* ``one() -> vec`` -- the constant function 1, ``(sqrt(4 pi), 0, ...)``;
* ``exp_ps(f, degree: int, tables) -> vec`` -- PS-p product series;
* ``exp_ps_star(f, degree: int, tables) -> vec`` -- PS*-p (DC isolation, scaling/squaring,
  even/odd factored series);
* ``exp_ol(f, exp_tables: SHExpTables) -> vec`` -- optimal linear (no products);
* ``exp_hyb(f, tables, exp_tables) -> vec`` -- scaling/squaring around OL;
* ``log(g, eps_rel: float, tables) -> vec`` -- eigen-inversion of the product matrix (Jacobi);
  heavy (``O(n^6)`` per call), meant for tables and tests rather than per-receiver work;
* ``ol_lookup(norm, exp_tables) -> vec2`` -- the OL coefficients (a, b) at ``||f^||``;
* ``log_cap_zh(theta, exp_tables) -> bands`` -- ZH coefficients of the log visibility of a
  blocking cap of angular radius theta (table, linear interpolation; rotate with ``zh_to_sh``);
* ``cap_zh_blocked(theta) -> bands`` -- the cap's visibility itself, in closed form;
* ``zh_accumulate(acc, axis, g) -> vec`` -- ``acc + zh_to_sh(axis, g)``, fully unrolled with
  constant recurrence coefficients (the per-blocker step of log-space accumulation);

with ``exp_tables = bundle.exp_tables(device)`` (:class:`SHExpTables`, defined with the exp/log
functions in :mod:`warpshade.basis._shexp_warp` and re-exported here).

Layer: above :mod:`warpshade.basis._gaunt` (Gaunt tensor), :mod:`warpshade.basis._rotation`
(x90 blocks) and :mod:`warpshade.basis._shexp_warp` (exp/log functions and tables), all imported
at the top; never imports :mod:`warpshade.basis.sh`. The modules that need finished bundles
(:mod:`warpshade.basis._shexp_kernels`, :mod:`warpshade.basis._zh_warp`,
:mod:`warpshade.basis.sh`) import this one.
"""

# No "from __future__ import annotations": Warp resolves closure types in annotations.

import functools
import math
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._wp import resolve_device, wp
from . import _gaunt, _rotation
from ._shexp_warp import SHExpTables, build_exp_tables, exp_funcs

wp.set_module_options({"enable_backward": False})

__all__ = ["SHKernels", "SHTables", "SHExpTables", "sh_kernels", "MAX_KERNEL_ORDER"]

#: Highest SH order with generated Warp code (order n = n bands = n*n coefficients).
MAX_KERNEL_ORDER = 12


@wp.struct
class SHTables:
    """Constant per-order tables on one device, passed to SH kernels as a struct.

    Attributes:
        order: SH order n the tables were built for.
        product_row_start: CSR row pointer over output coefficients, shape (n*n + 1,), int32.
        product_pair: the input indices of each Gaunt entry with ``j <= k``, packed as
            ``j | (k << 8)`` (one load per entry; n*n <= 256), shape (K',), int32.
        product_weight: ``Gamma_ijk`` for ``j < k`` and ``Gamma_ijj / 2`` on the diagonal, so that
            ``(f * g)_i = sum_e w_e (f_j g_k + f_k g_j)``, shape (K',), float32.
        x90: per-band blocks of the SH rotation by +90 degrees about x, each (2l+1)x(2l+1)
            row-major, concatenated over bands (band l starts at ``l (4 l^2 - 1) / 3``),
            shape (sum (2l+1)^2,), float32.
    """

    order: int
    product_row_start: wp.array(dtype=wp.int32)
    product_pair: wp.array(dtype=wp.int32)
    product_weight: wp.array(dtype=wp.float32)
    x90: wp.array(dtype=wp.float32)


_tables_lock = threading.Lock()
_tables_cache: dict = {}


def _build_tables(order: int, device) -> SHTables:
    dev = resolve_device(device)
    key = (order, dev.alias)
    with _tables_lock:
        if key in _tables_cache:
            return _tables_cache[key]
        idx, val = _gaunt.real_gaunt_tensor(order)
        keep = idx[:, 1] <= idx[:, 2]
        half_idx = idx[keep]
        weight = np.where(half_idx[:, 1] == half_idx[:, 2], 0.5, 1.0) * val[keep]
        row_start = np.searchsorted(half_idx[:, 0], np.arange(order * order + 1)).astype(np.int32)
        x90 = np.concatenate([b.ravel() for b in _rotation.x90_bands(order)])
        t = SHTables()
        t.order = order
        t.product_row_start = wp.array(row_start, dtype=wp.int32, device=dev)
        pair = (half_idx[:, 1] | (half_idx[:, 2] << 8)).astype(np.int32)
        t.product_pair = wp.array(pair, dtype=wp.int32, device=dev)
        t.product_weight = wp.array(weight.astype(np.float32), dtype=wp.float32, device=dev)
        t.x90 = wp.array(x90.astype(np.float32), dtype=wp.float32, device=dev)
        _tables_cache[key] = t
        return t


#: Highest order whose rotation is generated as straight-line code (x90 blocks without their zeros).
ROTATE_UNROLL_ORDER = 6
#: Highest order with the straight-line product (``SHKernels.product_unrolled``).
PRODUCT_UNROLL_ORDER = 4


def _x90_entries(order: int):
    """Non-zero entries of the x90 blocks as (row, column, value) lists over coefficient indices
    (float32 values, so unrolled code multiplies by exactly what the table holds)."""
    rows, cols, vals = [], [], []
    for l, blk in enumerate(_rotation.x90_bands(order)):
        b32 = np.asarray(blk, np.float32)
        for i in range(2 * l + 1):
            for j in range(2 * l + 1):
                if b32[i, j] != 0.0:
                    rows.append(l * l + i)
                    cols.append(l * l + j)
                    vals.append(float(b32[i, j]))
    return rows, cols, vals


def _product_entries(order: int):
    """The product table's entries in table order: output index, the two inputs, float32 weight."""
    idx, val = _gaunt.real_gaunt_tensor(order)
    keep = idx[:, 1] <= idx[:, 2]
    half_idx = idx[keep]
    weight = (np.where(half_idx[:, 1] == half_idx[:, 2], 0.5, 1.0) * val[keep]).astype(np.float32)
    return ([int(x) for x in half_idx[:, 0]], [int(x) for x in half_idx[:, 1]], [int(x) for x in half_idx[:, 2]],
            [float(w) for w in weight])


@dataclass(frozen=True)
class SHKernels:
    """Warp functions and kernels specialised to one SH order (see module docstring)."""

    order: int
    coeff_count: int
    vec: Any  # wp vector type of length order**2, float32
    bands: Any  # wp vector type of length order, float32 (per-band ZH coefficients)
    eval: Any
    dot: Any
    zh_to_sh: Any
    basis_kernel: Any
    zh_from_sh_about_axis: Any = None
    scale_bands: Any = None
    product: Any = None
    product_unrolled: Any = None
    square: Any = None
    rotate_z: Any = None
    rotate: Any = None
    load: Any = None
    store: Any = None
    product_kernel: Any = None
    product_matrix_kernel: Any = None
    rotate_kernel: Any = None
    zh_to_sh_kernel: Any = None
    zh_from_sh_kernel: Any = None
    one: Any = None
    scaling_power: Any = None
    exp_ps: Any = None
    exp_ps_star: Any = None
    exp_ol: Any = None
    exp_hyb: Any = None
    log: Any = None
    ol_lookup: Any = None
    log_cap_zh: Any = None
    cap_zh_blocked: Any = None
    zh_accumulate: Any = None

    def tables(self, device=None) -> SHTables:
        """The :class:`SHTables` of this order on ``device`` (built once, then cached)."""
        return _build_tables(self.order, device)

    def exp_tables(self, device=None) -> SHExpTables:
        """The OL and blocking-cap log tables of this order on ``device`` (built once, cached)."""
        return build_exp_tables(self.order, device)


@functools.lru_cache(maxsize=None)
def sh_kernels(order: int) -> SHKernels:
    """Return the cached Warp SH bundle for ``order`` (1 <= order <= MAX_KERNEL_ORDER)."""
    if not 1 <= order <= MAX_KERNEL_ORDER:
        raise ValueError(f"sh_kernels: order must be in 1..{MAX_KERNEL_ORDER}, got {order}")
    ORDER = order
    N = order * order
    vec_t = wp.types.vector(length=N, dtype=wp.float32)
    bands_t = wp.types.vector(length=order, dtype=wp.float32)
    SQRT2 = math.sqrt(2.0)
    Y00 = 0.5 / math.sqrt(math.pi)
    # Unrolled code (compile-time indices and constants, no table reads) for the rotation's x90
    # blocks up to ROTATE_UNROLL_ORDER and for the product up to PRODUCT_UNROLL_ORDER (its code
    # grows with the Gaunt entries: order 6 would take minutes to compile).
    X90_ROWS, X90_COLS, X90_VALS = _x90_entries(order)
    X90_COUNT = len(X90_VALS) if order <= ROTATE_UNROLL_ORDER else 0
    P_OUT, P_A, P_B, P_W = _product_entries(order) if order <= PRODUCT_UNROLL_ORDER else ([], [], [], [])
    P_COUNT = len(P_W)
    Z_M, Z_L = zip(*[(m, l) for m in range(1, order) for l in range(m, order)]) if order > 1 else ((), ())
    Z_COUNT = len(Z_M) if order <= ROTATE_UNROLL_ORDER else 0

    @wp.func
    def sh_eval(d: wp.vec3) -> vec_t:
        # Orthonormal associated Legendre recurrences in z, with sin^m(theta) cos/sin(m phi)
        # carried as the complex power (x + i y)^m, so no trigonometric calls are needed.
        out = vec_t()
        x = d[0]
        y = d[1]
        z = d[2]
        c = float(1.0)
        s = float(0.0)
        pmm = float(Y00)
        for m in range(ORDER):
            if m > 0:
                pmm = -wp.sqrt(float(2 * m + 1) / float(2 * m)) * pmm
            p_prev = float(0.0)
            p_cur = pmm
            for l in range(m, ORDER):
                if l == m + 1:
                    p_prev = p_cur
                    p_cur = wp.sqrt(float(2 * m + 3)) * z * pmm
                elif l > m + 1:
                    a = wp.sqrt(float(4 * l * l - 1) / float(l * l - m * m))
                    b = wp.sqrt(float((l - 1) * (l - 1) - m * m) / float(4 * (l - 1) * (l - 1) - 1))
                    p_next = a * (z * p_cur - b * p_prev)
                    p_prev = p_cur
                    p_cur = p_next
                if m == 0:
                    out[l * l + l] = p_cur
                else:
                    out[l * l + l + m] = float(SQRT2) * p_cur * c
                    out[l * l + l - m] = float(SQRT2) * p_cur * s
            c_next = c * x - s * y
            s = c * y + s * x
            c = c_next
        return out

    @wp.func
    def sh_dot(a: vec_t, b: vec_t) -> float:
        acc = float(0.0)
        for i in range(N):
            acc += a[i] * b[i]
        return acc

    @wp.func
    def sh_zh_to_sh(axis: wp.vec3, g: bands_t) -> vec_t:
        y = sh_eval(axis)
        out = vec_t()
        for l in range(ORDER):
            scale = wp.sqrt(4.0 * wp.pi / float(2 * l + 1)) * g[l]
            for m in range(-l, l + 1):
                out[l * l + l + m] = scale * y[l * l + l + m]
        return out

    @wp.kernel(enable_backward=False, module="unique")
    def basis_kernel(dirs: wp.array(dtype=wp.vec3), out: wp.array2d(dtype=wp.float32)):
        i = wp.tid()
        v = sh_eval(wp.normalize(dirs[i]))
        for j in range(N):
            out[i, j] = v[j]

    @wp.func
    def sh_zh_from_sh_about_axis(f: vec_t, axis: wp.vec3) -> bands_t:
        y = sh_eval(axis)
        g = bands_t()
        for l in range(ORDER):
            acc = float(0.0)
            for m in range(-l, l + 1):
                acc += f[l * l + l + m] * y[l * l + l + m]
            g[l] = wp.sqrt(4.0 * wp.pi / float(2 * l + 1)) * acc
        return g

    @wp.func
    def sh_scale_bands(f: vec_t, alpha: bands_t) -> vec_t:
        out = vec_t()
        for l in range(ORDER):
            for m in range(-l, l + 1):
                out[l * l + l + m] = alpha[l] * f[l * l + l + m]
        return out

    @wp.func
    def sh_product(f: vec_t, g: vec_t, tables: SHTables) -> vec_t:
        # CSR over the output index i; entries with j <= k, diagonal weights halved, so each
        # entry contributes w * (f_j g_k + f_k g_j) and the sum is written once per i. The
        # entry cursor runs on across rows (a while loop is ~1.4x faster than range(start, end)).
        out = vec_t()
        e = int(tables.product_row_start[0])
        for i in range(N):
            acc = float(0.0)
            end = tables.product_row_start[i + 1]
            while e < end:
                pair = tables.product_pair[e]
                a = pair & 255
                b = pair >> 8
                acc += tables.product_weight[e] * (f[a] * g[b] + f[b] * g[a])
                e += 1
            out[i] = acc
        return out

    @wp.func
    def sh_product_unrolled(f: vec_t, g: vec_t, tables: SHTables) -> vec_t:
        # sh_product as straight-line code (the table's entries in its order: the same sums);
        # the table is read only above PRODUCT_UNROLL_ORDER.
        out = vec_t()
        if wp.static(P_COUNT == 0):
            out = sh_product(f, g, tables)
        for e in range(wp.static(P_COUNT)):
            i = wp.static(P_OUT[e])
            a = wp.static(P_A[e])
            b = wp.static(P_B[e])
            out[i] = out[i] + wp.static(P_W[e]) * (f[a] * g[b] + f[b] * g[a])
        return out

    @wp.func
    def sh_square(f: vec_t, tables: SHTables) -> vec_t:
        out = vec_t()
        e = int(tables.product_row_start[0])
        for i in range(N):
            acc = float(0.0)
            end = tables.product_row_start[i + 1]
            while e < end:
                pair = tables.product_pair[e]
                acc += 2.0 * tables.product_weight[e] * f[pair & 255] * f[pair >> 8]
                e += 1
            out[i] = acc
        return out

    @wp.func
    def sh_rotate_z_cs(f: vec_t, c1: float, s1: float) -> vec_t:
        # Rz by the angle whose cosine and sine are (c1, s1). Within band l the pair
        # (y_l,m ~ cos(m phi), y_l,-m ~ sin(m phi)) turns by m * angle; cos and sin of m * angle
        # come from the angle-addition recurrence, so no trigonometric call is made.
        out = f
        if wp.static(Z_COUNT > 0):
            cm = vec_t()
            sm = vec_t()
            cm[1] = c1
            sm[1] = s1
            for m in range(wp.static(2), wp.static(ORDER)):
                cm[m] = cm[m - 1] * c1 - sm[m - 1] * s1
                sm[m] = sm[m - 1] * c1 + cm[m - 1] * s1
            for e in range(wp.static(Z_COUNT)):
                p = wp.static(Z_L[e] * Z_L[e] + Z_L[e] + Z_M[e])
                q = wp.static(Z_L[e] * Z_L[e] + Z_L[e] - Z_M[e])
                m = wp.static(Z_M[e])
                out[p] = cm[m] * f[p] - sm[m] * f[q]
                out[q] = sm[m] * f[p] + cm[m] * f[q]
        else:
            c = c1
            s = s1
            for m in range(1, ORDER):
                for l in range(m, ORDER):
                    a = f[l * l + l + m]
                    b = f[l * l + l - m]
                    out[l * l + l + m] = c * a - s * b
                    out[l * l + l - m] = s * a + c * b
                cn = c * c1 - s * s1
                s = s * c1 + c * s1
                c = cn
        return out

    @wp.func
    def sh_rotate_z(f: vec_t, angle: float) -> vec_t:
        return sh_rotate_z_cs(f, wp.cos(angle), wp.sin(angle))

    @wp.func
    def sh_rotate_x90(f: vec_t, x90: wp.array(dtype=wp.float32), transpose: int) -> vec_t:
        # Dense per-band product with the constant (2l+1)^2 block of Rx(+90) (or its transpose,
        # which is the block of Rx(-90)); up to ROTATE_UNROLL_ORDER as straight-line code over
        # the blocks' non-zero entries (x90 is then not read).
        out = vec_t()
        if wp.static(X90_COUNT > 0):
            if transpose == 0:
                for e in range(wp.static(X90_COUNT)):
                    out[wp.static(X90_ROWS[e])] = out[wp.static(X90_ROWS[e])] + wp.static(X90_VALS[e]) * f[wp.static(X90_COLS[e])]
            else:
                for e in range(wp.static(X90_COUNT)):
                    out[wp.static(X90_COLS[e])] = out[wp.static(X90_COLS[e])] + wp.static(X90_VALS[e]) * f[wp.static(X90_ROWS[e])]
        else:
            for l in range(ORDER):
                dim = 2 * l + 1
                offset = l * (4 * l * l - 1) // 3
                row_stride = dim
                col_stride = 1
                if transpose != 0:
                    row_stride = 1
                    col_stride = dim
                for i in range(dim):
                    acc = float(0.0)
                    for j in range(dim):
                        acc += x90[offset + i * row_stride + j * col_stride] * f[l * l + j]
                    out[l * l + i] = acc
        return out

    @wp.func
    def sh_rotate(f: vec_t, r: wp.mat33, tables: SHTables) -> vec_t:
        # ZYZ Euler angles R = Rz(alpha) Ry(beta) Rz(gamma), taken as (cos, sin) pairs straight
        # from the matrix entries (alpha = atan2(r12, r02), beta = atan2(sb, r22), gamma =
        # atan2(r21, -r20)), each pair normalised; near the poles only alpha + gamma is defined
        # (gamma is then 0).
        sb = wp.sqrt(r[0, 2] * r[0, 2] + r[1, 2] * r[1, 2])
        hb = wp.sqrt(sb * sb + r[2, 2] * r[2, 2])
        cb = float(1.0)
        snb = float(0.0)
        if hb > 0.0:
            cb = r[2, 2] / hb
            snb = sb / hb
        ca = float(1.0)
        sa = float(0.0)
        cg = float(1.0)
        sg = float(0.0)
        if sb < 1.0e-6:
            x = r[0, 0]
            y = r[1, 0]
            if r[2, 2] <= 0.0:
                x = r[1, 1]
                y = -r[1, 0]
            h = wp.sqrt(x * x + y * y)
            if h > 0.0:
                ca = x / h
                sa = y / h
        else:
            ca = r[0, 2] / sb
            sa = r[1, 2] / sb
            hg = wp.sqrt(r[2, 0] * r[2, 0] + r[2, 1] * r[2, 1])
            if hg > 0.0:
                cg = -r[2, 0] / hg
                sg = r[2, 1] / hg
        # Ry(beta) = Rx(-90) Rz(beta) Rx(90); rotations act right to left.
        out = sh_rotate_z_cs(f, cg, sg)
        out = sh_rotate_x90(out, tables.x90, 0)
        out = sh_rotate_z_cs(out, cb, snb)
        out = sh_rotate_x90(out, tables.x90, 1)
        return sh_rotate_z_cs(out, ca, sa)

    @wp.func
    def sh_load(a: wp.array2d(dtype=wp.float32), row: int) -> vec_t:
        v = vec_t()
        for j in range(N):
            v[j] = a[row, j]
        return v

    @wp.func
    def sh_store(a: wp.array2d(dtype=wp.float32), row: int, v: vec_t):
        for j in range(N):
            a[row, j] = v[j]

    @wp.kernel(enable_backward=False, module="unique")
    def product_kernel(
        f: wp.array2d(dtype=wp.float32),
        g: wp.array2d(dtype=wp.float32),
        tables: SHTables,
        out: wp.array2d(dtype=wp.float32),
    ):
        i = wp.tid()
        sh_store(out, i, sh_product(sh_load(f, i), sh_load(g, i), tables))

    @wp.kernel(enable_backward=False, module="unique")
    def product_matrix_kernel(
        f: wp.array2d(dtype=wp.float32),
        tables: SHTables,
        out: wp.array3d(dtype=wp.float32),
    ):
        # out must be zero-initialised: (M_f)_ij = sum_k Gamma_ijk f_k, one row i per CSR segment.
        t = wp.tid()
        fv = sh_load(f, t)
        for i in range(N):
            for e in range(tables.product_row_start[i], tables.product_row_start[i + 1]):
                pair = tables.product_pair[e]
                a = pair & 255
                b = pair >> 8
                w = tables.product_weight[e]
                out[t, i, a] = out[t, i, a] + w * fv[b]
                out[t, i, b] = out[t, i, b] + w * fv[a]

    @wp.kernel(enable_backward=False, module="unique")
    def rotate_kernel(
        f: wp.array2d(dtype=wp.float32),
        rotations: wp.array(dtype=wp.mat33),
        tables: SHTables,
        out: wp.array2d(dtype=wp.float32),
    ):
        i = wp.tid()
        sh_store(out, i, sh_rotate(sh_load(f, i), rotations[i], tables))

    @wp.kernel(enable_backward=False, module="unique")
    def zh_to_sh_kernel(
        axes: wp.array(dtype=wp.vec3),
        zh: wp.array2d(dtype=wp.float32),
        out: wp.array2d(dtype=wp.float32),
    ):
        i = wp.tid()
        g = bands_t()
        for l in range(ORDER):
            g[l] = zh[i, l]
        sh_store(out, i, sh_zh_to_sh(wp.normalize(axes[i]), g))

    @wp.kernel(enable_backward=False, module="unique")
    def zh_from_sh_kernel(
        f: wp.array2d(dtype=wp.float32),
        axes: wp.array(dtype=wp.vec3),
        out: wp.array2d(dtype=wp.float32),
    ):
        i = wp.tid()
        g = sh_zh_from_sh_about_axis(sh_load(f, i), wp.normalize(axes[i]))
        for l in range(ORDER):
            out[i, l] = g[l]

    return SHKernels(
        order=order,
        coeff_count=N,
        vec=vec_t,
        bands=bands_t,
        eval=sh_eval,
        dot=sh_dot,
        zh_to_sh=sh_zh_to_sh,
        basis_kernel=basis_kernel,
        zh_from_sh_about_axis=sh_zh_from_sh_about_axis,
        scale_bands=sh_scale_bands,
        product=sh_product,
        product_unrolled=sh_product_unrolled,
        square=sh_square,
        rotate_z=sh_rotate_z,
        rotate=sh_rotate,
        load=sh_load,
        store=sh_store,
        product_kernel=product_kernel,
        product_matrix_kernel=product_matrix_kernel,
        rotate_kernel=rotate_kernel,
        zh_to_sh_kernel=zh_to_sh_kernel,
        zh_from_sh_kernel=zh_from_sh_kernel,
        **exp_funcs(order, vec_t, bands_t, sh_product, sh_square, SHTables),
    )
