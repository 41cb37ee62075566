"""On-disk cache of precompute artifacts, keyed by content hashes, written atomically.

An artifact set (one precompute stage's outputs: a dict of NumPy arrays) is stored as one
``.npz`` file named by its key. Files are written to a temporary name in the same directory
and moved into place with ``os.replace``, so an interrupted run never leaves a truncated
artifact behind and a concurrent reader sees either nothing or the complete file.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .._fileio import atomic_path
from .._hashing import hash_arrays, hash_json

__all__ = ["ArtifactCache", "default_cache_dir"]


def default_cache_dir() -> Path:
    """``$WARPSHADE_CACHE`` if set, else ``~/.cache/warpshade``."""
    env = os.environ.get("WARPSHADE_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "warpshade"


class ArtifactCache:
    """A directory of ``<key>.npz`` artifact files.

    Args:
        root: cache directory (created on first write). None disables the cache.
    """

    def __init__(self, root: str | os.PathLike | None):
        self.root = Path(root) if root is not None else None
        self.hits = 0
        self.misses = 0

    @property
    def enabled(self) -> bool:
        return self.root is not None

    def path(self, key: str) -> Path:
        if self.root is None:
            raise RuntimeError("artifact cache is disabled")
        return self.root / f"{key}.npz"

    def load(self, key: str) -> dict | None:
        """Return the cached arrays for ``key``, or None (also for an unreadable file)."""
        if self.root is None:
            return None
        p = self.path(key)
        if not p.exists():
            self.misses += 1
            return None
        try:
            with np.load(p, allow_pickle=False) as data:
                out = {k: data[k] for k in data.files}
        except (OSError, ValueError):  # a damaged file is a miss, never a crash or wrong data
            self.misses += 1
            return None
        self.hits += 1
        return out

    def store(self, key: str, arrays: dict) -> Path | None:
        """Write ``arrays`` atomically under ``key``; returns the file path."""
        if self.root is None:
            return None
        final = self.path(key)
        with atomic_path(final) as tmp:
            with open(tmp, "wb") as f:
                np.savez(f, **{k: np.asarray(v) for k, v in arrays.items()})
        return final
