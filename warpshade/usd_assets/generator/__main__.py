"""``python -m warpshade.usd_assets.generator [--scenes NAME ...] [--out DIR]``: write the bundled scenes.

An output directory that cannot be written (a file, no permission, a full disk) ends in one line
naming it, and exit status 2, before any scene is built where that can be known.
"""

from __future__ import annotations

import argparse
import os
import sys

from ..._fileio import check_writable_dir
from ...io import bundled_asset_directory
from . import MAKERS, SCENES, generate

PROG = "python -m warpshade.usd_assets.generator"


def _message(exc: OSError) -> str:
    """An OSError as one line with the path, without ``[Errno N]``."""
    if exc.strerror and exc.filename:
        return f"{exc.filename}: {exc.strerror}"
    return str(exc.strerror or exc)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog=PROG, description="Write the bundled scenes of warpshade.")
    parser.add_argument("--out", default=None, help="output directory (default: the bundled directory, warpshade/usd_assets)")
    parser.add_argument("--scenes", nargs="*", default=list(SCENES), choices=sorted(MAKERS),
                        help="scenes to write (default: all but ripples, sunlit, cloth_train, cloth_heldout, svbrdf and aniso_table)")
    args = parser.parse_args(argv)
    out = bundled_asset_directory() if args.out is None else args.out
    try:
        check_writable_dir(out, "--out directory")
        written = generate(out, args.scenes)
    except OSError as exc:
        print(f"{PROG}: error: {_message(exc)}", file=sys.stderr)
        return 2
    for path in written:
        print(f"{os.path.getsize(path):>9,d} bytes  {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
