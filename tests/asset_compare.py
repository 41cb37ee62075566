"""Compare a generated asset file with the bundled one by what is reproducible across machines.

The scene generator (``python -m warpshade.usd_assets.generator``) is deterministic on one machine,
but its floating-point results are not bit-identical across machines: numpy's SIMD transcendental
functions (exp, tan, log1p, arctan, ...) and OpenBLAS kernels differ by an ulp or so between CPUs,
so a file's bytes may differ while its values agree to ~1e-13. :func:`asset_differences` compares
two files by kind, exactly where the content is discrete and within a stated tolerance where it is
floating point:

* ``.usda`` / ``.usdc``: both opened as Sdf layers; every spec (the pseudo-root with the layer
  metadata -- upAxis, metersPerUnit, time codes, defaultPrim, sublayers --, prims, properties,
  relationship targets) must exist in both, with the same fields, the same prim-children and
  property order; strings, tokens, asset paths, bools, ints, list ops and integer arrays
  (topology, joint indices) exactly equal; floating values (scalars, Gf vectors / matrices, Vt
  float / double / half arrays, each value of ``timeSamples``, whose time codes must be equal)
  within ``RTOL`` (``HALF_RTOL`` for half) of the field's largest magnitude, plus ``ATOL``.
* ``.hdr`` (Radiance RGBE): the header exactly; the decoded pixels (same shape) within
  ``HDR_MANTISSA_STEPS`` mantissa steps of the pixel's largest channel.
* ``.binary`` (MERL tabulated BRDF): the dimensions and the invalid cells exactly, the values within
  ``MERL_RTOL`` of each value.
* ``.svbrdf`` / ``.anisobrdf`` (float32 tables): sizes and headers exactly, values within ``RTOL``
  of the table's largest magnitude; ``.png`` (8/16-bit textures): within ``PNG_LEVELS`` levels.
* anything else: bytes.

Measured on two hosts (numpy dispatching AVX-512 vs SSE4.2 code paths, OpenBLAS SkylakeX vs
Sandybridge kernels), the differences are: USD files and ``sky.hdr`` identical (the 1e-4 / 1e-6
rounding of written coordinates absorbs them), ``measured_coating.binary`` values within 1.0e-13
of each value.
"""

from __future__ import annotations

import os

import numpy as np

#: Floating values in USD files (and float32 tables): largest allowed |bundled - generated| as a
#: fraction of the field's largest magnitude. Most are float32 as written by USD: an ulp-level
#: float64 difference upstream can flip the last float32 bit, at most 2**-23 ~ 1.2e-7 of the value,
#: so 1e-6 leaves a margin of ~8; any real change of a scene -- a point moved by 1e-4 of the scene's
#: size, a quaternion component by 1e-4 -- is >= 1e-4 of the field's magnitude, 100 times above it.
#: (The generator rounds coordinates to 1e-4 before writing them, and a rounding flipped by an ulp
#: would exceed RTOL; measured, every rounded value other than exact ties of plain arithmetic on
#: constants lies more than a million ulps from a rounding boundary.)
RTOL = 1e-6
#: Half-precision values (Vt half arrays): one half ulp at the field's largest magnitude, 2**-10.
HALF_RTOL = 2.0**-10
#: Absolute floor added to every floating tolerance (scene units: metres, radians, ...), so that
#: all-zero fields compare with a finite tolerance; a picometre, far below float32 resolution.
ATOL = 1e-12
#: Radiance RGBE pixels: allowed |difference| of each channel, in mantissa steps of the pixel's
#: largest channel (2**(e - 8) for a largest channel in [2**(e-1), 2**e)). A float-level change
#: of the radiance can move a value across a quantisation boundary: one step, or a renormalised
#: exponent (also within one step of the larger exponent). One step is 0.4-0.8 % of the pixel.
HDR_MANTISSA_STEPS = 1
#: MERL tables (float64): allowed |difference| as a fraction of each value (the values span ~300
#: decades, exp of arguments down to ~-650, so a tolerance relative to the table's maximum would
#: leave the small values unchecked). Observed across hosts: 1.0e-13 (exp's ulp error amplified by
#: its argument); a real change of the model or the grid moves values by far more than 1e-9.
MERL_RTOL = 1e-9
#: Absolute floor for MERL values (a value underflowing to 0 on one host, a denormal on another).
MERL_ATOL = 1e-300
#: 8- or 16-bit textures: allowed difference in integer levels (a value rounded to a level can
#: round to the neighbouring one when it sits at the rounding boundary).
PNG_LEVELS = 1

#: How many differing elements a message spells out before it only counts them.
_SHOW = 3


def asset_differences(bundled_path, generated_path) -> list[str]:
    """The differences between a bundled asset file and the generator's output (empty when they
    agree within this module's tolerances); each message names the file and where it differs."""
    bundled_path, generated_path = os.fspath(bundled_path), os.fspath(generated_path)
    name = os.path.basename(bundled_path)
    for path, which in ((bundled_path, "bundled"), (generated_path, "generated")):
        if not os.path.isfile(path):
            return [f"{name}: the {which} file {path} does not exist"]
    ext = os.path.splitext(name)[1].lower()
    compare = _BY_EXTENSION.get(ext, _bytes_differences)
    return compare(name, bundled_path, generated_path)


# ---- USD ----------------------------------------------------------------------------------------
def usd_layer_differences(name: str, bundled, generated) -> list[str]:
    """Differences between two Sdf layers (see the module docstring); ``name`` prefixes messages."""
    from pxr import Sdf

    specs_a, specs_b = _spec_paths(bundled), _spec_paths(generated)
    out = [f"{name}: spec {p} is missing from the generated file" for p in sorted(specs_a - specs_b, key=str)]
    out += [f"{name}: spec {p} is in the generated file only" for p in sorted(specs_b - specs_a, key=str)]
    for path in sorted(specs_a & specs_b, key=str):
        where = f"{name}: {'<layer>' if path == Sdf.Path.absoluteRootPath else path}"
        fields_a, fields_b = _fields(bundled, path), _fields(generated, path)
        if fields_a.keys() != fields_b.keys():
            only_a, only_b = sorted(fields_a.keys() - fields_b.keys()), sorted(fields_b.keys() - fields_a.keys())
            out.append(f"{where}: fields differ (bundled only: {only_a}, generated only: {only_b})")
        for field in sorted(fields_a.keys() & fields_b.keys()):
            out += _field_differences(f"{where} {field}", fields_a[field], fields_b[field])
    return out


def _usd_differences(name: str, bundled_path: str, generated_path: str) -> list[str]:
    from pxr import Sdf

    layers = []
    for path in (bundled_path, generated_path):
        try:  # anonymous: the layer registry never hands back a stale copy of a rewritten file
            layer = Sdf.Layer.OpenAsAnonymous(path)
        except Exception as exc:  # pxr raises Tf.ErrorException
            return [f"{name}: {path} cannot be opened as a USD layer ({exc})"]
        if layer is None:
            return [f"{name}: {path} cannot be opened as a USD layer"]
        layers.append(layer)
    return usd_layer_differences(name, *layers)


def _spec_paths(layer) -> set:
    paths = set()
    layer.Traverse(layer.pseudoRoot.path, paths.add)
    return paths


class _Unreadable:
    """A field value Python cannot receive: never equal, so the comparison says so."""

    def __init__(self, field, exc):
        self.text = f"<field {field} cannot be read from Python: {exc}; teach tests/asset_compare.py to compare it>"

    def __eq__(self, other):
        return False

    def __repr__(self):
        return self.text


def _fields(layer, path) -> dict:
    """Field name -> value of the spec at ``path``, plus its children order (primChildren,
    properties). Relationship-target and connection paths are specs without fields."""
    spec = layer.GetObjectAtPath(path)
    if spec is None:
        return {}
    out = {}
    for field in spec.ListInfoKeys():
        if field == "subLayerOffsets":  # a vector of SdfLayerOffset, which Python cannot receive
            out[field] = [(o.offset, o.scale) for o in layer.subLayerOffsets]
            continue
        try:
            out[field] = spec.GetInfo(field)
        except Exception as exc:  # no to-Python converter for the value's C++ type
            out[field] = _Unreadable(field, exc)
    if hasattr(spec, "nameChildren"):
        out["primChildren"] = list(spec.nameChildren.keys())
    if hasattr(spec, "properties"):
        out["properties"] = list(spec.properties.keys())
    return out


def _floats(value):
    """The value as a float64 array and its relative tolerance when it is floating point, else None."""
    if isinstance(value, float):  # Python's float is also USD's float and double scalars
        return np.asarray(value, np.float64), RTOL
    if type(value).__module__ not in ("pxr.Gf", "pxr.Vt"):  # bool, int, str, Sdf values, ...
        return None
    if type(value).__module__ == "pxr.Gf" and type(value).__name__.startswith("Quat"):  # no array conversion
        return np.array([value.GetReal(), *value.GetImaginary()], np.float64), RTOL
    try:
        array = np.asarray(value)
    except Exception:
        return None
    if array.dtype.kind != "f":
        return None
    return array.astype(np.float64), (HALF_RTOL if array.dtype == np.float16 else RTOL)


def _field_differences(where: str, a, b) -> list[str]:
    if type(a) is not type(b):
        return [f"{where}: bundled {type(a).__name__}, generated {type(b).__name__}"]
    if isinstance(a, dict):
        keys_a, keys_b = sorted(a, key=_key), sorted(b, key=_key)
        if keys_a != keys_b:
            only_a = [k for k in keys_a if k not in b]
            only_b = [k for k in keys_b if k not in a]
            return [f"{where}: keys differ (bundled only: {_brief(only_a)}, generated only: {_brief(only_b)})"]
        numeric = [_floats(a[k]) for k in keys_a] + [_floats(b[k]) for k in keys_a]
        scale = None
        if keys_a and all(n is not None for n in numeric):  # one scale over all samples of the field
            scale = max(float(np.abs(n[0]).max(initial=0.0)) for n in numeric)
        out = []
        for k in keys_a:
            out += _value_differences(f"{where}[{k}]", a[k], b[k], scale)
        return out
    return _value_differences(where, a, b, None)


def _key(k):
    return (0, k, "") if isinstance(k, (int, float)) else (1, 0.0, str(k))


def _brief(items) -> str:
    return repr(items) if len(items) <= 8 else f"{items[:8]!r}... ({len(items)} in all)"


def _value_differences(where: str, a, b, scale) -> list[str]:
    if type(a) is not type(b):
        return [f"{where}: bundled {type(a).__name__}, generated {type(b).__name__}"]
    if isinstance(a, dict):
        return _field_differences(where, a, b)
    fa, fb = _floats(a), _floats(b)
    if fa is not None and fb is not None:
        return _float_differences(where, fa[0], fb[0], fa[1], scale)
    if type(a).__module__ == "pxr.Vt":
        return _exact_array_differences(where, a, b)
    if a == b:
        return []
    return [f"{where}: bundled {_short(a)}, generated {_short(b)}"]


def _item(value):
    return value.item() if isinstance(value, np.generic) else value


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 120 else text[:117] + "..."


def _float_differences(where: str, a: np.ndarray, b: np.ndarray, rtol: float, scale=None) -> list[str]:
    if a.shape != b.shape:
        return [f"{where}: shape bundled {a.shape}, generated {b.shape}"]
    if a.size == 0:
        return []
    nan_a, nan_b = np.isnan(a), np.isnan(b)
    if np.any(nan_a != nan_b):
        k = np.unravel_index(int(np.argmax(nan_a != nan_b)), a.shape)
        return [f"{where}: NaN in one file only, at element {tuple(int(i) for i in k)}"]
    a, b = np.where(nan_a, 0.0, a), np.where(nan_b, 0.0, b)
    if scale is None:
        scale = max(float(np.abs(a).max()), float(np.abs(b).max()))
    with np.errstate(invalid="ignore"):  # inf - inf
        diff = np.where(a == b, 0.0, np.abs(a - b))
    tol = rtol * scale + ATOL
    bad = ~(diff <= tol)
    if not bad.any():
        return []
    k = np.unravel_index(int(np.argmax(np.where(bad, diff, -1.0))), a.shape)
    at = f" at element {tuple(int(i) for i in k)}" if a.ndim else ""
    return [f"{where}: max |difference| {diff[k]:.3g}{at} (bundled {a[k]:.9g}, generated {b[k]:.9g}), "
            f"{diff[k] / max(scale, ATOL):.3g} of the largest magnitude {scale:.4g} (tolerance {rtol:g} of it + {ATOL:g}); "
            f"{int(bad.sum())} of {a.size} values differ"]


def _exact_array_differences(where: str, a, b) -> list[str]:
    try:
        xa, xb = np.asarray(a), np.asarray(b)
    except Exception:
        xa, xb = np.asarray(list(a), dtype=object), np.asarray(list(b), dtype=object)
    if xa.shape != xb.shape:
        return [f"{where}: shape bundled {xa.shape}, generated {xb.shape}"]
    bad = xa != xb
    if not np.any(bad):
        return []
    idx = [tuple(int(i) for i in k) for k in np.argwhere(bad)[:_SHOW]]
    shown = ", ".join(f"element {k}: bundled {_short(_item(xa[k]))}, generated {_short(_item(xb[k]))}" for k in idx)
    return [f"{where}: {int(np.count_nonzero(bad))} of {xa.size} values differ ({shown})"]


# ---- Radiance RGBE ------------------------------------------------------------------------------
def _hdr_header(data: bytes) -> bytes:
    """The header up to and including the resolution line."""
    end = data.find(b"\n\n")
    if end < 0:
        return data[:256]
    end = data.find(b"\n", end + 2)
    return data[: end + 1 if end >= 0 else len(data)]


def hdr_step(image: np.ndarray) -> np.ndarray:
    """One RGBE mantissa step of each pixel's largest channel, (H, W) (0 for black pixels)."""
    peak = np.asarray(image, np.float64).max(axis=-1)
    return np.where(peak > 0.0, np.ldexp(1.0, np.frexp(peak)[1] - 8), 0.0)


def _hdr_differences(name: str, bundled_path: str, generated_path: str) -> list[str]:
    from warpshade.io import read_hdr

    with open(bundled_path, "rb") as fa, open(generated_path, "rb") as fb:
        head_a, head_b = _hdr_header(fa.read()), _hdr_header(fb.read())
    if head_a != head_b:
        return [f"{name}: header bundled {head_a!r}, generated {head_b!r}"]
    try:
        a, b = (read_hdr(p).astype(np.float64) for p in (bundled_path, generated_path))
    except ValueError as exc:
        return [f"{name}: {exc}"]
    if a.shape != b.shape:
        return [f"{name}: image shape bundled {a.shape}, generated {b.shape}"]
    step = np.maximum(hdr_step(a), hdr_step(b))[..., None]
    diff = np.abs(a - b)
    bad = diff > HDR_MANTISSA_STEPS * step
    if not bad.any():
        return []
    steps = np.where(bad, diff / np.where(step > 0.0, step, 1.0), 0.0)
    r, c, ch = (int(i) for i in np.unravel_index(int(np.argmax(np.where(bad, diff + steps, -1.0))), a.shape))
    return [f"{name}: pixel (row {r}, column {c}) channel {'RGB'[ch]}: bundled {a[r, c, ch]:.6g}, generated "
            f"{b[r, c, ch]:.6g}, {diff[r, c, ch] / max(step[r, c, 0], 1e-300):.3g} mantissa steps of the pixel's largest "
            f"channel ({diff[r, c, ch] / max(a[r, c].max(), b[r, c].max()):.3g} of it; tolerance {HDR_MANTISSA_STEPS} step); "
            f"{int(bad.any(axis=-1).sum())} of {a.shape[0] * a.shape[1]} pixels differ"]


# ---- MERL tabulated BRDF ------------------------------------------------------------------------
def _merl_differences(name: str, bundled_path: str, generated_path: str) -> list[str]:
    from warpshade.scene._tabulated import read_merl

    try:
        a, b = (read_merl(p).table for p in (bundled_path, generated_path))
    except ValueError as exc:
        return [f"{name}: {exc}"]
    if a.shape != b.shape:
        return [f"{name}: table dims (channels, n_theta_h, n_theta_d, n_phi_d) bundled {a.shape}, generated {b.shape}"]
    out = []
    invalid_a, invalid_b = a < 0.0, b < 0.0
    if np.any(invalid_a != invalid_b) or np.any(a[invalid_a] != b[invalid_a]):
        odd = (invalid_a != invalid_b) | (invalid_a & (a != b))
        out.append(f"{name}: the invalid cells differ ({int(odd.sum())} cells, first at (channel, theta_h, theta_d, phi_d) "
                   f"= {tuple(int(i) for i in np.argwhere(odd)[0])})")
    valid = ~invalid_a & ~invalid_b
    diff = np.where(valid, np.abs(a - b), 0.0)
    tol = MERL_RTOL * np.maximum(np.abs(a), np.abs(b)) + MERL_ATOL
    bad = diff > tol
    if bad.any():
        rel = np.where(bad, diff / np.maximum(np.maximum(np.abs(a), np.abs(b)), MERL_ATOL), -1.0)
        k = np.unravel_index(int(np.argmax(rel)), a.shape)
        out.append(f"{name}: value at (channel, theta_h, theta_d, phi_d) = {tuple(int(i) for i in k)}: bundled {a[k]:.17g}, "
                   f"generated {b[k]:.17g}, relative difference {rel[k]:.3g} (tolerance {MERL_RTOL:g}); "
                   f"{int(bad.sum())} of {a.size} values differ")
    return out


# ---- other tables and textures -----------------------------------------------------------------
def _svbrdf_differences(name: str, bundled_path: str, generated_path: str) -> list[str]:
    from warpshade.scene._svbrdf import read_svbrdf

    try:
        a, b = read_svbrdf(bundled_path), read_svbrdf(generated_path)
    except ValueError as exc:
        return [f"{name}: {exc}"]
    out = _float_differences(f"{name}: eta", np.asarray(a.eta), np.asarray(b.eta), RTOL)
    out += _float_differences(f"{name}: ndf", a.ndf, b.ndf, RTOL)
    return out + _float_differences(f"{name}: shadow", a.shadow, b.shadow, RTOL)


def _anisobrdf_differences(name: str, bundled_path: str, generated_path: str) -> list[str]:
    from warpshade.scene._tabulated_aniso import read_anisotropic_table

    try:
        a, b = (read_anisotropic_table(p).table for p in (bundled_path, generated_path))
    except ValueError as exc:
        return [f"{name}: {exc}"]
    if a.shape == b.shape and np.any((a < 0.0) != (b < 0.0)):
        return [f"{name}: the invalid cells (negative values) differ"]
    return _float_differences(f"{name}: table (channel, theta_h, phi_h, theta_d, phi_d)", a, b, RTOL)


def _png_differences(name: str, bundled_path: str, generated_path: str) -> list[str]:
    from warpshade.io import read_texture_file

    try:
        (a, eight_a), (b, eight_b) = read_texture_file(bundled_path), read_texture_file(generated_path)
    except ValueError as exc:
        return [f"{name}: {exc}"]
    if (a.shape, eight_a) != (b.shape, eight_b):
        return [f"{name}: image (shape, 8-bit) bundled {(a.shape, eight_a)}, generated {(b.shape, eight_b)}"]
    levels = 255.0 if eight_a else 65535.0
    diff = np.rint(np.abs(a.astype(np.float64) - b.astype(np.float64)) * levels)
    bad = diff > PNG_LEVELS
    if not bad.any():
        return []
    r, c, ch = (int(i) for i in np.unravel_index(int(np.argmax(diff)), diff.shape))
    return [f"{name}: pixel (row {r}, column {c}) channel {ch} differs by {int(diff[r, c, ch])} levels "
            f"(tolerance {PNG_LEVELS}); {int(bad.any(axis=-1).sum())} pixels differ"]


def _bytes_differences(name: str, bundled_path: str, generated_path: str) -> list[str]:
    with open(bundled_path, "rb") as fa, open(generated_path, "rb") as fb:
        a, b = fa.read(), fb.read()
    if a == b:
        return []
    first = next((i for i, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b)))
    return [f"{name}: bytes differ from offset {first} (sizes: bundled {len(a)}, generated {len(b)})"]


_BY_EXTENSION = {
    ".usda": _usd_differences,
    ".usdc": _usd_differences,
    ".usd": _usd_differences,
    ".hdr": _hdr_differences,
    ".binary": _merl_differences,
    ".svbrdf": _svbrdf_differences,
    ".anisobrdf": _anisobrdf_differences,
    ".png": _png_differences,
}
