"""``python -m warpshade.usd_assets.generator [--scenes NAME ...] [--out DIR]``: write the bundled scenes."""

from __future__ import annotations

import argparse
import os
import sys

from . import MAKERS, SCENES, generate


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m warpshade.usd_assets.generator",
                                     description="Write the bundled scenes of warpshade.")
    parser.add_argument("--out", default=None, help="output directory (default: the bundled directory, warpshade/usd_assets)")
    parser.add_argument("--scenes", nargs="*", default=list(SCENES), choices=sorted(MAKERS),
                        help="scenes to write (default: all but ripples, sunlit, cloth_train, cloth_heldout, svbrdf and aniso_table)")
    args = parser.parse_args(argv)
    for path in generate(args.out, args.scenes):
        print(f"{os.path.getsize(path):>9,d} bytes  {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
