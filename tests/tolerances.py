"""Named tolerances shared by several test files, and the assertions that use them.

A tolerance lives here when more than one file compares the same kind of result (a float32 Warp
kernel against its float64 mirror, a quadrature against a closed form, a Monte Carlo estimate
against its oracle); a bound that belongs to one test's own numerics stays in that file, next to
the comment that justifies it. Imported by name (``from tolerances import ATOL_FLOAT32``) through
pytest's ``pythonpath = ["tests"]``.
"""

from __future__ import annotations

import numpy as np

#: float64 identities: closed forms against each other or exact quadrature, sums of a few dozen
#: products of O(1) numbers.
ATOL_FLOAT64 = 1e-12
#: A float32 Warp kernel against its float64 mirror on O(1) values: a few normalisations or a
#: float32 sum of up to ~1000 terms of size <= 4 pi / S (SH recurrences to order 4, barycentric
#: interpolation, positions of magnitude 1-3). Absolute.
ATOL_FLOAT32 = 2e-5
#: The same comparison, relative: a few ulp of exp/erf at O(1) magnitudes, float32 accumulation
#: against float64 oracles.
RTOL_FLOAT32 = 2e-5
#: float32 zonal-harmonic kernels against float64: |y_lm| <= 2.7 times O(1) inputs, a sum of at
#: most 36 float32 terms per band.
ATOL_ZH_FLOAT32 = 5e-6
#: Gauss-Legendre projection (degree 400) of a function with a kink at the horizon (the clamped
#: cosine, the membrane function): the product rule's error on the kink is far below this.
ATOL_QUADRATURE = 2e-4
#: Bilinear look-ups in a lighting table over normals against direct SH evaluation, relative to
#: the largest radiance: ldprt's 65 x 128 table (order 3; interpolation error ~5e-4 of the lighting
#: norm) and shexp's 33 x 64 L*H(N) table (L*H a polynomial of degree <= 3 in N; measured 6e-4).
RTOL_TABLE = 3e-3
#: A recorded (replayed) launch runs the same float32 kernels on the same inputs as an uncaptured
#: one: results agree to a few ulps, relative to the model's size.
REPLAY_RTOL = 1e-6
#: A Monte Carlo estimate lies within this many of its reported standard errors of the oracle
#: (a false failure about once in 1.7 million independent comparisons).
STDERR_SIGMAS = 5.0


def _where(index: tuple) -> str:
    return f" at index {tuple(int(k) for k in index)}" if index else ""


def assert_close(actual, expected, *, rtol: float = 0.0, atol: float = 0.0, what: str = "value") -> None:
    """Assert ``|actual - expected| <= atol + rtol * |expected|`` elementwise.

    ``actual`` and ``expected`` broadcast against each other (any shape, float). On failure the
    message names ``what``, the worst element, both values, the error and the bound it broke.
    """
    a = np.asarray(actual, dtype=np.float64)
    e = np.asarray(expected, dtype=np.float64)
    a, e = np.broadcast_arrays(a, e)
    err = np.abs(a - e)
    bound = atol + rtol * np.abs(e)
    bad = ~(err <= bound)  # NaN in either input fails
    if bad.any():
        excess = np.where(bad, np.nan_to_num(err - bound, nan=np.inf), -np.inf)
        i = np.unravel_index(int(np.argmax(excess)), excess.shape)
        raise AssertionError(
            f"{what}: {int(bad.sum())} of {bad.size} elements differ{_where(i)}: {a[i]:.9g} vs expected {e[i]:.9g} "
            f"(|error| {err[i]:.3g} > atol {atol:.3g} + rtol {rtol:.3g} * |expected| = {bound[i]:.3g})")


def assert_within_stderr(estimate, expected, stderr, *, sigmas: float = STDERR_SIGMAS, floor=0.0,
                         what: str = "estimate") -> None:
    """Assert a Monte Carlo ``estimate`` lies within ``sigmas * stderr + floor`` of ``expected``.

    All arguments broadcast against each other (float, any shape); ``floor`` (absolute, may be an
    array) covers float32 rounding where the standard error is zero. On failure the message names
    ``what``, the worst element and its error in standard errors.
    """
    est = np.asarray(estimate, dtype=np.float64)
    exp = np.asarray(expected, dtype=np.float64)
    sd = np.asarray(stderr, dtype=np.float64)
    est, exp, sd, fl = np.broadcast_arrays(est, exp, sd, np.asarray(floor, dtype=np.float64))
    err = np.abs(est - exp)
    bound = sigmas * sd + fl
    bad = ~(err <= bound)
    if bad.any():
        excess = np.where(bad, np.nan_to_num(err - bound, nan=np.inf), -np.inf)
        i = np.unravel_index(int(np.argmax(excess)), excess.shape)
        z = err[i] / sd[i] if sd[i] > 0 else np.inf
        raise AssertionError(
            f"{what}: {int(bad.sum())} of {bad.size} elements outside {sigmas:g} standard errors{_where(i)}: "
            f"{est[i]:.9g} vs expected {exp[i]:.9g} (|error| {err[i]:.3g} = {z:.3g} stderr, bound {bound[i]:.3g} "
            f"with floor {fl[i]:.3g})")
