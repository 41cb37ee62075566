"""The ``warpshade`` command line."""

from __future__ import annotations

import argparse
import sys

__all__ = ["main"]


def _cmd_selfcheck(args) -> int:
    """Evaluate the SH basis on the Warp device and check it against the float64 reference."""
    import numpy as np

    from .basis import quadrature, sh

    q = quadrature.gauss_legendre(2 * (args.order - 1))
    y_ref = sh.basis(q.directions, args.order)
    y_wp = sh.basis(q.directions, args.order, device=args.device)
    gram = (y_wp.astype(np.float64) * q.weights[:, None]).T @ y_wp
    ortho = float(np.abs(gram - np.eye(args.order**2)).max())
    agree = float(np.abs(y_wp - y_ref).max())
    print(f"warpshade SH self-check (order {args.order}, device {args.device}):")
    print(f"  kernel vs float64 reference, max |diff|     = {agree:.3e}")
    print(f"  orthonormality by exact quadrature, max err = {ortho:.3e}")
    ok = agree < 1e-5 and ortho < 1e-5
    print("  OK" if ok else "  FAILED")
    return 0 if ok else 1


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="warpshade", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("selfcheck", help="check the Warp SH kernels against the float64 reference")
    p.add_argument("--order", type=int, default=6)
    p.add_argument("--device", default="cpu")
    p.set_defaults(func=_cmd_selfcheck)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
