"""Tabulated BRDFs in the MERL binary layout: the half/diff parameterisation against a port of the
MERL reference code, file round trips, lookup accuracy against the analytic models, validation."""

import dataclasses
import json
import math
import struct

import numpy as np
import pytest

from warpshade.scene import _materials as M
from warpshade.scene import _tabulated as T

# The half/diff transform and its inverse, float64.
ATOL_TRANSFORM = 1e-10
# write -> read: stored = value / scale, read = stored * scale (one rounding each way).
RTOL_ROUNDTRIP = 1e-14
# b(v, s) vs b(s, v) of a tabulated BRDF: the same cell up to rounding of the angles.
RTOL_RECIPROCITY = 1e-12
# Relative RMS error of the lookup against the analytic model at random pairs with both
# cosines > MIN_COS (closer to the horizon the cells whose centre lies below it are invalid).
# Measured (40k pairs): GGX 0.5 / Blinn-Phong 20 at (32, 32, 64): nearest 0.128 / 0.053, linear
# 0.017 / 0.0036; at (90, 90, 180): nearest 0.045 / 0.019, linear 0.0021 / 0.0004.
MIN_COS = 0.1
RTOL_NEAREST_SMALL = 0.2
RTOL_LINEAR_SMALL = 0.03
RTOL_NEAREST_STANDARD = 0.07
RTOL_LINEAR_STANDARD = 0.004
# Linear lookup beats nearest by at least this factor (measured 7-15x).
LINEAR_GAIN = 4.0
# Pointwise relative error of the linear lookup of the smooth GGX lobe (measured max 0.024 at
# the small dims).
RTOL_LINEAR_POINTWISE_SMALL = 0.04

SMALL = (32, 32, 64)
GGX = M.Microfacet(0.5, "ggx")
BLINN = M.BlinnPhong(20.0)


def _hemi(rng, count, min_cos=MIN_COS):
    d = rng.normal(size=(4 * count, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d[:, 2] = np.abs(d[:, 2])
    return d[d[:, 2] > min_cos][:count]


def _rel_rms(x, ref):
    return float(np.sqrt(np.mean((x - ref) ** 2) / np.mean(ref**2)))


# ---- a direct port of the MERL reference code (BRDFRead.cpp) ----------------------------------


def _ref_rotate(vec, axis, angle):
    c, s = math.cos(angle), math.sin(angle)
    dot = sum(a * b for a, b in zip(axis, vec)) * (1.0 - c)
    cross = (axis[1] * vec[2] - axis[2] * vec[1], axis[2] * vec[0] - axis[0] * vec[2],
             axis[0] * vec[1] - axis[1] * vec[0])
    return [vec[i] * c + axis[i] * dot + cross[i] * s for i in range(3)]


def _ref_indices(light, view, dims):
    n_th, n_td, n_pd = dims
    half = [a + b for a, b in zip(light, view)]
    norm = math.sqrt(sum(x * x for x in half))
    half = [x / norm for x in half]
    theta_half, fi_half = math.acos(half[2]), math.atan2(half[1], half[0])
    diff = _ref_rotate(_ref_rotate(light, (0.0, 0.0, 1.0), -fi_half), (0.0, 1.0, 0.0), -theta_half)
    theta_diff, fi_diff = math.acos(diff[2]), math.atan2(diff[1], diff[0])
    ih = 0 if theta_half <= 0.0 else min(int(math.sqrt(theta_half / (math.pi / 2.0) * n_th * n_th)), n_th - 1)
    idd = min(max(int(theta_diff / (math.pi * 0.5) * n_td), 0), n_td - 1)
    if fi_diff < 0.0:
        fi_diff += math.pi
    ip = min(max(int(fi_diff / math.pi * n_pd), 0), n_pd - 1)
    return ih, idd, ip


@pytest.mark.parametrize("dims", [SMALL, T.MERL_DIMS])
def test_indices_match_the_reference_code(dims, rng):
    v, s = _hemi(rng, 300, 0.0), _hemi(rng, 300, 0.0)
    theta_h, _, theta_d, phi_d = T.half_diff_angles(v, s)
    got = np.stack(T.merl_indices(theta_h, theta_d, phi_d, dims), axis=-1)
    want = np.array([_ref_indices(list(si), list(vi), dims) for vi, si in zip(v, s)])
    np.testing.assert_array_equal(got, want)
    # the flat index of the reference code is the C-order index of the (n_th, n_td, n_pd) table
    flat = got[:, 2] + got[:, 1] * dims[2] + got[:, 0] * dims[2] * dims[1]
    np.testing.assert_array_equal(flat, np.ravel_multi_index(tuple(got.T), dims))


def test_half_diff_transform_and_inverse(rng):
    v = rng.normal(size=(2000, 3))
    s = rng.normal(size=(2000, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    s /= np.linalg.norm(s, axis=1, keepdims=True)
    th, ph, td, pd = T.half_diff_angles(v, s)
    v2, s2 = T.half_diff_directions(th, td, pd, ph)
    np.testing.assert_allclose(v2, v, atol=ATOL_TRANSFORM)
    np.testing.assert_allclose(s2, s, atol=ATOL_TRANSFORM)
    # angles -> directions -> angles (theta_h away from 0 and pi, where phi_h is undefined)
    th = rng.uniform(0.01, np.pi / 2, 2000)
    td = rng.uniform(0.0, np.pi / 2, 2000)
    pd = rng.uniform(-np.pi, np.pi, 2000)
    ph = rng.uniform(-np.pi, np.pi, 2000)
    got = T.half_diff_angles(*T.half_diff_directions(th, td, pd, ph))
    for a, b in zip(got, (th, ph, td, pd)):
        np.testing.assert_allclose(np.angle(np.exp(1j * (a - b))), 0.0, atol=ATOL_TRANSFORM)
    # the half vector of the constructed pair is the given one; reciprocity is phi_d + pi
    v, s = T.half_diff_directions(0.3, 0.7, 0.4)
    np.testing.assert_allclose((v + s) / np.linalg.norm(v + s), [np.sin(0.3), 0.0, np.cos(0.3)], atol=ATOL_TRANSFORM)
    np.testing.assert_allclose(T.half_diff_angles(s, v)[3], 0.4 - np.pi, atol=ATOL_TRANSFORM)


# ---- files ------------------------------------------------------------------------------------


@pytest.mark.parametrize("brdf", [GGX, BLINN], ids=lambda b: b.name)
def test_roundtrip_small_and_lookup_accuracy(brdf, tmp_path, rng):
    path = T.write_merl(tmp_path / f"{brdf.name}.binary", brdf, dims=SMALL)
    assert path.stat().st_size == T.MERL_HEADER_BYTES + 3 * np.prod(SMALL) * 8
    assert struct.unpack("<3i", path.read_bytes()[:12]) == SMALL
    tab = T.read_merl(path)
    want = T.tabulate(brdf, SMALL)
    invalid = want < 0.0
    assert invalid.any() and not invalid.all()
    np.testing.assert_allclose(tab.table[~invalid], want[~invalid], rtol=RTOL_ROUNDTRIP)
    scales = np.broadcast_to(np.asarray(T.MERL_SCALES)[:, None, None, None], want.shape)
    np.testing.assert_allclose(tab.table[invalid], T.MERL_INVALID * scales[invalid], rtol=RTOL_ROUNDTRIP)
    assert tab.dims == SMALL and tab.source == str(path)

    v, s = _hemi(rng, 20000), _hemi(rng, 20000)
    ref = brdf.evaluate(v, s)
    nearest = _rel_rms(tab.evaluate(v, s), ref)
    linear_brdf = T.read_merl(path, interpolation="linear")
    linear = _rel_rms(linear_brdf.evaluate(v, s), ref)
    assert nearest < RTOL_NEAREST_SMALL
    assert linear < RTOL_LINEAR_SMALL
    assert linear * LINEAR_GAIN < nearest
    if brdf is GGX:
        np.testing.assert_allclose(linear_brdf.evaluate(v, s), ref, rtol=RTOL_LINEAR_POINTWISE_SMALL)


def test_roundtrip_standard_dims(tmp_path, rng):
    path = T.write_merl(tmp_path / "ggx.binary", GGX)
    assert path.stat().st_size == 12 + 3 * 90 * 90 * 180 * 8
    assert not list(tmp_path.glob(".*"))  # no temporary left behind
    v, s = _hemi(rng, 20000), _hemi(rng, 20000)
    ref = GGX.evaluate(v, s)
    nearest = T.read_merl(path)
    assert nearest.dims == T.MERL_DIMS
    assert _rel_rms(nearest.evaluate(v, s), ref) < RTOL_NEAREST_STANDARD
    linear = dataclasses.replace(nearest, interpolation="linear")
    assert linear.describe()["table_sha1"] == nearest.describe()["table_sha1"]
    assert _rel_rms(linear.evaluate(v, s), ref) < RTOL_LINEAR_STANDARD


def test_channels_and_scales(tmp_path, rng):
    rgb = (0.5, 1.0, 2.0)
    path = T.write_merl(tmp_path / "colour.binary", BLINN, dims=SMALL, rgb=rgb)
    stored = np.frombuffer(path.read_bytes()[12:], dtype="<f8").reshape(3, *SMALL)
    tab = T.read_merl(path)
    valid = tab.table[0] > 0.0
    for c in range(3):
        np.testing.assert_allclose(tab.table[c][valid] / tab.table[0][valid], rgb[c] / rgb[0], rtol=RTOL_ROUNDTRIP)
        np.testing.assert_allclose(stored[c][valid] * T.MERL_SCALES[c], tab.table[c][valid], rtol=RTOL_ROUNDTRIP)
    assert np.all(stored[tab.table < 0.0] == T.MERL_INVALID)

    v, s = _hemi(rng, 500, 0.0), _hemi(rng, 500, 0.0)
    for interpolation in ("nearest", "linear"):
        brdf = T.TabulatedBRDF(tab.table, interpolation=interpolation)
        colour = brdf.rgb(v, s)
        assert colour.shape == (500, 3)
        np.testing.assert_allclose(brdf.evaluate(v, s), colour @ np.asarray(T.LUMINANCE_WEIGHTS), rtol=1e-12)
        for c, names in enumerate((("r", 0), ("g", 1), ("b", 2))):
            for name in names:
                one = T.TabulatedBRDF(tab.table, channel=name, interpolation=interpolation)
                np.testing.assert_array_equal(one.evaluate(v, s), colour[:, c])
    with pytest.raises(ValueError, match="channel"):
        T.TabulatedBRDF(tab.table, channel="alpha")
    with pytest.raises(ValueError, match="interpolation"):
        T.TabulatedBRDF(tab.table, interpolation="cubic")


# ---- lookup properties ------------------------------------------------------------------------


@pytest.mark.parametrize("interpolation", ["nearest", "linear"])
def test_reciprocity_horizon_and_cell_centres(interpolation, rng):
    brdf = T.TabulatedBRDF.from_brdf(GGX, SMALL, interpolation=interpolation)
    v, s = _hemi(rng, 2000, 0.0), _hemi(rng, 2000, 0.0)
    np.testing.assert_allclose(brdf.evaluate(v, s), brdf.evaluate(s, v), rtol=RTOL_RECIPROCITY)
    below = s * np.array([1.0, 1.0, -1.0])
    assert np.all(brdf.evaluate(v, below) == 0.0) and np.all(brdf.evaluate(below, v) == 0.0)
    assert np.all(brdf.rgb(below, v) == 0.0)
    assert np.all(brdf.evaluate(v, -v) == 0.0)  # v + s = 0 is handled
    # at the cell centres the lookup returns the table
    th, td, pd = T.merl_cell_centres(SMALL)
    cv, cs = T.half_diff_directions(th[:, None, None], td[None, :, None], pd[None, None, :])
    table = np.tensordot(T.LUMINANCE_WEIGHTS, brdf.table, 1)
    valid = np.all(brdf.table >= 0.0, axis=0)
    np.testing.assert_allclose(brdf.evaluate(cv, cs)[valid], table[valid], rtol=1e-9)
    # resampling a tabulated BRDF on its own cells gives its table back
    if interpolation == "nearest":
        np.testing.assert_array_equal(T.tabulate(brdf, SMALL), brdf.table)


def test_invalid_cells(rng):
    dims = (8, 8, 16)
    table = np.full((3, *dims), 0.1)
    table[:, rng.random(dims) < 0.3] = T.MERL_INVALID
    v, s = _hemi(rng, 3000, 0.0), _hemi(rng, 3000, 0.0)
    nearest = T.TabulatedBRDF(table).evaluate(v, s)
    assert set(np.unique(nearest)) <= {0.0, 0.1} and np.any(nearest == 0.0)
    linear = T.TabulatedBRDF(table, interpolation="linear").evaluate(v, s)
    # invalid cells are left out of the blend rather than read as 0
    np.testing.assert_allclose(linear[nearest > 0.0], 0.1, rtol=1e-12)
    assert np.all((linear == 0.0) | np.isclose(linear, 0.1, rtol=1e-12))


def test_describe_is_a_stable_content_key(tmp_path):
    a = T.TabulatedBRDF.from_brdf(GGX, SMALL)
    b = T.TabulatedBRDF.from_brdf(M.Microfacet(0.5, "ggx"), SMALL)
    d = a.describe()
    assert json.loads(json.dumps(d)) == d
    assert d == b.describe()
    assert d["model"] == "tabulated" and d["dims"] == list(SMALL) and len(d["table_sha1"]) == 16
    changed = a.table.copy()
    changed[1, 3, 4, 5] *= 1.0 + 1e-9
    assert T.TabulatedBRDF(changed).describe()["table_sha1"] != d["table_sha1"]
    assert T.TabulatedBRDF(a.table, interpolation="linear").describe() != d
    assert T.TabulatedBRDF(a.table, channel=1).describe()["channel"] == "g"
    assert T.TabulatedBRDF.from_brdf(BLINN, SMALL).describe()["table_sha1"] != d["table_sha1"]
    path = T.write_merl(tmp_path / "a.binary", GGX, dims=SMALL)
    read = T.read_merl(path).describe()
    assert read["source"] == str(path) and read["dims"] == list(SMALL)
    with pytest.raises(ValueError):  # the table is a read-only copy
        a.table[0, 0, 0, 0] = 1.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.interpolation = "linear"


# ---- validation -------------------------------------------------------------------------------


def _write_raw(path, dims, values=None, extra=b""):
    data = struct.pack("<3i", *dims)
    if values is not None:
        data += np.asarray(values, dtype="<f8").tobytes()
    path.write_bytes(data + extra)
    return path


def _bad_files(tmp_path):
    dims = (2, 3, 4)
    good = np.full(3 * 24, 100.0)
    nan = good.copy()
    nan[[30, 31, 50]] = [np.nan, np.inf, -np.inf]
    short = tmp_path / "short.binary"
    short.write_bytes(struct.pack("<2i", 90, 90))
    return [
        (tmp_path / "missing.binary", "no such file"),
        (tmp_path, "not a regular file"),
        (short, "shorter"),
        (_write_raw(tmp_path / "zero_dim.binary", (0, 3, 4)), "1..4096"),
        (_write_raw(tmp_path / "neg_dim.binary", (2, -3, 4), good), "1..4096"),
        (_write_raw(tmp_path / "huge_dim.binary", (5000, 1, 1), np.ones(3 * 5000)), "1..4096"),
        (_write_raw(tmp_path / "truncated.binary", dims, good[:-1]), f"expected {12 + 72 * 8} bytes"),
        (_write_raw(tmp_path / "trailing.binary", dims, good, b"\0"), f"got {12 + 72 * 8 + 1}"),
        (_write_raw(tmp_path / "nan.binary", dims, nan), "3 non-finite"),
        (_write_raw(tmp_path / "zeros.binary", dims, np.zeros(72)), "no positive"),
        (_write_raw(tmp_path / "negative.binary", dims, -np.ones(72)), "no positive"),
    ]


def test_bad_files_name_the_file(tmp_path):
    for path, what in _bad_files(tmp_path):
        with pytest.raises(ValueError) as exc:
            T.read_merl(path)
        message = str(exc.value)
        assert str(path) in message and what in message, message
    with pytest.raises(ValueError, match=r"\(1, 0, 1, 2\)"):  # the first non-finite entry: flat 30 = 24 + 1 * 4 + 2
        T.read_merl(tmp_path / "nan.binary")


def test_write_validation(tmp_path):
    with pytest.raises(ValueError, match="dims"):
        T.write_merl(tmp_path / "x.binary", GGX, dims=(0, 4, 4))
    with pytest.raises(ValueError, match="x.binary"):
        T.write_merl(tmp_path / "x.binary", GGX, dims=(4, 4, 4), rgb=(0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="rgb"):
        T.tabulate(GGX, (4, 4, 4), rgb=(1.0, -1.0, 1.0))
    assert not list(tmp_path.iterdir())
    with pytest.raises(ValueError, match="non-finite"):
        T.TabulatedBRDF(np.full((3, 2, 2, 2), np.nan))
    with pytest.raises(ValueError, match="shape"):
        T.TabulatedBRDF(np.ones((2, 2, 2)))
