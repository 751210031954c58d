"""`vecu figures`: every seed figure reproduced as a PNG from vecu's own runs."""

from __future__ import annotations

import argparse

from vecu import argtypes
from vecu.figures import FAMILIES


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("figures", help="reproduce the seed papers' figures as PNGs",
                       description="Run vecu and redraw each seed figure (titled with the "
                                   "paper's figure number) into --out; docs/reproduction.md "
                                   "sets them beside the papers'.")
    p.add_argument("--out", type=argtypes.out_dir, default="figures", metavar="DIR", help="directory (default figures)")
    p.add_argument("--only", choices=FAMILIES, action="append", default=None,
                   help="one family (repeatable; default all)")
    p.add_argument("--quick", action="store_true", help="reduced lengths (CI): same figures")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from pathlib import Path

    from vecu.figures import make_figures

    out = Path(args.out)  # checked before any work (vecu.cli.outputs)
    out.mkdir(parents=True, exist_ok=True)
    for path, note in make_figures(out, args.only or list(FAMILIES), quick=args.quick):
        print(f"{path}  {note}")
    return 0
