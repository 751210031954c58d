"""`vecu plugins`: the installed plug-in ECU functions (entry-point group `vecu.functions`)."""

from __future__ import annotations

import argparse
import json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plugins", help="list installed plug-in ECU functions (package, version)",
                       description="The ECU functions installed packages bring through the "
                                   "entry-point group `vecu.functions` (docs/plugins.md): name, "
                                   "package and version, and whether it loads. Every vecu "
                                   "command runs the ones that load.")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(func=main, uses_kernels=False)


def main(args: argparse.Namespace) -> int:
    from dataclasses import asdict

    from vecu import functions

    found = functions.plugins()
    if args.json:
        print(json.dumps([asdict(p) for p in found], indent=1))
        return 0
    if not found:
        print(f"no plug-ins installed (entry-point group {functions.ENTRY_POINT_GROUP}; "
              "docs/plugins.md)")
        return 0
    for p in found:
        state = "ok" if p.error is None else f"NOT LOADED: {p.error}"
        print(f"{p.name:<20} {p.package} {p.version:<10} {p.target:<40} {state}")
    return 0
