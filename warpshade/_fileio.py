"""Atomic file output: write to a temporary file in the destination's directory, then rename.

Every file warpshade writes (USD layers, images, reports, cached artifacts, benchmark results)
goes through :func:`atomic_path`, so an interrupted run never leaves a truncated file where a
complete one is expected, and a reader sees either the old file or the new one.

Temporary files are named ``.<stem>-<pid>-<random><suffix>``. A process killed while writing
(SIGKILL: no clean-up runs) leaves its temporary file behind; the next write to the same
destination removes those of processes that no longer run (:func:`remove_stale_temporaries`).
"""

from __future__ import annotations

import json
import os
import re
import tempfile
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic_path", "write_text_atomic", "write_json_atomic", "remove_stale_temporaries", "temporary_pattern",
           "check_writable_dir", "captured_stderr"]


def _pid_alive(pid: int) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, owned by someone else
        return True
    return True


#: The random part of :func:`tempfile.mkstemp`'s names (eight characters of this alphabet): a
#: temporary file of :func:`atomic_path` is ``.<stem>-<pid>-<8 of them><suffix>``, and nothing else
#: counts as one (a user's ``.notes-123-draft.usda`` is left alone).
_MKSTEMP_RANDOM = "[a-z0-9_]{8}"


def temporary_pattern(path) -> re.Pattern:
    """The names of :func:`atomic_path`'s temporary files for ``path`` (group 1: the writer's
    process id): exactly mkstemp's shape, so that a user's file of a similar name is never one."""
    path = Path(path)
    return re.compile(rf"^\.{re.escape(path.stem)}-(\d+)-{_MKSTEMP_RANDOM}{re.escape(path.suffix)}$")


def remove_stale_temporaries(path) -> list[Path]:
    """Remove the temporary files of :func:`atomic_path` for ``path`` left by dead processes.

    Returns:
        The removed paths.
    """
    path = Path(path)
    pattern = temporary_pattern(path)
    removed = []
    try:
        entries = list(path.parent.iterdir())
    except OSError:
        return removed
    for entry in entries:
        m = pattern.match(entry.name)
        if m and int(m.group(1)) != os.getpid() and not _pid_alive(int(m.group(1))):
            try:
                entry.unlink()
                removed.append(entry)
            except OSError:
                pass
    return removed


@contextmanager
def captured_stderr():
    """Collect what native libraries print on file descriptor 2 (USD's diagnostics, Warp's
    start-up notes) while the block runs; yields a list that holds the lines afterwards."""
    import sys

    lines: list[str] = []
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as captured:
        os.dup2(captured.fileno(), 2)
        try:
            yield lines
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            captured.seek(0)
            text = captured.read().decode(errors="replace")
            lines.extend(line.strip() for line in text.splitlines() if line.strip())


def check_writable_dir(directory, what: str = "output directory") -> Path:
    """Create ``directory`` if needed and check that files can be created in it (``what`` names it in
    the messages; empty: the path alone).

    Raises:
        OSError: naming the directory (it is a file, or cannot be created or written).
    """
    d = Path(directory)
    named = f"{what} {d}" if what else str(d)
    if d.exists() and not d.is_dir():
        raise NotADirectoryError(f"{named} is an existing file, not a directory")
    try:
        d.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=f".warpshade-probe-{os.getpid()}-", dir=d)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise PermissionError(f"{named} is not writable ({exc.strerror or exc})") from None
    return d


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
    if path.exists() and path.is_dir():
        raise IsADirectoryError(f"cannot write {path}: it is a directory")
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(path if suffix is None else path.with_suffix(suffix))
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}-{os.getpid()}-", suffix=suffix if suffix is not None else path.suffix,
                               dir=path.parent)
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
