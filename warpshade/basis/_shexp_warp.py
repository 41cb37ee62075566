"""SH exponential and logarithm as Warp functions, generated per SH order (private).

Layer: below :mod:`warpshade.basis.sh_warp`. This module imports only
:mod:`warpshade.basis._shexp` (constants and float64 tables) and Warp; ``sh_warp`` calls
:func:`exp_funcs` with the order's vector types, product/square functions and table struct,
and re-exports :class:`SHExpTables`. The kernels that launch these functions need the finished
bundle and therefore live above ``sh_warp``, in :mod:`warpshade.basis._shexp_kernels`.

Reached through the per-order bundle of :func:`warpshade.basis.sh_warp.sh_kernels` (members
``exp_ps``, ``exp_ps_star``, ``exp_ol``, ``exp_hyb``, ``log``, ``ol_lookup``, ``log_cap_zh``,
``cap_zh_blocked``, ``one`` and the method ``exp_tables(device)``) and through the host wrappers
:func:`warpshade.basis.sh.exp` / :func:`warpshade.basis.sh.log` with ``device=``. The float64
reference of every function is in :mod:`warpshade.basis._shexp` (same algorithms, same
operation order), and the maths is documented there.

float32 safety: the DC factor ``exp(f_0 / sqrt(4 pi))`` is applied in log form at the end, and
during repeated squaring a vector whose norm exceeds ``RENORM_THRESHOLD`` is rescaled to unit
norm with the scale carried as a logarithm (``(c u)^(2^k) = c^(2^k) u^(2^k)``), so large but
finite inputs give finite outputs (0 where the true value underflows) instead of inf/NaN.
"""

# No "from __future__ import annotations": Warp resolves closure types in annotations.

import math
import threading

import numpy as np

from .._wp import resolve_device, wp
from . import _shexp

wp.set_module_options({"enable_backward": False})

__all__ = ["SHExpTables", "build_exp_tables", "exp_funcs", "METHOD_IDS"]

#: Method name -> integer id used by kernels that select the method at run time.
METHOD_IDS = {name: i for i, name in enumerate(_shexp.EXP_METHODS)}
#: Norm above which an intermediate square is rescaled (float32 max is 3.4e38).
RENORM_THRESHOLD = 1.0e8
#: Largest exponent passed to exp() in float32 (exp(80) = 5.5e34, below the float32 maximum).
MAX_LOG_SCALE = 80.0


@wp.struct
class SHExpTables:
    """Per-order tables of the SH exponential/log on one device (see :mod:`warpshade.basis._shexp`).

    Attributes:
        ol_a, ol_b: OL coefficients on a uniform grid of ``||f^||`` over [0, ol_norm_max],
            shape (S,), float32.
        ol_norm_max: end of the OL grid (inputs beyond use the last entries).
        log_cap: ZH coefficients of the log visibility of a blocking cap on a uniform grid of
            its angular radius over [0, log_cap_theta_max], shape (S, n), float32.
        log_cap_theta_max: end of the cap grid, radians (pi/2).
    """

    ol_a: wp.array(dtype=wp.float32)
    ol_b: wp.array(dtype=wp.float32)
    ol_norm_max: float
    log_cap: wp.array2d(dtype=wp.float32)
    log_cap_theta_max: float


_tables_lock = threading.Lock()
_tables_cache: dict = {}


def build_exp_tables(order: int, device=None, samples: int = _shexp.TABLE_SAMPLES) -> SHExpTables:
    """The :class:`SHExpTables` of an order on a device (built once, then cached)."""
    dev = resolve_device(device)
    key = (order, dev.alias, samples)
    with _tables_lock:
        if key in _tables_cache:
            return _tables_cache[key]
        ol = _shexp.ol_table(order, samples)
        cap = _shexp.log_cap_table(order, samples)
        t = SHExpTables()
        t.ol_a = wp.array(ol.a.astype(np.float32), dtype=wp.float32, device=dev)
        t.ol_b = wp.array(ol.b.astype(np.float32), dtype=wp.float32, device=dev)
        t.ol_norm_max = float(ol.norm_max)
        t.log_cap = wp.array(cap.zh.astype(np.float32), dtype=wp.float32, device=dev)
        t.log_cap_theta_max = float(cap.theta[-1])
        _tables_cache[key] = t
        return t


def exp_funcs(order: int, vec_t, bands_t, sh_product, sh_square, SHTables) -> dict:
    """Build the exp/log ``@wp.func`` of one order from the bundle's product/square functions.

    Args:
        order: SH order n.
        vec_t: Warp vector type of n*n float32 coefficients; bands_t: of n float32 ZH bands.
        sh_product, sh_square: the order's ``@wp.func`` ``(f: vec, g: vec, tables) -> vec`` and
            ``(f: vec, tables) -> vec``.
        SHTables: the struct type of the product tables (:class:`warpshade.basis.sh_warp.SHTables`).

    Returns:
        ``{bundle member name: @wp.func}`` for the members listed in the module docstring
        (plus ``scaling_power`` and ``zh_accumulate``).
    """
    ORDER = order
    N = order * order
    SQRT_4PI = math.sqrt(4.0 * math.pi)
    INV_SQRT_4PI = 1.0 / SQRT_4PI
    MAX_DEGREE = _shexp.MAX_DEGREE
    MAX_SQUARINGS = _shexp.MAX_SQUARINGS
    mat_t = wp.types.matrix(shape=(N, N), dtype=wp.float32)

    @wp.func
    def sh_one() -> vec_t:
        v = vec_t()
        v[0] = float(SQRT_4PI)
        return v

    @wp.func
    def scaling_power(norm: float) -> int:
        # max(0, floor(log2 ||f^|| + 3)) (eq. 21), bounded
        p = int(0)
        if norm > 0.0:
            p = int(wp.floor(wp.log2(norm) + 3.0))
        return wp.clamp(p, 0, MAX_SQUARINGS)

    @wp.func
    def dc_log_scale(f: vec_t) -> float:
        return wp.min(f[0] * float(INV_SQRT_4PI), float(MAX_LOG_SCALE))

    @wp.func
    def finish(h: vec_t, log_scale: float) -> vec_t:
        return h * wp.exp(wp.min(log_scale, float(MAX_LOG_SCALE)))

    @wp.func
    def square_repeatedly(h_in: vec_t, count: int, log_scale_in: float, tables: SHTables) -> vec_t:
        # h^(2^count)* * exp(log_scale); renormalises so float32 never overflows
        h = h_in
        log_scale = log_scale_in
        for k in range(count):
            h = sh_square(h, tables)
            norm = wp.length(h)
            if norm > float(RENORM_THRESHOLD):
                h = h / norm
                log_scale += wp.log(norm) * wp.pow(2.0, float(count - 1 - k))
        return finish(h, log_scale)

    @wp.func
    def exp_ps(f: vec_t, degree: int, tables: SHTables) -> vec_t:
        # PS-p: 1 + f + f^2*/2! + ... + f^p*/p!, products amassed left to right (eq. 17)
        out = f + sh_one()
        term = f
        inv_factorial = float(1.0)
        for k in range(2, wp.min(degree, MAX_DEGREE) + 1):
            term = sh_product(term, f, tables)
            inv_factorial = inv_factorial / float(k)
            out = out + term * inv_factorial
        return out

    @wp.func
    def factored_series(x: vec_t, degree: int, tables: SHTables) -> vec_t:
        # (h0 1 + h2 x^2* + h4 x^4* + ...) + x * (h1 1 + h3 x^2* + ...)  (eq. 22)
        even = sh_one()
        if degree < 2:
            return even + x
        odd = sh_one()
        x2 = sh_square(x, tables)
        power = x2
        inv_factorial = float(1.0)
        for k in range(2, wp.min(degree, MAX_DEGREE) + 1):
            inv_factorial = inv_factorial / float(k)
            if k % 2 == 0:
                if k == 4:
                    power = sh_square(x2, tables)
                elif k > 4:
                    power = sh_product(power, x2, tables)
                even = even + power * inv_factorial
            else:
                odd = odd + power * inv_factorial
        if degree < 3:
            return even + x
        return even + sh_product(x, odd, tables)

    @wp.func
    def exp_ps_star(f: vec_t, degree: int, tables: SHTables) -> vec_t:
        # PS*-p: DC isolation (eq. 20), scaling/squaring (eq. 21), factored series (eq. 22)
        log_scale = dc_log_scale(f)
        x = f
        x[0] = 0.0
        p = scaling_power(wp.length(x))
        x = x * wp.pow(2.0, -float(p))
        return square_repeatedly(factored_series(x, degree, tables), p, log_scale, tables)

    @wp.func
    def ol_lookup(norm: float, et: SHExpTables) -> wp.vec2:
        # linear interpolation on the uniform ||f^|| grid, clamped at both ends
        count = et.ol_a.shape[0]
        pos = wp.clamp(norm / et.ol_norm_max, 0.0, 1.0) * float(count - 1)
        i0 = wp.min(int(pos), count - 2)
        w = pos - float(i0)
        a = (1.0 - w) * et.ol_a[i0] + w * et.ol_a[i0 + 1]
        b = (1.0 - w) * et.ol_b[i0] + w * et.ol_b[i0 + 1]
        return wp.vec2(a, b)

    @wp.func
    def ol_linear(x: vec_t, et: SHExpTables) -> vec_t:
        ab = ol_lookup(wp.length(x), et)
        out = x * ab[1]
        out[0] = ab[0] * float(SQRT_4PI)
        return out

    @wp.func
    def exp_ol(f: vec_t, et: SHExpTables) -> vec_t:
        # OL: exp(f_0 / sqrt(4 pi)) (a(||f^||) 1 + b(||f^||) f^)  (eq. 23)
        log_scale = dc_log_scale(f)
        x = f
        x[0] = 0.0
        return finish(ol_linear(x, et), log_scale)

    @wp.func
    def exp_hyb(f: vec_t, tables: SHTables, et: SHExpTables) -> vec_t:
        # HYB: scaling/squaring around OL (sec. 4.3)
        log_scale = dc_log_scale(f)
        x = f
        x[0] = 0.0
        p = scaling_power(wp.length(x))
        x = x * wp.pow(2.0, -float(p))
        return square_repeatedly(ol_linear(x, et), p, log_scale, tables)

    @wp.func
    def log_cap_zh(theta: float, et: SHExpTables) -> bands_t:
        # ZH coefficients of log(visibility of a blocking cap of half-angle theta), linear interp.
        count = et.log_cap.shape[0]
        pos = wp.clamp(theta / et.log_cap_theta_max, 0.0, 1.0) * float(count - 1)
        i0 = wp.min(int(pos), count - 2)
        w = pos - float(i0)
        out = bands_t()
        for l in range(ORDER):
            out[l] = (1.0 - w) * et.log_cap[i0, l] + w * et.log_cap[i0 + 1, l]
        return out

    CAP_SCALE = [math.sqrt(math.pi / (2.0 * l + 1.0)) for l in range(ORDER)]
    LEG_A = [(2.0 * l + 1.0) / (l + 1.0) for l in range(ORDER)]
    LEG_B = [l / (l + 1.0) for l in range(ORDER)]

    @wp.func
    def cap_zh_blocked(theta: float) -> bands_t:
        # visibility of a blocking cap (eq. 33) in closed form, as sh.cap_zh(theta, blocked=True):
        # g_0 = sqrt(4 pi) - sqrt(pi) (1 - c), g_l = -sqrt(pi/(2l+1)) (P_{l-1}(c) - P_{l+1}(c))
        c = wp.cos(theta)
        out = bands_t()
        p_prev = float(1.0)  # P_{l-1}
        p_cur = c  # P_l
        out[0] = float(SQRT_4PI) - wp.static(CAP_SCALE[0]) * (1.0 - c)
        for l in range(wp.static(1), wp.static(ORDER)):
            p_next = wp.static(LEG_A[l]) * c * p_cur - wp.static(LEG_B[l]) * p_prev
            out[l] = -wp.static(CAP_SCALE[l]) * (p_prev - p_next)
            p_prev = p_cur
            p_cur = p_next
        return out

    # Constants of the associated-Legendre recurrences (as in sh_eval) and of the ZH rule,
    # folded into the generated code by wp.static so the per-blocker path has no sqrt.
    PMM = [0.0] * ORDER
    REC_A = [[0.0] * ORDER for _ in range(ORDER)]
    REC_B = [[0.0] * ORDER for _ in range(ORDER)]
    for m in range(ORDER):
        PMM[m] = 1.0 if m == 0 else -math.sqrt((2.0 * m + 1.0) / (2.0 * m))
        for l in range(m + 2, ORDER):
            REC_A[m][l] = math.sqrt((4.0 * l * l - 1.0) / (l * l - m * m))
            REC_B[m][l] = math.sqrt(((l - 1.0) ** 2 - m * m) / (4.0 * (l - 1.0) ** 2 - 1.0))
    FIRST = [math.sqrt(2.0 * m + 3.0) for m in range(ORDER)]
    ZH_SCALE = [math.sqrt(4.0 * math.pi / (2.0 * l + 1.0)) for l in range(ORDER)]
    Y00 = 0.5 / math.sqrt(math.pi)
    SQRT2 = math.sqrt(2.0)
    LL = [l * l + l for l in range(ORDER)]

    @wp.func
    def zh_accumulate(acc: vec_t, axis: wp.vec3, g: bands_t) -> vec_t:
        # acc + zh_to_sh(axis, g): the ZH rotation rule fused and fully unrolled with constant
        # recurrence coefficients (the per-blocker work of SHEXP, eq. 34)
        out = acc
        x = axis[0]
        y = axis[1]
        z = axis[2]
        gs = bands_t()
        for l in range(wp.static(ORDER)):
            gs[l] = g[l] * wp.static(ZH_SCALE[l])
        c = float(1.0)
        s = float(0.0)
        pmm = float(wp.static(Y00))
        for m in range(wp.static(ORDER)):
            pmm = pmm * wp.static(PMM[m])
            p_prev = float(0.0)
            p_cur = pmm
            for l in range(wp.static(ORDER)):
                if wp.static(l == m + 1):
                    p_prev = p_cur
                    p_cur = wp.static(FIRST[m]) * z * pmm
                if wp.static(l > m + 1):
                    p_next = wp.static(REC_A[m][l]) * (z * p_cur - wp.static(REC_B[m][l]) * p_prev)
                    p_prev = p_cur
                    p_cur = p_next
                if wp.static(m == 0):
                    out[wp.static(LL[l])] += gs[l] * p_cur
                if wp.static(m > 0 and l >= m):
                    w = gs[l] * p_cur * wp.static(SQRT2)
                    out[wp.static(LL[l] + m)] += w * c
                    out[wp.static(LL[l] - m)] += w * s
            c_next = c * x - s * y
            s = c * y + s * x
            c = c_next
        return out

    @wp.func
    def sh_log(g: vec_t, eps_rel: float, tables: SHTables) -> vec_t:
        # log(g) = R^T q'(D~) R (g - 1), eigenvalues of M_g clipped at eps_rel * largest
        # (eqs. 30-32); symmetric eigendecomposition by cyclic Jacobi rotations.
        a = mat_t()
        for i in range(N):
            e = tables.product_row_start[i]
            end = tables.product_row_start[i + 1]
            while e < end:
                pair = tables.product_pair[e]
                j = pair & 255
                k = pair >> 8
                w = tables.product_weight[e]
                a[i, j] = a[i, j] + w * g[k]
                a[i, k] = a[i, k] + w * g[j]
                e += 1
        v = mat_t()
        total = float(0.0)
        for i in range(N):
            v[i, i] = 1.0
            for j in range(N):
                total += a[i, j] * a[i, j]
        for sweep in range(16):
            off = float(0.0)
            for p in range(N):
                for q in range(p + 1, N):
                    off += a[p, q] * a[p, q]
            if off <= 1.0e-14 * total:
                break
            for p in range(N - 1):
                for q in range(p + 1, N):
                    apq = a[p, q]
                    if apq * apq > 1.0e-30 * total:
                        theta = (a[q, q] - a[p, p]) / (2.0 * apq)
                        t = 1.0 / (wp.abs(theta) + wp.sqrt(theta * theta + 1.0))
                        if theta < 0.0:
                            t = -t
                        c = 1.0 / wp.sqrt(t * t + 1.0)
                        s = t * c
                        for k in range(N):
                            akp = a[k, p]
                            akq = a[k, q]
                            a[k, p] = c * akp - s * akq
                            a[k, q] = s * akp + c * akq
                        for k in range(N):
                            apk = a[p, k]
                            aqk = a[q, k]
                            a[p, k] = c * apk - s * aqk
                            a[q, k] = s * apk + c * aqk
                        for k in range(N):
                            vkp = v[k, p]
                            vkq = v[k, q]
                            v[k, p] = c * vkp - s * vkq
                            v[k, q] = s * vkp + c * vkq
        largest = float(-1.0e30)
        for i in range(N):
            largest = wp.max(largest, a[i, i])
        out = vec_t()
        if largest <= 0.0:
            return out
        d = g - sh_one()
        for i in range(N):
            lam = wp.max(a[i, i], eps_rel * largest)
            t = lam - 1.0
            qp = float(0.0)
            if wp.abs(t) < 1.0e-3:
                qp = 1.0 - 0.5 * t + t * t / 3.0
            else:
                qp = wp.log(lam) / t
            coeff = float(0.0)
            for j in range(N):
                coeff += v[j, i] * d[j]
            coeff *= qp
            for j in range(N):
                out[j] = out[j] + v[j, i] * coeff
        return out

    return {
        "one": sh_one,
        "scaling_power": scaling_power,
        "exp_ps": exp_ps,
        "exp_ps_star": exp_ps_star,
        "exp_ol": exp_ol,
        "exp_hyb": exp_hyb,
        "ol_lookup": ol_lookup,
        "log_cap_zh": log_cap_zh,
        "cap_zh_blocked": cap_zh_blocked,
        "log": sh_log,
        "zh_accumulate": zh_accumulate,
    }
