"""Tabulated (measured) isotropic BRDFs in the MERL binary layout (float64 mirrors).

Conventions as in :mod:`warpshade.scene._materials`: local shading frame with +z the normal,
``evaluate(view, light)`` returns ``b(v, s)`` in 1/sr without the cosine, 0 below the horizon.

Parameterisation (Rusinkiewicz 1998 half/difference angles, as used by the MERL database of
Matusik et al. 2003)::

    h = normalize(v + s),  theta_h = acos(h_z),  phi_h = atan2(h_y, h_x)
    d = R_y(-theta_h) R_z(-phi_h) s                 (the light in the half-vector frame)
    theta_d = acos(d_z),  phi_d = atan2(d_y, d_x)

An isotropic BRDF depends on (theta_h, theta_d, phi_d) only. Swapping v and s maps ``d`` to
``(-d_x, -d_y, d_z)``, i.e. phi_d to phi_d + pi, so by reciprocity phi_d is folded into [0, pi)
(``phi_d += pi`` when negative). The inverse (:func:`half_diff_directions`): d from
(theta_d, phi_d), ``s = R_z(phi_h) R_y(theta_h) d``, ``h = (sin theta_h cos phi_h,
sin theta_h sin phi_h, cos theta_h)`` and ``v = 2 (h . s) h - s``.

File layout (``.binary``, little-endian)::

    int32   n_theta_h, n_theta_d, n_phi_d          (standard: 90, 90, 180)
    float64 red[n_theta_h][n_theta_d][n_phi_d]      (phi_d fastest)
    float64 green[...], blue[...]                   (same shape)

A stored value times its channel scale (:data:`MERL_SCALES`: 1/1500, 1.15/1500, 1.66/1500) is
the BRDF value; negative stored values mark unmeasured (invalid) cells. Cells, as in the MERL
reference code (``BRDFRead.cpp``): theta_h cell ``floor(sqrt(theta_h / (pi/2)) n_theta_h)``
(finer near the specular peak), theta_d cell ``floor(theta_d / (pi/2) n_theta_d)``, phi_d cell
``floor(phi_d / pi n_phi_d)`` over the folded [0, pi) (the reference's 360 / 2 = 180 entries),
each clamped to the table. Cell centres (:func:`merl_cell_centres`) are at
``((i + 0.5) / n)^2 pi/2``, ``(j + 0.5) / n pi/2`` and ``(k + 0.5) / n pi``.

:class:`TabulatedBRDF` holds the (3, n_theta_h, n_theta_d, n_phi_d) table of BRDF values and
looks it up "nearest" (the reference behaviour) or "linear" (trilinear in the cell-index space:
clamped in theta_h and theta_d, periodic in phi_d, whose period is pi; invalid cells are left out
of the blend and the remaining weights renormalised). Invalid cells read as 0 under "nearest".
:func:`read_merl` / :func:`write_merl` read and write the files; :func:`tabulate` samples any
:class:`~warpshade.scene._materials.BRDF` at the cell centres.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._fileio import atomic_path
from ._materials import BRDF, _unit

__all__ = [
    "LUMINANCE_WEIGHTS",
    "MERL_DIMS",
    "MERL_HEADER_BYTES",
    "MERL_INVALID",
    "MERL_SCALES",
    "MAX_DIM",
    "TabulatedBRDF",
    "half_diff_angles",
    "half_diff_directions",
    "merl_cell_centres",
    "merl_indices",
    "read_merl",
    "tabulate",
    "write_merl",
]

MERL_DIMS = (90, 90, 180)
"""(n_theta_h, n_theta_d, n_phi_d) of the database's files."""
MERL_SCALES = (1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0)
"""BRDF value = stored value * scale, per channel (red, green, blue)."""
MERL_INVALID = -1.0
"""Stored marker :func:`write_merl` puts in cells whose centre has a direction below the horizon."""
MERL_HEADER_BYTES = 12
MAX_DIM = 4096
"""Largest table size along one axis that :func:`read_merl` accepts."""
MAX_VALUE = 1e10
"""Largest BRDF value (1/sr, after the scales) :func:`read_merl` accepts: far above measured
materials (mirror-like MERL entries stay below 1e5) and far below what float32 shading overflows
on (the SH projections sum values times quadrature weights and lighting)."""
LUMINANCE_WEIGHTS = (0.2126, 0.7152, 0.0722)
"""Rec. 709 luminance of linear RGB."""

_CHANNELS = {"rgb": "rgb", "luminance": None, "r": 0, "g": 1, "b": 2, 0: 0, 1: 1, 2: 2}
_CHANNEL_NAMES = {"rgb": "rgb", None: "luminance", 0: "r", 1: "g", 2: "b"}
_INTERPOLATIONS = ("nearest", "linear")


# ---- the half/difference parameterisation -----------------------------------------------------


def half_diff_angles(view, light):
    """Directions -> (theta_h, phi_h, theta_d, phi_d), each of the broadcast shape, float64.

    phi_h and phi_d are in (-pi, pi] (phi_d not folded). ``view`` and ``light`` are normalised;
    where ``v + s`` vanishes the half vector is taken as +z.
    """
    v = _unit(view, "half_diff_angles: view")
    s = _unit(light, "half_diff_angles: light")
    return _half_diff(*np.broadcast_arrays(v, s))


def _half_diff(v, s):
    """:func:`half_diff_angles` of unit, broadcast directions."""
    h = v + s
    n = np.linalg.norm(h, axis=-1, keepdims=True)
    h = np.where(n > 1e-12, h / np.where(n > 1e-12, n, 1.0), np.array([0.0, 0.0, 1.0]))
    # atan2 forms of the acos's: accurate near 0 as well
    theta_h = np.arctan2(np.hypot(h[..., 0], h[..., 1]), h[..., 2])
    phi_h = np.arctan2(h[..., 1], h[..., 0])
    cp, sp = np.cos(phi_h), np.sin(phi_h)
    tx = s[..., 0] * cp + s[..., 1] * sp  # R_z(-phi_h) s
    ty = -s[..., 0] * sp + s[..., 1] * cp
    tz = s[..., 2]
    ct, st = np.cos(theta_h), np.sin(theta_h)
    dx = tx * ct - tz * st  # R_y(-theta_h) t
    dz = tx * st + tz * ct
    theta_d = np.arctan2(np.hypot(dx, ty), dz)
    phi_d = np.arctan2(ty, dx)
    return theta_h, phi_h, theta_d, phi_d


def half_diff_directions(theta_h, theta_d, phi_d, phi_h=0.0):
    """(theta_h, theta_d, phi_d[, phi_h]) -> (view, light), each (..., 3): the inverse of
    :func:`half_diff_angles`."""
    th, td, pd, ph = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (theta_h, theta_d, phi_d, phi_h)))
    d = np.stack([np.sin(td) * np.cos(pd), np.sin(td) * np.sin(pd), np.cos(td)], axis=-1)
    ct, st = np.cos(th), np.sin(th)
    tx = d[..., 0] * ct + d[..., 2] * st  # R_y(theta_h) d
    tz = -d[..., 0] * st + d[..., 2] * ct
    cp, sp = np.cos(ph), np.sin(ph)
    s = np.stack([tx * cp - d[..., 1] * sp, tx * sp + d[..., 1] * cp, tz], axis=-1)  # R_z(phi_h)
    h = np.stack([st * cp, st * sp, ct], axis=-1)
    v = 2.0 * np.sum(h * s, axis=-1, keepdims=True) * h - s
    return v, s


def _fold_phi_d(phi_d):
    return np.where(phi_d < 0.0, phi_d + np.pi, phi_d)


def _check_dims(dims, what: str) -> tuple[int, int, int]:
    try:
        out = tuple(int(n) for n in dims)
    except (TypeError, ValueError):
        raise ValueError(f"{what}: dims must be three integers, got {dims!r}") from None
    if len(out) != 3 or any(not 1 <= n <= MAX_DIM for n in out):
        raise ValueError(f"{what}: dims (n_theta_h, n_theta_d, n_phi_d) must each be in 1..{MAX_DIM}, got {dims!r}")
    return out


def merl_indices(theta_h, theta_d, phi_d, dims=MERL_DIMS):
    """The MERL reference code's cell of each (theta_h, theta_d, phi_d): three int64 arrays.

    phi_d may be unfolded (it is folded into [0, pi) here)."""
    n_th, n_td, n_pd = _check_dims(dims, "merl_indices")
    th = np.maximum(np.asarray(theta_h, dtype=np.float64), 0.0)
    i = np.floor(np.sqrt(th / (np.pi / 2.0)) * n_th)
    j = np.floor(np.asarray(theta_d, dtype=np.float64) / (np.pi / 2.0) * n_td)
    k = np.floor(_fold_phi_d(np.asarray(phi_d, dtype=np.float64)) / np.pi * n_pd)
    return (np.clip(i, 0, n_th - 1).astype(np.int64), np.clip(j, 0, n_td - 1).astype(np.int64),
            np.clip(k, 0, n_pd - 1).astype(np.int64))


def merl_cell_centres(dims=MERL_DIMS):
    """Angles of the cell centres: (theta_h (n_th,), theta_d (n_td,), phi_d (n_pd,)), float64."""
    n_th, n_td, n_pd = _check_dims(dims, "merl_cell_centres")
    theta_h = ((np.arange(n_th) + 0.5) / n_th) ** 2 * (np.pi / 2.0)
    theta_d = (np.arange(n_td) + 0.5) / n_td * (np.pi / 2.0)
    phi_d = (np.arange(n_pd) + 0.5) / n_pd * np.pi
    return theta_h, theta_d, phi_d


def _linear_axis(u, n: int):
    """Clamped linear interpolation along one index axis: (i0, i1, t) with u at cell centres."""
    u = np.clip(u, 0.0, n - 1.0)
    i0 = np.minimum(np.floor(u), max(n - 2, 0)).astype(np.int64)
    i1 = np.minimum(i0 + 1, n - 1)
    return i0, i1, np.clip(u - i0, 0.0, 1.0)


def _periodic_axis(u, n: int):
    """Periodic linear interpolation along one index axis (period n cells)."""
    f = np.floor(u)
    t = u - f
    i0 = np.mod(f.astype(np.int64), n)
    return i0, np.mod(i0 + 1, n), t


# ---- the tabulated BRDF -----------------------------------------------------------------------


def _canonical_channel(channel):
    key = channel.lower() if isinstance(channel, str) else channel
    if isinstance(key, (bool, np.bool_)) or key not in _CHANNELS:
        raise ValueError(f"TabulatedBRDF: channel must be 'rgb', 'luminance', 'r', 'g', 'b', 0, 1 or 2, got {channel!r}")
    return _CHANNELS[key]


@dataclass(frozen=True, eq=False)
class TabulatedBRDF(BRDF):
    """An isotropic BRDF tabulated on the MERL cells (module docstring). Immutable: use
    ``dataclasses.replace(brdf, interpolation="linear")`` for a variant.

    Attributes:
        table: BRDF values (already times the channel scales), shape (3, n_theta_h, n_theta_d,
            n_phi_d), float64; negative entries are invalid (unmeasured) cells. Stored as a
            read-only copy.
        channel: the colour it shades: "rgb" (each channel its own BRDF: :meth:`color_channels`
            gives the three, and :meth:`evaluate` returns their luminance, the scalar shape),
            "luminance" (``LUMINANCE_WEIGHTS . rgb``, grey), or one channel, "r" / "g" / "b"
            (or 0 / 1 / 2; stored as the letter).
        interpolation: "nearest" (the MERL reference lookup) or "linear" (trilinear in the cell
            index space).
        source: the file it came from, or "<array>".

    :meth:`rgb` returns all three channels; :meth:`describe` identifies the content (a cache key).
    """

    table: np.ndarray = field(repr=False)
    channel: str = "rgb"
    interpolation: str = "nearest"
    source: str = "<array>"
    name = "tabulated"

    def __post_init__(self):
        table = np.array(self.table, dtype=np.float64, copy=True)
        if table.ndim != 4 or table.shape[0] != 3:
            raise ValueError("TabulatedBRDF: table must have shape (3, n_theta_h, n_theta_d, n_phi_d), "
                             f"got {table.shape}")
        _check_dims(table.shape[1:], "TabulatedBRDF")
        bad = ~np.isfinite(table)
        if bad.any():
            first = tuple(int(i) for i in np.unravel_index(int(np.argmax(bad)), table.shape))
            raise ValueError(f"TabulatedBRDF: table has {int(bad.sum())} non-finite entries (first at {first})")
        if self.interpolation not in _INTERPOLATIONS:
            raise ValueError(f"TabulatedBRDF: interpolation must be one of {_INTERPOLATIONS}, "
                             f"got {self.interpolation!r}")
        table.flags.writeable = False
        digest = hashlib.sha1(np.ascontiguousarray(table, dtype="<f8").tobytes()).hexdigest()[:16]
        object.__setattr__(self, "table", table)
        object.__setattr__(self, "channel", _CHANNEL_NAMES[_canonical_channel(self.channel)])
        object.__setattr__(self, "source", str(self.source))
        object.__setattr__(self, "_hash", digest)

    @classmethod
    def from_brdf(cls, brdf: BRDF, dims=MERL_DIMS, rgb=(1.0, 1.0, 1.0), channel="rgb",
                  interpolation="nearest") -> TabulatedBRDF:
        """Tabulate ``brdf`` in memory (:func:`tabulate`); invalid cells hold -1."""
        return cls(tabulate(brdf, dims, rgb), channel, interpolation, "<array>")

    @property
    def dims(self) -> tuple[int, int, int]:
        return tuple(int(n) for n in self.table.shape[1:])

    @property
    def content_hash(self) -> str:
        """First 16 hex digits of the SHA-1 of the table's little-endian float64 bytes."""
        return self._hash

    def describe(self) -> dict:
        return {"model": self.name, "source": self.source, "channel": self.channel,
                "interpolation": self.interpolation, "dims": list(self.dims), "table_sha1": self.content_hash}

    def color_channels(self) -> tuple | None:
        """The three single-channel BRDFs ("r", "g", "b") of a colour table (``channel = "rgb"``),
        which shaders that honour colour use one per channel; None for a grey one."""
        if self.channel != "rgb":
            return None
        return tuple(TabulatedBRDF(self.table, c, self.interpolation, self.source) for c in ("r", "g", "b"))

    def rgb(self, view, light) -> np.ndarray:
        """All three channels, (..., 3), float64; 0 below the horizon."""
        v = _unit(view, f"{self.name}: view")
        s = _unit(light, f"{self.name}: light")
        v, s = np.broadcast_arrays(v, s)
        above = (v[..., 2] > 0.0) & (s[..., 2] > 0.0)
        out = np.stack(self._lookup(v, s, (0, 1, 2)), axis=-1)
        return np.where(above[..., None], out, 0.0)

    def _eval(self, v, s):
        c = _CHANNELS[self.channel]
        if c is not None and c != "rgb":
            return self._lookup(v, s, (c,))[0]
        r, g, b = self._lookup(v, s, (0, 1, 2))
        wr, wg, wb = LUMINANCE_WEIGHTS
        return wr * r + wg * g + wb * b

    def _lookup(self, v, s, channels) -> list[np.ndarray]:
        """Per requested channel, the looked-up values (broadcast shape of v and s)."""
        theta_h, _, theta_d, phi_d = _half_diff(v, s)
        n_th, n_td, n_pd = self.dims
        flat_table = self.table.reshape(3, -1)
        if self.interpolation == "nearest":
            i, j, k = merl_indices(theta_h, theta_d, phi_d, self.dims)
            flat = (i * n_td + j) * n_pd + k
            return [np.maximum(flat_table[c].take(flat), 0.0) for c in channels]
        # continuous cell coordinates: integers at the cell centres
        ui = np.sqrt(np.maximum(theta_h, 0.0) / (np.pi / 2.0)) * n_th - 0.5
        uj = theta_d / (np.pi / 2.0) * n_td - 0.5
        uk = _fold_phi_d(phi_d) / np.pi * n_pd - 0.5
        i0, i1, ti = _linear_axis(ui, n_th)
        j0, j1, tj = _linear_axis(uj, n_td)
        k0, k1, tk = _periodic_axis(uk, n_pd)
        rows = [(i * (n_td * n_pd) + j * n_pd, wi * wj)
                for i, wi in ((i0, 1.0 - ti), (i1, ti)) for j, wj in ((j0, 1.0 - tj), (j1, tj))]
        corners = [(ij + k, wij * wk) for ij, wij in rows for k, wk in ((k0, 1.0 - tk), (k1, tk))]
        out = []
        for c in channels:
            num = np.zeros(theta_h.shape)
            den = np.zeros(theta_h.shape)
            for flat, w in corners:
                val = flat_table[c].take(flat)
                w = np.where(val >= 0.0, w, 0.0)  # invalid cells are left out of the blend
                num += w * val
                den += w
            out.append(np.where(den > 0.0, num / np.where(den > 0.0, den, 1.0), 0.0))
        return out


# ---- tabulation and files ---------------------------------------------------------------------


def tabulate(brdf: BRDF, dims=MERL_DIMS, rgb=(1.0, 1.0, 1.0)) -> np.ndarray:
    """Sample ``brdf`` at the MERL cell centres (phi_h = 0): (3, n_theta_h, n_theta_d, n_phi_d).

    Channel c holds ``rgb[c] * b(v, s)`` for a scalar BRDF, or ``rgb[c] * brdf.rgb(v, s)[c]`` for a
    :class:`TabulatedBRDF` (resampling). Cells whose centre has a direction at or below the
    horizon hold -1 (invalid). Values are BRDF values, not divided by the MERL scales.
    """
    n_th, n_td, n_pd = _check_dims(dims, "tabulate")
    factors = np.asarray(rgb, dtype=np.float64)
    if factors.shape != (3,) or not np.all(np.isfinite(factors)) or np.any(factors < 0.0):
        raise ValueError(f"tabulate: rgb must be three finite factors >= 0, got {rgb!r}")
    centres_h, centres_d, centres_p = merl_cell_centres(dims)
    out = np.empty((3, n_th, n_td, n_pd))
    td, pd = np.meshgrid(centres_d, centres_p, indexing="ij")
    step = max(1, 1_000_000 // (n_td * n_pd))
    for i in range(0, n_th, step):
        th = centres_h[i : i + step, None, None]
        v, s = half_diff_directions(th, td[None], pd[None])
        valid = (v[..., 2] > 0.0) & (s[..., 2] > 0.0)
        # evaluate invalid cells at the normal pair: finite, and overwritten below
        up = np.array([0.0, 0.0, 1.0])
        v = np.where(valid[..., None], v, up)
        s = np.where(valid[..., None], s, up)
        if isinstance(brdf, TabulatedBRDF):
            vals = np.moveaxis(brdf.rgb(v, s), -1, 0) * factors[:, None, None, None]
        else:
            vals = factors[:, None, None, None] * np.asarray(brdf.evaluate(v, s), dtype=np.float64)[None]
        out[:, i : i + step] = np.where(valid[None], vals, -1.0)
    bad = ~np.isfinite(out)
    if bad.any():
        first = tuple(int(x) for x in np.unravel_index(int(np.argmax(bad)), out.shape))
        raise ValueError(f"tabulate: {getattr(brdf, 'name', brdf)!s} gave {int(bad.sum())} non-finite values "
                         f"(first at cell {first})")
    return out


def write_merl(path, brdf: BRDF, dims=MERL_DIMS, rgb=(1.0, 1.0, 1.0)) -> Path:
    """Tabulate ``brdf`` (:func:`tabulate`) and write it as a MERL ``.binary`` file, atomically.

    Stored values are ``value / MERL_SCALES[c]``; invalid cells (a direction below the horizon)
    store :data:`MERL_INVALID`. Returns the path.
    """
    path = Path(path)
    table = tabulate(brdf, dims, rgb)
    if not np.any(table > 0.0):
        raise ValueError(f"write_merl: {path}: the tabulated BRDF has no positive value (read_merl would refuse it)")
    scales = np.asarray(MERL_SCALES)[:, None, None, None]
    stored = np.where(table < 0.0, MERL_INVALID, table / scales)
    header = np.asarray(table.shape[1:], dtype="<i4")
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(header.tobytes())
            f.write(np.ascontiguousarray(stored, dtype="<f8").tobytes())
    return path


def read_merl(path, channel="rgb", interpolation="nearest") -> TabulatedBRDF:
    """Read a MERL ``.binary`` file into a :class:`TabulatedBRDF` (values times the scales).

    By default (``channel = "rgb"``) the table keeps its colour: a glossy stage shades each
    channel with that channel's BRDF (RPO builds one set of operators per channel), times its RGB
    ``specular`` factor. ``"luminance"`` shades the grey luminance (a coloured table read so warns,
    UserWarning, with the colour to give ``specular``); ``"r"``, ``"g"`` or ``"b"`` one channel.

    Raises:
        ValueError: naming the file, when it is missing or not a file, shorter than the header,
            has dims outside 1..4096, a size other than ``12 + 3 n_theta_h n_theta_d n_phi_d 8``
            bytes, non-finite entries, or no positive entry.
    """
    path = Path(path)
    if not path.exists():
        raise ValueError(f"read_merl: {path}: no such file")
    if not path.is_file():
        raise ValueError(f"read_merl: {path}: not a regular file")
    size = os.path.getsize(path)
    if size < MERL_HEADER_BYTES:
        raise ValueError(f"read_merl: {path}: {size} bytes, shorter than the {MERL_HEADER_BYTES}-byte header")
    with open(path, "rb") as f:
        dims = np.fromfile(f, dtype="<i4", count=3)
        if any(not 1 <= int(n) <= MAX_DIM for n in dims):
            raise ValueError(f"read_merl: {path}: header dims {tuple(int(n) for n in dims)} "
                             f"(n_theta_h, n_theta_d, n_phi_d) must each be in 1..{MAX_DIM}")
        count = 3 * int(np.prod(dims.astype(np.int64)))
        expected = MERL_HEADER_BYTES + 8 * count
        if size != expected:
            raise ValueError(f"read_merl: {path}: expected {expected} bytes for dims {tuple(int(n) for n in dims)} "
                             f"(12 + 3 * {count // 3} * 8), got {size}")
        stored = np.fromfile(f, dtype="<f8", count=count)
    if stored.size != count:  # the file changed while being read
        raise ValueError(f"read_merl: {path}: read {stored.size} of {count} values")
    stored = stored.astype(np.float64).reshape(3, *(int(n) for n in dims))
    bad = ~np.isfinite(stored)
    if bad.any():
        first = tuple(int(i) for i in np.unravel_index(int(np.argmax(bad)), stored.shape))
        raise ValueError(f"read_merl: {path}: {int(bad.sum())} non-finite (NaN or inf) entries, the first at "
                         f"(channel, theta_h, theta_d, phi_d) = {first}")
    if not np.any(stored > 0.0):
        raise ValueError(f"read_merl: {path}: no positive entry (the table is all zero or invalid)")
    table = stored * np.asarray(MERL_SCALES)[:, None, None, None]
    huge = np.abs(table) > MAX_VALUE
    if huge.any():
        first = tuple(int(i) for i in np.unravel_index(int(np.argmax(huge)), stored.shape))
        raise ValueError(f"read_merl: {path}: {int(huge.sum())} entries beyond {MAX_VALUE:g} /sr (largest "
                         f"{float(np.abs(table).max()):g}), the first at (channel, theta_h, theta_d, phi_d) = {first}; "
                         "not a BRDF table in the MERL layout")
    brdf = TabulatedBRDF(table, channel, interpolation, str(path))
    if brdf.channel == "luminance":
        _warn_if_coloured(table, path)
    return brdf


#: Relative spread of a table's mean channel values above which :func:`read_merl` calls it coloured.
COLOURED_SPREAD = 0.02


def _warn_if_coloured(table: np.ndarray, path: Path) -> None:
    """Warn that a coloured table read as its luminance renders grey, with the RGB colour (mean
    of each channel over the valid cells, luminance 1) that a stage's ``specular`` would need."""
    import warnings

    valid = np.all(table >= 0.0, axis=0)
    means = np.array([float(c[valid].mean()) if valid.any() else 0.0 for c in table])
    lum = float(np.dot(LUMINANCE_WEIGHTS, means))
    if lum <= 0.0 or (means.max() - means.min()) <= COLOURED_SPREAD * means.max():
        return
    colour = ", ".join(f"{c:.3f}" for c in means / lum)
    warnings.warn(f"read_merl: {path}: the table is coloured (mean RGB relative to its luminance: {colour}) and is "
                  f"read as its luminance, which renders grey; give the glossy stage specular = [{colour}] for its "
                  "colour, or read one channel (channel='r', 'g' or 'b')", UserWarning, stacklevel=3)
