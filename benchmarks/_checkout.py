"""The commit a benchmark measured, for its JSON's meta (the scripts import it as a sibling module,
as they do ``_dish``: ``python benchmarks/<script>.py`` puts ``benchmarks/`` first on the path)."""

from __future__ import annotations

import subprocess
from pathlib import Path


def checkout_commit(root: Path) -> str | None:
    """``root``'s commit (with ``+changes`` when its tracked files differ), or None outside git."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "diff", "--quiet", "HEAD"], cwd=root, capture_output=True).returncode != 0
    except (OSError, subprocess.CalledProcessError):
        return None
    return head + ("+changes" if dirty else "")
