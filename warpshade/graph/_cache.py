"""On-disk cache of precompute artifacts, keyed by content hashes, written atomically, checked on read.

An artifact set (one precompute stage's outputs: a dict of NumPy arrays) is stored as one
``.npz`` file named ``<key>.<digest>.npz``, where ``digest`` is the first 16 hex digits of the
SHA-256 of the file's bytes. Files are written to a temporary name in the same directory and
moved into place with ``os.replace``, so an interrupted run never leaves a truncated artifact
behind and a concurrent reader sees either nothing or the complete file.

On read the digest is recomputed: a truncated, zero-length or bit-flipped file, one that is not
a valid archive, or one holding pickled objects is *damaged* -- it is reported
(:attr:`ArtifactCache.damaged`), removed and treated as a miss, never raised and never
returned. What the arrays must look like (shapes, dtypes, finite values) is checked one level
up, against the stage's declared ports (:mod:`warpshade.graph._precompute`).
"""

from __future__ import annotations

import errno
import hashlib
import io
import os
from pathlib import Path

import numpy as np

from .._fileio import atomic_path

__all__ = [
    "DIGEST_LENGTH",
]

#: Hex digits of the SHA-256 digest in a cache file's name.
DIGEST_LENGTH = 16


def default_cache_dir() -> Path:
    """Where artifacts are cached: ``$WARPSHADE_CACHE`` if set, else ``$XDG_CACHE_HOME/warpshade``
    (the XDG base-directory convention; a relative ``$XDG_CACHE_HOME`` is ignored, as the
    specification says), else ``~/.cache/warpshade``."""
    env = os.environ.get("WARPSHADE_CACHE")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg and Path(xdg).is_absolute() else Path.home() / ".cache"
    return base / "warpshade"


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()[:DIGEST_LENGTH]


class ArtifactCache:
    """A directory of ``<key>.<digest>.npz`` artifact files.

    Args:
        root: cache directory (created on first write). None disables the cache.

    Attributes:
        hits, misses: counts of :meth:`load` outcomes.
        damaged: ``(file, reason)`` of every entry found damaged (and removed) by :meth:`load`.
    """

    def __init__(self, root: str | os.PathLike | None):
        self.root = Path(root) if root is not None else None
        if self.root is not None and self.root.exists() and not self.root.is_dir():
            raise NotADirectoryError(f"artifact cache {self.root} is an existing file, not a directory")
        self.hits = 0
        self.misses = 0
        self.damaged: list[tuple[str, str]] = []

    @property
    def enabled(self) -> bool:
        return self.root is not None

    def _entries(self, key: str) -> list[Path]:
        if self.root is None or not self.root.is_dir():
            return []
        return sorted(self.root.glob(f"{key}.*.npz"))

    def path(self, key: str) -> Path | None:
        """The file holding ``key``, or None."""
        entries = self._entries(key)
        return entries[0] if entries else None

    def _discard(self, p: Path, reason: str) -> None:
        self.damaged.append((str(p), reason))
        try:
            p.unlink()
        except OSError:
            pass

    def load(self, key: str) -> dict | None:
        """The cached arrays for ``key``, or None (a miss; damaged entries are removed)."""
        if self.root is None:
            return None
        for p in self._entries(key):
            expected = p.name[len(key) + 1 : -len(".npz")]
            try:
                data = p.read_bytes()
            except OSError as exc:
                self._discard(p, f"unreadable ({exc.strerror or exc})")
                continue
            if len(expected) != DIGEST_LENGTH or _digest(data) != expected:
                self._discard(p, f"content does not match its digest ({len(data)} bytes: truncated or altered)")
                continue
            try:
                with np.load(io.BytesIO(data), allow_pickle=False) as archive:
                    out = {k: archive[k] for k in archive.files}
            except Exception as exc:  # zipfile.BadZipFile, EOFError, zlib.error, ValueError (pickles), ...
                self._discard(p, f"not a readable archive ({type(exc).__name__}: {exc})")
                continue
            self.hits += 1
            return out
        self.misses += 1
        return None

    def store(self, key: str, arrays: dict) -> Path | None:
        """Write ``arrays`` atomically under ``key``; returns the file path (None when disabled).

        Raises:
            OSError: naming the cache directory when it cannot take the file (read-only, full).
        """
        if self.root is None:
            return None
        buffer = io.BytesIO()
        np.savez(buffer, **{k: np.asarray(v) for k, v in arrays.items()})
        data = buffer.getvalue()
        final = self.root / f"{key}.{_digest(data)}.npz"
        try:
            with atomic_path(final) as tmp:
                tmp.write_bytes(data)
        except OSError as exc:  # a read-only or full cache: name it and how to choose another
            raise OSError(exc.errno or errno.EIO, f"artifact cache {self.root}: cannot store {final.name} "
                          f"({exc.strerror or exc}); set $WARPSHADE_CACHE to a writable directory") from None
        for old in self._entries(key):  # an earlier entry of the same key (another digest)
            if old != final:
                try:
                    old.unlink()
                except OSError:
                    pass
        return final

    def discard(self, key: str, reason: str) -> None:
        """Remove every entry of ``key``, recording why (e.g. it failed its stage's checks)."""
        for p in self._entries(key):
            self._discard(p, reason)
