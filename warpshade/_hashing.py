"""Content hashes of arrays and JSON-able values (cache keys of artifacts and ground truth)."""

from __future__ import annotations

import hashlib
import json

import numpy as np

__all__ = ["hash_arrays", "hash_json"]


def hash_arrays(arrays, h=None) -> str:
    """SHA-256 over the dtype, shape and bytes of a sequence of arrays (None allowed)."""
    h = h or hashlib.sha256()
    for a in arrays:
        if a is None:
            h.update(b"<none>")
            continue
        a = np.ascontiguousarray(a)
        h.update(str(a.dtype).encode())
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def hash_json(obj) -> str:
    """SHA-256 of a canonical JSON encoding (sorted keys) of ``obj``."""
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=repr).encode()).hexdigest()
