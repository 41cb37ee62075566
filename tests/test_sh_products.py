"""Triple product tensor, SH products and product matrices against independent oracles.

Oracles: exact Gauss-Legendre quadrature of products of basis functions, sympy's exact
(real) Gaunt coefficients, and the selection-rule counts of the SHEXP paper.
"""

import itertools

import numpy as np
import pytest

from warpshade.basis import quadrature, sh
from warpshade.basis.sh_warp import SHTables, sh_kernels
from warpshade._wp import wp

sympy_wigner = pytest.importorskip("sympy.physics.wigner")
scipy_special = pytest.importorskip("scipy.special")

# Exact quadrature of a degree-3(n-1) integrand vs closed form: float64 rounding over <= 242
# nodes and the sum of (up to 8) complex Gaunt terms.
ATOL_TENSOR = 1e-13
# A quadrature entry below this is an (exact or accidental) zero of the tensor.
ZERO_TOL = 1e-10
# Products of coefficient vectors of O(1) entries: float64 sums of <= 13k terms.
ATOL_PRODUCT_FLOAT64 = 1e-12
# float32 kernel: each output sums ~K/n^2 (<= ~80 at n = 6) products of O(1) inputs with O(0.3)
# weights; float32 rounding 6e-8 per operation gives a few 1e-6 in the worst case.
ATOL_PRODUCT_FLOAT32 = 1e-5

# Nonzero-count table of the SHEXP paper (Ren et al. 2006, sec. 3) for orders 1..8. It counts
# entries allowed by the selection rules (including accidental zeros); the order-4 entry (369)
# does not match the rules (359), so it is left out of the comparison.
PAPER_COUNTS = {1: 1, 2: 10, 3: 83, 5: 1164, 6: 2961, 7: 6586, 8: 13018}


def quadrature_tensor(order: int) -> np.ndarray:
    q = quadrature.gauss_legendre(3 * (order - 1))
    y = sh.basis(q.directions, order)
    return np.einsum("p,pi,pj,pk->ijk", q.weights, y, y, y, optimize=True)


def dense(order: int) -> np.ndarray:
    idx, val = sh.triple_product_tensor(order)
    t = np.zeros((order * order,) * 3)
    t[idx[:, 0], idx[:, 1], idx[:, 2]] = val
    return t


def lm_of(i: int) -> tuple[int, int]:
    l = int(np.sqrt(i))
    return l, i - l * l - l


@pytest.mark.parametrize("order", range(1, 9))
def test_tensor_matches_quadrature(order):
    t_quad = quadrature_tensor(order)
    t = dense(order)
    assert np.abs(t - t_quad).max() < ATOL_TENSOR
    # The sparse list holds exactly the nonzero entries: nothing missing, no stored zeros.
    np.testing.assert_array_equal(np.abs(t_quad) > ZERO_TOL, t != 0)
    idx, val = sh.triple_product_tensor(order)
    n6 = order**6
    print(f"order {order}: K = {len(val)} nonzeros of {n6} ({100.0 * len(val) / n6:.2f} %)")


def selection_rule_count(order: int) -> int:
    """Entries allowed by the real-Gaunt selection rules, counted by brute force over (i, j, k)."""
    lm = np.array([lm_of(i) for i in range(order * order)])
    l, m = lm[:, 0], lm[:, 1]
    la, lb, lc = np.meshgrid(l, l, l, indexing="ij")
    ma, mb, mc = np.meshgrid(m, m, m, indexing="ij")
    triangle = (lc <= la + lb) & (lc >= np.abs(la - lb)) & ((la + lb + lc) % 2 == 0)
    a, b, c = np.sort(np.stack([np.abs(ma), np.abs(mb), np.abs(mc)]), axis=0)
    azimuth = (c == a + b) & (((ma < 0).astype(int) + (mb < 0) + (mc < 0)) % 2 == 0)
    return int(np.count_nonzero(triangle & azimuth))


@pytest.mark.parametrize("order", sorted(PAPER_COUNTS))
def test_selection_rules_reproduce_paper_counts(order):
    allowed = selection_rule_count(order)
    assert allowed == PAPER_COUNTS[order]
    # Everything the tensor stores is allowed; the difference is the accidental zeros.
    assert len(sh.triple_product_tensor(order)[1]) <= allowed


def test_symmetry_of_the_tensor():
    t = dense(5)
    for perm in itertools.permutations(range(3)):
        np.testing.assert_array_equal(t, np.transpose(t, perm))
    # Gamma_0jk = delta_jk / sqrt(4 pi): multiplying by the constant function.
    np.testing.assert_allclose(t[0], np.eye(25) / np.sqrt(4 * np.pi), atol=1e-15)


def sympy_sign_map(order: int) -> np.ndarray:
    """s_i = +-1 with sympy's real SH Z_i = s_i y_i, found numerically from sympy's own U matrix.

    sympy.physics.wigner.real_gaunt documents Z_l^mu = sum_m U^mu_m Y_l^m with
    U^mu_m = delta_|mu||m| (delta_m0 delta_mu0 + [Theta(mu)(delta_m,mu + (-1)^m delta_m,-mu)
    + i Theta(-mu)((-1)^m delta_m,mu - delta_m,-mu)] / sqrt(2)); Y_l^m is scipy's sph_harm_y.
    """
    rng = np.random.default_rng(5)
    d = rng.standard_normal((8, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    theta, phi = np.arccos(d[:, 2]), np.arctan2(d[:, 1], d[:, 0])
    y = sh.basis(d, order)
    signs = np.empty(order * order)
    for i in range(order * order):
        l, mu = lm_of(i)
        big_y = lambda m: scipy_special.sph_harm_y(l, m, theta, phi)  # noqa: E731
        if mu == 0:
            z = big_y(0)
        elif mu > 0:
            z = (big_y(mu) + (-1) ** mu * big_y(-mu)) / np.sqrt(2)
        else:
            z = 1j * ((-1) ** mu * big_y(mu) - big_y(-mu)) / np.sqrt(2)
        assert np.abs(z.imag).max() < 1e-12
        ratio = z.real / y[:, i]
        assert np.allclose(ratio, ratio[0], atol=1e-10) and abs(abs(ratio[0]) - 1) < 1e-10
        signs[i] = np.sign(ratio[0])
    return signs


def test_matches_sympy_real_gaunt_all_entries_low_orders():
    order = 3
    signs = sympy_sign_map(order)
    t = dense(order)
    for i, j, k in itertools.product(range(order * order), repeat=3):
        (a, ma), (b, mb), (c, mc) = lm_of(i), lm_of(j), lm_of(k)
        expect = signs[i] * signs[j] * signs[k] * float(sympy_wigner.real_gaunt(a, b, c, ma, mb, mc))
        assert t[i, j, k] == pytest.approx(expect, abs=ATOL_TENSOR)


@pytest.mark.parametrize("order", [4, 5, 6, 7, 8])
def test_matches_sympy_real_gaunt_sampled(order, rng):
    # sympy is exact but slow: compare a random sample of stored (nonzero) entries, weighted to
    # the highest band, and of arbitrary index triples (mostly zeros) at the higher orders.
    signs = sympy_sign_map(order)
    t = dense(order)
    idx, _ = sh.triple_product_tensor(order)
    top = np.flatnonzero(idx.max(axis=1) >= (order - 1) ** 2)  # entries touching band n-1
    picks = (
        list(idx[rng.choice(top, 6, replace=False)])
        + list(idx[rng.choice(len(idx), 4, replace=False)])
        + list(rng.integers(0, order * order, (5, 3)))
    )
    for i, j, k in picks:
        (a, ma), (b, mb), (c, mc) = lm_of(i), lm_of(j), lm_of(k)
        expect = signs[i] * signs[j] * signs[k] * float(sympy_wigner.real_gaunt(a, b, c, ma, mb, mc, prec=30))
        assert t[i, j, k] == pytest.approx(expect, abs=ATOL_TENSOR)


def test_complex_gaunt_matches_sympy():
    from warpshade.basis import sh as _gaunt  # complex_gaunt

    for a, b, c, ma, mb in [(1, 1, 2, 1, -1), (3, 2, 3, -2, 0), (5, 4, 7, 3, -4), (7, 7, 6, 5, -3)]:
        mc = -ma - mb
        expect = float(sympy_wigner.gaunt(a, b, c, ma, mb, mc))
        assert _gaunt.complex_gaunt(a, b, c, ma, mb, mc) == pytest.approx(expect, abs=1e-15)


def random_coeffs(rng, shape, order):
    """Coefficients with a decaying spectrum (like real lighting/visibility), O(1) entries."""
    f = rng.standard_normal(shape + (order * order,))
    return f / (1.0 + sh.band_of(order))


@pytest.mark.parametrize("order", [1, 2, 4, 6, 8])
def test_product_matches_quadrature_projection(order, rng):
    f = random_coeffs(rng, (3,), order)
    g = random_coeffs(rng, (3,), order)
    q = quadrature.gauss_legendre(3 * (order - 1))
    y = sh.basis(q.directions, order)
    fg = (y @ f.T) * (y @ g.T)  # (P, 3): f(s) g(s) on the nodes
    expect = ((y * q.weights[:, None]).T @ fg).T  # projected back onto order n
    np.testing.assert_allclose(sh.product(f, g), expect, atol=ATOL_PRODUCT_FLOAT64)
    np.testing.assert_allclose(sh.square(f), sh.product(f, f), atol=ATOL_PRODUCT_FLOAT64)


def test_product_matrix_consistency(rng):
    order = 5
    f = random_coeffs(rng, (2, 3), order)
    g = random_coeffs(rng, (2, 3), order)
    m = sh.product_matrix(f)
    assert m.shape == (2, 3, 25, 25)
    np.testing.assert_allclose(m, np.swapaxes(m, -1, -2), atol=1e-15)
    np.testing.assert_allclose(np.einsum("...ij,...j->...i", m, g), sh.product(f, g), atol=ATOL_PRODUCT_FLOAT64)
    # The constant function 1 has f_0 = sqrt(4 pi): its product matrix is the identity.
    one = np.zeros(25)
    one[0] = np.sqrt(4 * np.pi)
    np.testing.assert_allclose(sh.product_matrix(one), np.eye(25), atol=1e-14)


def test_product_broadcasts_and_rejects_bad_input(rng):
    f = random_coeffs(rng, (4, 1), 3)
    g = random_coeffs(rng, (5,), 3)
    out = sh.product(f, g)
    assert out.shape == (4, 5, 9)
    np.testing.assert_allclose(out[2, 3], sh.product(f[2, 0], g[3]), atol=1e-15)
    with pytest.raises(ValueError, match="order"):
        sh.product(np.zeros(9), np.zeros(16))
    with pytest.raises(ValueError, match="order\\*\\*2"):
        sh.product(np.zeros(8), np.zeros(8))
    with pytest.raises(ValueError, match="NaN"):
        sh.product(np.full(4, np.nan), np.zeros(4))


@pytest.mark.parametrize("order", [4, 6])
def test_warp_product_kernels_match_reference(order, device, rng):
    f = random_coeffs(rng, (64,), order)
    g = random_coeffs(rng, (64,), order)
    got = sh.product(f, g, device=device)
    assert got.dtype == np.float32 and got.shape == (64, order * order)
    assert np.abs(got - sh.product(f, g)).max() < ATOL_PRODUCT_FLOAT32
    m = sh.product_matrix(f[:8], device=device)
    assert np.abs(m - sh.product_matrix(f[:8])).max() < ATOL_PRODUCT_FLOAT32


@pytest.mark.parametrize("order", [3, 4, 5])  # 5: above PRODUCT_UNROLL_ORDER, the table loop
def test_unrolled_product_is_the_table_product(order, device, rng):
    """``product_unrolled`` (straight-line code) sums the same entries in the same order as the
    table loop: bit-identical results, and the float64 product to float32 accuracy."""
    k = sh_kernels(order)

    @wp.kernel(enable_backward=False, module="unique")
    def both(f: wp.array2d(dtype=wp.float32), g: wp.array2d(dtype=wp.float32), tables: SHTables,
             out_loop: wp.array2d(dtype=wp.float32), out_unrolled: wp.array2d(dtype=wp.float32)):
        i = wp.tid()
        a = k.load(f, i)
        b = k.load(g, i)
        k.store(out_loop, i, k.product(a, b, tables))
        k.store(out_unrolled, i, k.product_unrolled(a, b, tables))

    f = random_coeffs(rng, (64,), order).astype(np.float32)
    g = random_coeffs(rng, (64,), order).astype(np.float32)
    loop = wp.empty((64, order * order), dtype=wp.float32, device=device)
    unrolled = wp.empty_like(loop)
    wp.launch(both, dim=64, device=device, inputs=[wp.array(f, device=device), wp.array(g, device=device),
                                                   k.tables(device), loop, unrolled])
    np.testing.assert_array_equal(unrolled.numpy(), loop.numpy())
    assert np.abs(unrolled.numpy() - sh.product(f.astype(np.float64), g.astype(np.float64))).max() < ATOL_PRODUCT_FLOAT32


def test_warp_funcs_compose_inside_a_user_kernel(device, rng):
    """The bundle's @wp.func members used the way later kernels use them: a per-receiver loop
    multiplying several blocker visibilities, then windowing and a ZH projection."""
    order = 4
    k = sh_kernels(order)

    @wp.kernel(enable_backward=False, module="unique")
    def accumulate(
        blockers: wp.array3d(dtype=wp.float32),
        alpha: wp.array(dtype=wp.float32),
        axis: wp.vec3,
        tables: SHTables,
        out: wp.array2d(dtype=wp.float32),
        zh_out: wp.array2d(dtype=wp.float32),
    ):
        r = wp.tid()
        acc = k.load(blockers[r], 0)
        for b in range(1, blockers.shape[1]):
            acc = k.product(acc, k.load(blockers[r], b), tables)
        a = k.bands()
        for l in range(order):
            a[l] = alpha[l]
        acc = k.scale_bands(k.square(acc, tables), a)
        k.store(out, r, acc)
        g = k.zh_from_sh_about_axis(acc, axis)
        for l in range(order):
            zh_out[r, l] = g[l]

    receivers, count = 6, 3
    vis = random_coeffs(rng, (receivers, count), order)
    alpha = sh.window_weights("cosine", order)
    axis = np.array([0.2, -0.3, 0.9])
    axis /= np.linalg.norm(axis)
    out = wp.empty((receivers, order * order), dtype=wp.float32, device=device)
    zh_out = wp.empty((receivers, order), dtype=wp.float32, device=device)
    wp.launch(
        accumulate,
        dim=receivers,
        inputs=[
            wp.array(vis.astype(np.float32), dtype=wp.float32, device=device),
            wp.array(alpha.astype(np.float32), dtype=wp.float32, device=device),
            wp.vec3(*axis.astype(np.float32)),
            k.tables(device),
            out,
            zh_out,
        ],
        device=device,
    )
    expect = vis[:, 0]
    for b in range(1, count):
        expect = sh.product(expect, vis[:, b])
    expect = sh.window(sh.square(expect), "cosine")
    assert np.abs(out.numpy() - expect).max() < ATOL_PRODUCT_FLOAT32
    assert np.abs(zh_out.numpy() - sh.zh_from_sh_about_axis(expect, axis)).max() < ATOL_PRODUCT_FLOAT32


def test_chunked_cpu_launches_match_one_launch(monkeypatch, rng):
    # Large CPU launches are split over a thread pool; force the split on a small batch.
    order = 4
    f = random_coeffs(rng, (37,), order)
    g = random_coeffs(rng, (37,), order)
    r = quadrature.random_rotations(37, seed=4)
    single = (sh.product(f, g, device="cpu"), sh.rotate(f, r, device="cpu"), sh.basis(f[:, 1:4], order, device="cpu"))
    monkeypatch.setattr(sh, "CPU_CHUNK_MIN_ROWS", 4)
    chunked = (sh.product(f, g, device="cpu"), sh.rotate(f, r, device="cpu"), sh.basis(f[:, 1:4], order, device="cpu"))
    for a, b in zip(single, chunked):
        np.testing.assert_array_equal(a, b)
