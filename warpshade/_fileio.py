"""Atomic file output: write to a temporary file in the destination's directory, then rename.

Every file warpshade writes (USD layers, images, reports, cached artifacts, benchmark results)
goes through :func:`atomic_path`, so an interrupted run never leaves a truncated file where a
complete one is expected, and a reader sees either the old file or the new one.
"""

from __future__ import annotations

import json
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic_path", "write_text_atomic", "write_json_atomic"]


@contextmanager
def atomic_path(path, suffix: str | None = None, exists: bool = True):
    """Yield a temporary path next to ``path``; on success it replaces ``path`` atomically.

    Args:
        path: the destination file. Its directory is created if missing.
        suffix: suffix of the temporary name (default: the destination's, so writers that
            pick a format from the extension work).
        exists: create the temporary file (True) or only reserve its name (False, for
            writers that refuse to overwrite, e.g. ``Sdf.Layer.CreateNew``).

    The file gets the usual permissions (0666 minus the umask), not mkstemp's 0600. On any
    exception the temporary file is removed and ``path`` is left untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}-", suffix=suffix if suffix is not None else path.suffix, dir=path.parent)
    os.close(fd)
    if not exists:
        os.unlink(tmp)
    try:
        yield Path(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_text_atomic(path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def _json_default(obj):
    import numpy as np

    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    return repr(obj)


def write_json_atomic(path, obj, indent: int = 2) -> Path:
    """Write ``obj`` as JSON (NumPy values converted) to ``path`` atomically."""
    return write_text_atomic(path, json.dumps(obj, indent=indent, default=_json_default))
