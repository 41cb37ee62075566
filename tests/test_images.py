"""HDR image I/O: Radiance RGBE (hand-built byte streams as the oracle) and OpenEXR."""

import os

import numpy as np
import pytest

from warpshade.io import read_exr, read_hdr, read_image, write_exr, write_hdr

#: RGBE keeps 8 mantissa bits for the largest channel; Radiance's (m + 0.5) decoding of our
#: floor() encoding errs by at most half a quantum, i.e. 2**-8 of the pixel's largest channel.
RGBE_RELATIVE = 2.0**-8
#: EXR half channels: 11-bit significand, relative error <= 2**-11 after rounding.
HALF_RELATIVE = 2.0**-11

HEADER = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n"


def _decode(m, e):
    """Radiance's RGBE decoding, written out for the oracle values."""
    return 0.0 if e == 0 else (m + 0.5) * 2.0 ** (e - 136)


def test_flat_rgbe_bytes_decode_exactly(tmp_path):
    pixels = [(128, 64, 0, 129), (255, 1, 17, 140), (0, 0, 0, 0), (200, 100, 50, 120)]
    path = tmp_path / "flat.hdr"
    path.write_bytes(HEADER + b"-Y 2 +X 2\n" + bytes(v for p in pixels for v in p))
    img = read_hdr(path)
    expected = np.array([[_decode(m, p[3]) for m in p[:3]] for p in pixels], np.float32).reshape(2, 2, 3)
    assert img.shape == (2, 2, 3) and img.dtype == np.float32
    np.testing.assert_array_equal(img, expected)


def test_run_length_rgbe_bytes_decode_exactly(tmp_path):
    width = 9
    scan = bytes([2, 2, 0, width])
    scan += bytes([128 + width, 128])  # R: one run of 128
    scan += bytes([width]) + bytes(range(width))  # G: literal 0..8
    scan += bytes([128 + 4, 7, 5, 1, 2, 3, 4, 5])  # B: run of four 7s, literal 1..5
    scan += bytes([128 + width, 129])  # E: exponent 129 everywhere
    path = tmp_path / "rle.hdr"
    path.write_bytes(HEADER + f"-Y 1 +X {width}\n".encode() + scan)
    img = read_hdr(path)
    b = [7, 7, 7, 7, 1, 2, 3, 4, 5]
    expected = np.array([[_decode(128, 129), _decode(g, 129), _decode(b[x], 129)] for g, x in zip(range(width), range(width))])
    np.testing.assert_array_equal(img[0], expected.astype(np.float32))


def test_old_style_repeat_and_exposure(tmp_path):
    body = bytes([100, 50, 25, 130]) + bytes([1, 1, 1, 3])  # one pixel, repeated 3 more times
    path = tmp_path / "old.hdr"
    path.write_bytes(b"#?RADIANCE\nEXPOSURE=2.0\n\n-Y 1 +X 4\n" + body)
    img = read_hdr(path)
    expected = np.array([_decode(100, 130), _decode(50, 130), _decode(25, 130)]) / 2.0
    np.testing.assert_allclose(img[0], np.tile(expected, (4, 1)), rtol=1e-7)


@pytest.mark.parametrize("width", [5, 37])  # flat (< 8 wide) and run-length encoded rows
def test_hdr_round_trip(tmp_path, rng, width):
    img = (rng.lognormal(0.0, 2.0, size=(6, width, 3))).astype(np.float32)
    img[2] = img[2, :1]  # a constant row exercises run packets
    img[3, :, 1] = 0.0
    path = tmp_path / "rt.hdr"
    write_hdr(path, img)
    back = read_image(path)
    peak = img.max(axis=-1, keepdims=True)
    assert np.all(np.abs(back - img) <= RGBE_RELATIVE * peak * (1 + 1e-6))
    # a second write of the decoded image reproduces the same bytes (quantisation is stable)
    write_hdr(tmp_path / "rt2.hdr", back)
    assert (tmp_path / "rt2.hdr").read_bytes() == path.read_bytes()


def test_exr_channels_and_round_trip(tmp_path, rng):
    import OpenEXR

    img = rng.uniform(0.0, 50.0, size=(4, 8, 3)).astype(np.float32)
    write_exr(tmp_path / "rgb.exr", img)
    np.testing.assert_array_equal(read_image(tmp_path / "rgb.exr"), img)

    half = {c: img[..., k].astype(np.float16) for k, c in enumerate("RGB")}
    half["A"] = np.ones((4, 8), np.float16)
    with OpenEXR.File({"compression": OpenEXR.PIZ_COMPRESSION, "type": OpenEXR.scanlineimage}, half) as f:
        f.write(str(tmp_path / "half.exr"))
    np.testing.assert_allclose(read_exr(tmp_path / "half.exr"), img, rtol=HALF_RELATIVE)

    with OpenEXR.File({"type": OpenEXR.scanlineimage}, {"Y": np.ascontiguousarray(img[..., 0])}) as f:
        f.write(str(tmp_path / "grey.exr"))
    grey = read_exr(tmp_path / "grey.exr")
    np.testing.assert_array_equal(grey, np.repeat(img[..., :1], 3, axis=-1))


def test_missing_and_unreadable_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.hdr"):
        read_image(tmp_path / "nope.hdr")
    (tmp_path / "junk.hdr").write_bytes(b"not an image")
    with pytest.raises(ValueError, match="junk.hdr.*RADIANCE"):
        read_image(tmp_path / "junk.hdr")
    (tmp_path / "short.hdr").write_bytes(HEADER + b"-Y 4 +X 4\n" + bytes(12))
    with pytest.raises(ValueError, match="short.hdr.*truncated"):
        read_hdr(tmp_path / "short.hdr")
    (tmp_path / "rotated.hdr").write_bytes(HEADER + b"+X 1 -Y 1\n" + bytes(4))  # flips are read: tests/test_faults_outputs.py
    with pytest.raises(ValueError, match=r"resolution line b'\+X 1 -Y 1'"):
        read_hdr(tmp_path / "rotated.hdr")
    (tmp_path / "junk.exr").write_bytes(b"garbage")
    with pytest.raises(ValueError, match="junk.exr"):
        read_image(tmp_path / "junk.exr")
    (tmp_path / "pic.png").write_bytes(b"x")
    with pytest.raises(ValueError, match="unsupported extension"):
        read_image(tmp_path / "pic.png")


def test_writers_reject_bad_input_and_leave_no_temp_files(tmp_path):
    with pytest.raises(ValueError, match="NaN"):
        write_hdr(tmp_path / "bad.hdr", np.full((2, 2, 3), np.nan, np.float32))
    with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
        write_hdr(tmp_path / "bad.hdr", np.zeros((2, 2), np.float32))
    assert os.listdir(tmp_path) == []
