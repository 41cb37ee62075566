"""Reading and writing linear HDR images: OpenEXR (through the ``OpenEXR`` package) and Radiance .hdr.

All images are returned as float32 arrays of shape (height, width, 3), linear RGB, row 0 at the
top of the image (the first scanline stored in the file for Radiance "-Y H +X W" images, the
``dataWindow.min.y`` row for OpenEXR). Single-channel images (``Y`` or one unnamed channel) are
broadcast to grey; an alpha channel is ignored.

Radiance .hdr (RGBE) details:

* reading accepts the flat layout, the "new" run-length encoding (``2 2 hi lo`` scanline
  header) and the "old" run-length encoding (``1 1 1 n`` repeat pixels); the standard
  "-Y H +X W" orientation and its flips ("+Y H +X W" stores the bottom row first, "-X" each
  row right to left) are accepted, rotated ones ("+X W -Y H") are not. An ``EXPOSURE=`` header
  value is divided out so the returned values are the original radiance (Radiance's own
  convention). A size above :data:`warpshade._limits.MAX_IMAGE_PIXELS` is refused before
  anything is allocated;
* decoding uses Radiance's rounding, ``value = (mantissa + 0.5) * 2**(exponent - 136)``;
* writing uses the new run-length encoding (runs of equal bytes of length >= 4 become run
  packets, everything else literal packets), which every common reader accepts.

Errors: a missing file raises FileNotFoundError naming it; a file that exists but cannot be
decoded raises ValueError naming it and saying why. Writers go through a temporary file and
``os.replace`` so a failed write never leaves a truncated image behind.
"""

from __future__ import annotations

import os

import numpy as np

from .._fileio import atomic_path

__all__ = [
    "IMAGE_EXTENSIONS",
]

#: File extensions :func:`read_image` understands (lower case).
IMAGE_EXTENSIONS = (".exr", ".hdr", ".pic", ".rgbe")

_RGBE_EXPONENT_BIAS = 136  # 128 exponent bias + 8 mantissa bits


def _check_exists(path) -> str:
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"image file not found: {path}")
    return path


def read_image(path) -> np.ndarray:
    """Read a linear HDR image by extension (.exr, or .hdr/.pic/.rgbe).

    Returns:
        Radiance, shape (height, width, 3), float32, linear RGB.

    Raises:
        FileNotFoundError: the file does not exist.
        ValueError: unknown extension, or the file cannot be decoded (the message names it).
    """
    path = _check_exists(path)
    ext = os.path.splitext(path)[1].lower()
    if ext == ".exr":
        return read_exr(path)
    if ext in (".hdr", ".pic", ".rgbe"):
        return read_hdr(path)
    raise ValueError(f"image {path}: unsupported extension {ext!r} (supported: {', '.join(IMAGE_EXTENSIONS)})")


# ---- OpenEXR ---------------------------------------------------------------------------------
def read_exr(path) -> np.ndarray:
    """Read an OpenEXR image (scanline or tiled, half/float/uint channels) as (H, W, 3) float32."""
    import OpenEXR

    path = _check_exists(path)
    try:
        with OpenEXR.File(path, separate_channels=True) as exr:
            channels = {name: np.asarray(ch.pixels) for name, ch in exr.channels().items()}
    except Exception as exc:  # the binding raises RuntimeError for unreadable files
        raise ValueError(f"image {path}: not a readable OpenEXR file ({exc})") from exc
    # Layer prefixes ("diffuse.R") are matched on the last component; the unprefixed layer wins.
    by_suffix: dict[str, np.ndarray] = {}
    for name in sorted(channels, key=lambda n: n.count(".")):
        by_suffix.setdefault(name.rsplit(".", 1)[-1].upper(), channels[name])
    if all(c in by_suffix for c in "RGB"):
        img = np.stack([by_suffix[c] for c in "RGB"], axis=-1)
    elif "Y" in by_suffix:
        img = np.repeat(by_suffix["Y"][..., None], 3, axis=-1)
    elif len(channels) == 1:
        img = np.repeat(next(iter(channels.values()))[..., None], 3, axis=-1)
    else:
        raise ValueError(f"image {path}: no R, G, B or Y channels (found {sorted(channels)})")
    img = img.astype(np.float32)
    if img.ndim != 3 or img.shape[0] < 1 or img.shape[1] < 1:
        raise ValueError(f"image {path}: unexpected pixel array shape {img.shape}")
    return img


def write_exr(path, image) -> None:
    """Write (H, W, 3) linear RGB as a float32 ZIP-compressed scanline OpenEXR file (atomic)."""
    import OpenEXR

    img = _as_rgb(image, path)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    channels = {c: np.ascontiguousarray(img[..., k]) for k, c in enumerate("RGB")}

    def _write(tmp):
        with OpenEXR.File(header, channels) as exr:
            exr.write(tmp)

    _atomic_write(path, _write, suffix=".exr")


# ---- Radiance RGBE ---------------------------------------------------------------------------
def read_hdr(path) -> np.ndarray:
    """Read a Radiance RGBE (.hdr) image as (H, W, 3) float32 linear radiance."""
    path = _check_exists(path)
    with open(path, "rb") as fh:
        data = fh.read()
    try:
        return _decode_hdr(data)
    except ValueError as exc:
        raise ValueError(f"image {path}: not a readable Radiance .hdr file ({exc})") from exc


def _decode_hdr(data: bytes) -> np.ndarray:
    if not (data.startswith(b"#?RADIANCE") or data.startswith(b"#?RGBE")):
        raise ValueError("missing '#?RADIANCE' signature")
    pos = 0
    exposure = 1.0
    fmt = None
    while True:  # header lines up to an empty line
        end = data.find(b"\n", pos)
        if end < 0:
            raise ValueError("header is not terminated by an empty line")
        line = data[pos:end].strip()
        pos = end + 1
        if not line:
            break
        if line.startswith(b"FORMAT="):
            fmt = line[7:].decode("ascii", "replace")
        elif line.startswith(b"EXPOSURE="):
            exposure *= float(line[9:])
    if fmt is not None and fmt != "32-bit_rle_rgbe":
        raise ValueError(f"unsupported FORMAT={fmt} (only 32-bit_rle_rgbe)")
    end = data.find(b"\n", pos)
    if end < 0:
        raise ValueError("missing resolution line")
    line = data[pos:end]
    pos = end + 1
    height, width, flip_rows, flip_columns = _resolution(line)
    buf = np.frombuffer(data, dtype=np.uint8, offset=pos)
    if buf.shape[0] < 4 * height:  # every scanline takes at least one pixel's 4 bytes
        raise ValueError(f"truncated pixel data: {buf.shape[0]} bytes for {height} scanlines")
    rgbe = np.empty((height, width, 4), dtype=np.uint8)
    cursor = 0
    for row in range(height):
        cursor = _decode_scanline(buf, cursor, rgbe[row], width, row)
    if flip_rows:
        rgbe = rgbe[::-1]
    if flip_columns:
        rgbe = rgbe[:, ::-1]
    mantissa = rgbe[..., :3].astype(np.float64)
    exponent = rgbe[..., 3].astype(np.int64)
    scale = np.where(exponent > 0, np.ldexp(1.0, exponent - _RGBE_EXPONENT_BIAS), 0.0)
    img = (mantissa + 0.5) * scale[..., None] / exposure
    return img.astype(np.float32)


def _resolution(line: bytes) -> tuple[int, int, bool, bool]:
    """``(height, width, flip_rows, flip_columns)`` of a resolution line ``[-+]Y H [-+]X W``
    (scanlines along X; ``+Y`` stores the bottom row first, ``-X`` each row right to left).

    Raises:
        ValueError: quoting the line (a rotated image, with Y along scanlines, is not read), or
            naming a size above :data:`warpshade._limits.MAX_IMAGE_PIXELS`.
    """
    from .._limits import MAX_IMAGE_PIXELS

    res = line.split()
    if len(res) != 4 or res[0] not in (b"-Y", b"+Y") or res[2] not in (b"+X", b"-X"):
        raise ValueError(f"unsupported resolution line {line[:80]!r} (only '-Y H +X W' and its flips "
                         "'+Y H +X W', '-Y H -X W', '+Y H -X W')")
    try:
        height, width = int(res[1]), int(res[3])
    except ValueError:
        raise ValueError(f"resolution line {line[:80]!r}: the sizes are not integers") from None
    if height < 1 or width < 1:
        raise ValueError(f"bad image size {width}x{height}")
    if height * width > MAX_IMAGE_PIXELS:
        raise ValueError(f"image size {width}x{height} ({height * width:,} pixels) exceeds the limit of "
                         f"{MAX_IMAGE_PIXELS:,} pixels an image may have")
    return height, width, res[0] == b"+Y", res[2] == b"-X"


def _decode_scanline(buf: np.ndarray, cursor: int, out: np.ndarray, width: int, row: int) -> int:
    """Decode one scanline into ``out`` (width, 4) uint8; returns the new read position."""
    if cursor + 4 > buf.shape[0]:
        raise ValueError(f"truncated pixel data at scanline {row}")
    head = buf[cursor : cursor + 4]
    if 8 <= width <= 0x7FFF and head[0] == 2 and head[1] == 2 and not head[2] & 0x80:
        if (int(head[2]) << 8 | int(head[3])) != width:
            raise ValueError(f"scanline {row}: run-length header width does not match the image width")
        cursor += 4
        for channel in range(4):
            x = 0
            while x < width:
                if cursor >= buf.shape[0]:
                    raise ValueError(f"truncated run-length data at scanline {row}")
                count = int(buf[cursor])
                cursor += 1
                if count > 128:  # a run of one repeated byte
                    count -= 128
                    if count > width - x or cursor >= buf.shape[0]:
                        raise ValueError(f"scanline {row}: run overruns the scanline")
                    out[x : x + count, channel] = buf[cursor]
                    cursor += 1
                else:  # literal bytes
                    if count == 0 or count > width - x or cursor + count > buf.shape[0]:
                        raise ValueError(f"scanline {row}: bad literal packet")
                    out[x : x + count, channel] = buf[cursor : cursor + count]
                    cursor += count
                x += count
        return cursor
    # Flat pixels, possibly with old-style run-length repeats (1 1 1 n).
    x = 0
    shift = 0
    while x < width:
        if cursor + 4 > buf.shape[0]:
            raise ValueError(f"truncated pixel data at scanline {row}")
        px = buf[cursor : cursor + 4]
        cursor += 4
        if px[0] == 1 and px[1] == 1 and px[2] == 1:
            if x == 0:
                raise ValueError(f"scanline {row}: repeat code with no previous pixel")
            count = int(px[3]) << shift
            if count > width - x:
                raise ValueError(f"scanline {row}: repeat overruns the scanline")
            out[x : x + count] = out[x - 1]
            x += count
            shift += 8
        else:
            out[x] = px
            x += 1
            shift = 0
    return cursor


def _float_to_rgbe(img: np.ndarray) -> np.ndarray:
    img = np.maximum(img.astype(np.float64), 0.0)
    peak = img.max(axis=-1)
    mant, expo = np.frexp(peak)  # peak = mant * 2**expo, mant in [0.5, 1)
    ok = peak > 1e-32
    scale = np.where(ok, np.ldexp(1.0, 8 - expo), 0.0)  # 256 / 2**expo
    rgbe = np.zeros(img.shape[:-1] + (4,), dtype=np.uint8)
    rgbe[..., :3] = np.clip(np.floor(img * scale[..., None]), 0, 255).astype(np.uint8)
    rgbe[..., 3] = np.where(ok, np.clip(expo + 128, 0, 255), 0).astype(np.uint8)
    return rgbe


def _encode_channel(values: np.ndarray) -> bytes:
    """Radiance new-style run-length encoding of one channel of one scanline."""
    out = bytearray()
    n = values.shape[0]
    # Start index and length of every maximal run of equal bytes.
    change = np.flatnonzero(np.diff(values.astype(np.int16)) != 0) + 1
    starts = np.concatenate([[0], change])
    lengths = np.diff(np.concatenate([starts, [n]]))
    literal_start = 0
    for start, length in zip(starts.tolist(), lengths.tolist()):
        if length < 4:
            continue
        for a in range(literal_start, start, 128):
            b = min(a + 128, start)
            out.append(b - a)
            out += values[a:b].tobytes()
        remaining = length
        while remaining > 0:
            chunk = min(remaining, 127)
            if chunk < 4 and remaining != length:  # a short tail goes out as a literal
                break
            out.append(128 + chunk)
            out.append(int(values[start]))
            remaining -= chunk
            start += chunk
        literal_start = start
    for a in range(literal_start, n, 128):
        b = min(a + 128, n)
        out.append(b - a)
        out += values[a:b].tobytes()
    return bytes(out)


def write_hdr(path, image) -> None:
    """Write (H, W, 3) linear RGB as a run-length encoded Radiance .hdr file (atomic).

    Negative values are clamped to zero (RGBE cannot store them); NaN/inf are rejected.
    """
    img = _as_rgb(image, path)
    height, width = img.shape[:2]
    rgbe = _float_to_rgbe(img)
    body = bytearray(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n")
    body += f"-Y {height} +X {width}\n".encode("ascii")
    rle = 8 <= width <= 0x7FFF
    for row in range(height):
        if rle:
            body += bytes([2, 2, width >> 8, width & 0xFF])
            for channel in range(4):
                body += _encode_channel(rgbe[row, :, channel])
        else:
            body += rgbe[row].tobytes()

    def _write(tmp):
        with open(tmp, "wb") as fh:
            fh.write(bytes(body))

    _atomic_write(path, _write, suffix=".hdr")


# ---- helpers ---------------------------------------------------------------------------------
def _as_rgb(image, path) -> np.ndarray:
    img = np.asarray(image, dtype=np.float32)
    if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] < 1 or img.shape[1] < 1:
        raise ValueError(f"image {path}: expected shape (H, W, 3), got {img.shape}")
    if not np.all(np.isfinite(img)):
        raise ValueError(f"image {path}: contains NaN or infinite values")
    return img


def _atomic_write(path, write, suffix: str) -> None:
    with atomic_path(path, suffix=suffix) as tmp:
        write(str(tmp))
