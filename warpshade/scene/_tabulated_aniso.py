"""Tabulated anisotropic BRDFs in warpshade's own 4-D half/difference layout (float64 mirrors).

Conventions as in :mod:`warpshade.scene._materials`: a local shading frame with +z the normal and
+x the tangent (the direction an anisotropic material is "brushed" along); ``evaluate(view,
light)`` returns ``b(v, s)`` in 1/sr without the cosine, 0 below the horizon.

Parameterisation: the Rusinkiewicz (1998) half/difference angles of
:mod:`warpshade.scene._tabulated` (``theta_h``, ``phi_h``, ``theta_d``, ``phi_d``), with ``phi_h``
kept (an anisotropic BRDF depends on it). Two symmetries halve the table:

* reciprocity, ``b(v, s) = b(s, v)``: swapping ``v`` and ``s`` keeps ``h`` and maps ``d`` to
  ``(-d_x, -d_y, d_z)``, i.e. ``phi_d`` to ``phi_d + pi``; ``phi_d`` is folded into [0, pi);
* a half-turn about the normal, ``b(R v, R s) = b(v, s)`` with ``R = R_z(pi)``: the surfaces this
  layout is for have a tangent *line* (brush marks, grooves, fibres; a UV tangent field where
  ``t`` and ``-t`` are the same material), so ``x -> -x, y -> -y`` changes nothing. It maps
  ``phi_h`` to ``phi_h + pi`` and leaves ``d`` (expressed in the rotated half-vector frame) and so
  ``theta_d``, ``phi_d`` unchanged; ``phi_h`` is folded into [0, pi). (Every microfacet model with
  an NDF and masking even in ``h_x`` and ``h_y`` -- anisotropic Beckmann, GGX, Ward -- has it.)

Cells: ``theta_h`` cell ``floor(sqrt(theta_h / (pi/2)) n_theta_h)`` (finer near the specular peak,
as MERL), ``phi_h`` cell ``floor(phi_h / pi n_phi_h)`` of the folded angle, ``theta_d`` cell
``floor(theta_d / (pi/2) n_theta_d)``, ``phi_d`` cell ``floor(phi_d / pi n_phi_d)`` of the folded
angle, each clamped to the table; cell centres at ``((i + 0.5) / n)^2 pi/2``, ``(j + 0.5) / n pi``,
``(k + 0.5) / n pi/2`` and ``(l + 0.5) / n pi`` (:func:`aniso_cell_centres`). "nearest" looks up
the cell; "linear" interpolates 4-linearly in the cell-index space, clamped in ``theta_h`` and
``theta_d``, periodic in ``phi_h`` and ``phi_d`` (period pi each, by the symmetries); invalid
cells are left out of the blend and the remaining weights renormalised (0 when none is valid).

File layout (``.anisobrdf``, little-endian, 32-byte header)::

    char[8]  magic  b"WSANISO\\0"
    uint32   version                                    (1)
    uint32   channels                                   (1: grey, 3: linear RGB)
    uint32   n_theta_h, n_phi_h, n_theta_d, n_phi_d     (each 1..1024)
    float32  values[channels][n_theta_h][n_phi_h][n_theta_d][n_phi_d]   (phi_d fastest)

Values are BRDF values in 1/sr (no channel scales); a negative value marks an invalid cell (a
cell centre with a direction at or below the horizon, or unmeasured). :func:`write_anisotropic_table`
writes atomically (:func:`warpshade._fileio.atomic_path`); :func:`read_anisotropic_table` checks
the magic, version, channel count, dimensions, file size, finiteness and range, naming the file in
every error. :func:`tabulate_anisotropic` samples any :class:`~warpshade.scene._materials.BRDF` of
the local frame at the cell centres (``phi_h`` over [0, pi)).
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._fileio import atomic_path
from ._materials import BRDF, _unit
from ._tabulated import LUMINANCE_WEIGHTS, _half_diff, _linear_axis, _periodic_axis, half_diff_directions

__all__ = [
    "ANISO_EXTENSION",
    "ANISO_HEADER_BYTES",
    "ANISO_MAGIC",
    "AnisotropicTable",
    "aniso_cell_centres",
    "aniso_indices",
    "is_anisotropic_table",
    "read_anisotropic_table",
    "table_lookup",
    "tabulate_anisotropic",
    "write_anisotropic_table",
]

ANISO_MAGIC = b"WSANISO\x00"
ANISO_VERSION = 1
ANISO_HEADER_BYTES = 32
ANISO_EXTENSION = ".anisobrdf"
#: Largest size along one axis the reader accepts.
ANISO_MAX_DIM = 1024
#: Largest |value| (1/sr) the reader accepts (as :data:`warpshade.scene._tabulated.MAX_VALUE`).
ANISO_MAX_VALUE = 1e10
_INTERPOLATIONS = ("nearest", "linear")
_CHANNELS = {"luminance": None, "r": 0, "g": 1, "b": 2}


def _check_dims(dims, what: str) -> tuple[int, int, int, int]:
    try:
        out = tuple(int(n) for n in dims)
    except (TypeError, ValueError):
        raise ValueError(f"{what}: dims must be four integers, got {dims!r}") from None
    if len(out) != 4 or any(not 1 <= n <= ANISO_MAX_DIM for n in out):
        raise ValueError(f"{what}: dims (n_theta_h, n_phi_h, n_theta_d, n_phi_d) must each be in 1..{ANISO_MAX_DIM}, "
                         f"got {dims!r}")
    return out


def _fold(phi):
    """An angle folded into [0, pi) (both of the layout's symmetries have period pi)."""
    return np.mod(phi, np.pi)


def aniso_cell_centres(dims):
    """Angles of the cell centres: (theta_h, phi_h, theta_d, phi_d), 1-D float64 arrays."""
    n_th, n_ph, n_td, n_pd = _check_dims(dims, "aniso_cell_centres")
    return (((np.arange(n_th) + 0.5) / n_th) ** 2 * (np.pi / 2.0), (np.arange(n_ph) + 0.5) / n_ph * np.pi,
            (np.arange(n_td) + 0.5) / n_td * (np.pi / 2.0), (np.arange(n_pd) + 0.5) / n_pd * np.pi)


def _coordinates(theta_h, phi_h, theta_d, phi_d, dims):
    """Continuous cell coordinates of the angles (cell i spans [i, i + 1))."""
    n_th, n_ph, n_td, n_pd = dims
    return (np.sqrt(np.maximum(theta_h, 0.0) / (np.pi / 2.0)) * n_th, _fold(phi_h) / np.pi * n_ph,
            np.asarray(theta_d, np.float64) / (np.pi / 2.0) * n_td, _fold(phi_d) / np.pi * n_pd)


def aniso_indices(theta_h, phi_h, theta_d, phi_d, dims):
    """The cell of each angle quadruple (phi's unfolded or folded): four int64 arrays."""
    dims = _check_dims(dims, "aniso_indices")
    coords = _coordinates(np.asarray(theta_h, np.float64), np.asarray(phi_h, np.float64),
                          np.asarray(theta_d, np.float64), np.asarray(phi_d, np.float64), dims)
    return tuple(np.clip(np.floor(u), 0, n - 1).astype(np.int64) for u, n in zip(coords, dims))


@dataclass(frozen=True, eq=False)
class AnisotropicTable(BRDF):
    """An anisotropic BRDF tabulated in the layout of the module docstring. Immutable: use
    ``dataclasses.replace(brdf, interpolation="linear")`` for a variant.

    Attributes:
        table: BRDF values, (channels, n_theta_h, n_phi_h, n_theta_d, n_phi_d), channels 1 or 3,
            float64 (a read-only copy); negative entries are invalid cells.
        channel: what :meth:`evaluate` returns: "luminance" (:data:`LUMINANCE_WEIGHTS` of an RGB
            table; the one channel of a grey one) or "r" / "g" / "b" of an RGB table.
        interpolation: "nearest" or "linear".
        source: the file it came from, or "<array>".
    """

    table: np.ndarray = field(repr=False)
    channel: str = "luminance"
    interpolation: str = "linear"
    source: str = "<array>"
    name = "tabulated-anisotropic"

    def __post_init__(self):
        table = np.array(self.table, dtype=np.float64, copy=True)
        if table.ndim != 5 or table.shape[0] not in (1, 3):
            raise ValueError("AnisotropicTable: table must have shape (1 or 3, n_theta_h, n_phi_h, n_theta_d, n_phi_d), "
                             f"got {table.shape}")
        _check_dims(table.shape[1:], "AnisotropicTable")
        if not np.all(np.isfinite(table)):
            raise ValueError(f"AnisotropicTable: table has {int((~np.isfinite(table)).sum())} non-finite entries")
        if self.interpolation not in _INTERPOLATIONS:
            raise ValueError(f"AnisotropicTable: interpolation must be one of {_INTERPOLATIONS}, got {self.interpolation!r}")
        if self.channel not in _CHANNELS or (table.shape[0] == 1 and self.channel != "luminance"):
            raise ValueError(f"AnisotropicTable: channel must be 'luminance' or, for an RGB table, 'r', 'g' or 'b'; "
                             f"got {self.channel!r} for {table.shape[0]} channel(s)")
        table.flags.writeable = False
        object.__setattr__(self, "table", table)
        object.__setattr__(self, "source", str(self.source))
        object.__setattr__(self, "_hash", hashlib.sha1(np.ascontiguousarray(table, "<f8").tobytes()).hexdigest()[:16])

    @property
    def dims(self) -> tuple[int, int, int, int]:
        return tuple(int(n) for n in self.table.shape[1:])

    @property
    def content_hash(self) -> str:
        return self._hash

    def describe(self) -> dict:
        return {"model": self.name, "source": self.source, "channel": self.channel, "interpolation": self.interpolation,
                "dims": list(self.dims), "channels": int(self.table.shape[0]), "table_sha1": self.content_hash}

    def scalar_table(self) -> np.ndarray:
        """The (n_theta_h, n_phi_h, n_theta_d, n_phi_d) table :meth:`evaluate` looks up (the
        channel, or the luminance; cells invalid in any channel stay invalid)."""
        t = self.table
        if t.shape[0] == 1:
            return t[0]
        c = _CHANNELS[self.channel]
        if c is not None:
            return t[c]
        lum = np.tensordot(np.asarray(LUMINANCE_WEIGHTS), np.maximum(t, 0.0), axes=1)
        return np.where(np.any(t < 0.0, axis=0), -1.0, lum)

    def _eval(self, v, s):
        return table_lookup(self.scalar_table(), self.interpolation, v, s)


def table_lookup(table: np.ndarray, interpolation: str, v, s) -> np.ndarray:
    """One-channel look-up of unit local directions (broadcast), float64 (the horizon is not tested here)."""
    theta_h, phi_h, theta_d, phi_d = _half_diff(*np.broadcast_arrays(v, s))
    dims = table.shape
    flat = table.reshape(-1)
    strides = (dims[1] * dims[2] * dims[3], dims[2] * dims[3], dims[3], 1)
    coords = _coordinates(theta_h, phi_h, theta_d, phi_d, dims)
    if interpolation == "nearest":
        idx = sum(np.clip(np.floor(u), 0, n - 1).astype(np.int64) * st for u, n, st in zip(coords, dims, strides))
        return np.maximum(flat.take(idx), 0.0)
    axes = [_linear_axis(coords[0] - 0.5, dims[0]), _periodic_axis(coords[1] - 0.5, dims[1]),
            _linear_axis(coords[2] - 0.5, dims[2]), _periodic_axis(coords[3] - 0.5, dims[3])]
    num = np.zeros(theta_h.shape)
    den = np.zeros(theta_h.shape)
    for corner in range(16):
        idx = 0
        w = 1.0
        for a, ((i0, i1, t), st) in enumerate(zip(axes, strides)):
            up = (corner >> a) & 1
            idx = idx + (i1 if up else i0) * st
            w = w * (t if up else 1.0 - t)
        val = flat.take(idx)
        w = np.where(val >= 0.0, w, 0.0)
        num += w * val
        den += w
    return np.where(den > 0.0, num / np.where(den > 0.0, den, 1.0), 0.0)


# ---- tabulation and files ---------------------------------------------------------------------


def tabulate_anisotropic(brdf: BRDF, dims, rgb=None) -> np.ndarray:
    """Sample ``brdf`` (local frame, +x the tangent) at the cell centres: (channels, *dims),
    float64; channels 1 (``rgb`` None) or 3 (``rgb[c]`` times the BRDF). Invalid cells (a centre
    direction at or below the horizon) hold -1."""
    n_th, n_ph, n_td, n_pd = _check_dims(dims, "tabulate_anisotropic")
    factors = np.ones(1) if rgb is None else np.asarray(rgb, np.float64).reshape(-1)
    if factors.shape not in ((1,), (3,)) or not np.all(np.isfinite(factors)) or np.any(factors < 0.0):
        raise ValueError(f"tabulate_anisotropic: rgb must be three finite factors >= 0, got {rgb!r}")
    th, ph, td, pd = aniso_cell_centres(dims)
    out = np.empty((factors.size, n_th, n_ph, n_td, n_pd))
    gp, gd, gq = np.meshgrid(ph, td, pd, indexing="ij")
    for i in range(n_th):
        v, s = half_diff_directions(th[i], gd, gq, gp)
        valid = (v[..., 2] > 0.0) & (s[..., 2] > 0.0)
        up = np.array([0.0, 0.0, 1.0])
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # finite where valid, checked below
            vals = np.asarray(brdf.evaluate(np.where(valid[..., None], v, up), np.where(valid[..., None], s, up)),
                              np.float64)
        vals = np.where(valid, vals, 0.0)
        out[:, i] = np.where(valid[None], factors[:, None, None, None] * vals[None], -1.0)
    if not np.all(np.isfinite(out)):
        raise ValueError(f"tabulate_anisotropic: {getattr(brdf, 'name', brdf)!s} gave non-finite values")
    return out


def write_anisotropic_table(path, table) -> Path:
    """Write a (channels, n_theta_h, n_phi_h, n_theta_d, n_phi_d) table (channels 1 or 3) as an
    ``.anisobrdf`` file, atomically; returns the path."""
    path = Path(path)
    t = AnisotropicTable(table).table  # validates shape and values
    if not np.any(t > 0.0):
        raise ValueError(f"write_anisotropic_table: {path}: the table has no positive value")
    header = ANISO_MAGIC + np.asarray([ANISO_VERSION, t.shape[0], *t.shape[1:]], dtype="<u4").tobytes()
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(header)
            f.write(np.ascontiguousarray(t, dtype="<f4").tobytes())
    return path


def is_anisotropic_table(path) -> bool:
    """Whether the file starts with :data:`ANISO_MAGIC`."""
    try:
        with open(path, "rb") as f:
            return f.read(len(ANISO_MAGIC)) == ANISO_MAGIC
    except OSError:
        return False


def read_anisotropic_table(path, channel: str = "luminance", interpolation: str = "linear") -> AnisotropicTable:
    """Read an ``.anisobrdf`` file (module docstring) into an :class:`AnisotropicTable`.

    Raises:
        ValueError: naming the file, when it is missing, shorter than the header, has a wrong
            magic, an unknown version, a channel count other than 1 or 3, dims outside 1..1024,
            a size other than the header's, non-finite or out-of-range entries, or no positive one.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"read_anisotropic_table: {path}: no such file" if not path.exists()
                         else f"read_anisotropic_table: {path}: not a regular file")
    size = os.path.getsize(path)
    if size < ANISO_HEADER_BYTES:
        raise ValueError(f"read_anisotropic_table: {path}: {size} bytes, shorter than the {ANISO_HEADER_BYTES}-byte header")
    with open(path, "rb") as f:
        head = f.read(ANISO_HEADER_BYTES)
        if head[:8] != ANISO_MAGIC:
            raise ValueError(f"read_anisotropic_table: {path}: bad magic {head[:8]!r} (expected {ANISO_MAGIC!r}); "
                             "not an anisotropic BRDF table")
        version, channels, *dims = (int(x) for x in np.frombuffer(head[8:], dtype="<u4"))
        if version != ANISO_VERSION:
            raise ValueError(f"read_anisotropic_table: {path}: version {version}, this reader knows {ANISO_VERSION}")
        if channels not in (1, 3):
            raise ValueError(f"read_anisotropic_table: {path}: {channels} channels (1 or 3 expected)")
        if any(not 1 <= n <= ANISO_MAX_DIM for n in dims):
            raise ValueError(f"read_anisotropic_table: {path}: header dims {tuple(dims)} (n_theta_h, n_phi_h, n_theta_d, "
                             f"n_phi_d) must each be in 1..{ANISO_MAX_DIM}")
        count = channels * int(np.prod(np.asarray(dims, np.int64)))
        expected = ANISO_HEADER_BYTES + 4 * count
        if size != expected:
            raise ValueError(f"read_anisotropic_table: {path}: expected {expected} bytes for {channels} channel(s) of dims "
                             f"{tuple(dims)}, got {size} (truncated or padded)")
        data = np.fromfile(f, dtype="<f4", count=count)
    if data.size != count:
        raise ValueError(f"read_anisotropic_table: {path}: read {data.size} of {count} values")
    table = data.astype(np.float64).reshape(channels, *dims)
    bad = ~np.isfinite(table) | (np.abs(table) > ANISO_MAX_VALUE)
    if bad.any():
        first = tuple(int(i) for i in np.unravel_index(int(np.argmax(bad)), table.shape))
        raise ValueError(f"read_anisotropic_table: {path}: {int(bad.sum())} non-finite or out-of-range entries, the first "
                         f"at (channel, theta_h, phi_h, theta_d, phi_d) = {first}")
    if not np.any(table > 0.0):
        raise ValueError(f"read_anisotropic_table: {path}: no positive entry")
    try:
        return AnisotropicTable(table, channel, interpolation, str(path))
    except ValueError as exc:
        raise ValueError(f"read_anisotropic_table: {path}: {exc}") from None
