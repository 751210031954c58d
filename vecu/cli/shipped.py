"""`vecu scenario list|show` and `vecu campaign list|show`: the files shipped with vecu, by name."""

from __future__ import annotations

import argparse
import sys

from vecu.shipped import describe, resolve, shipped_files
from vecu.tomlfile import read_toml


def register_list_show(sub: argparse._SubParsersAction, kind: str) -> None:
    """Add `list` and `show` under the `kind` ("scenario" or "campaign") subcommand."""
    ls = sub.add_parser("list", help=f"list the {kind}s shipped with vecu",
                        description=f"The shipped {kind}s: name and description. Run one by "
                                    f"name from any directory (`vecu {kind} run NAME`).")
    ls.add_argument("--names", action="store_true", help="names only, one per line")
    ls.set_defaults(func=lambda args: _list(kind, args.names), uses_kernels=False)
    sh = sub.add_parser("show", help=f"print a shipped {kind} file (to copy and edit)",
                        description=f"Print the {kind} file NAME (or a path) to copy and edit, "
                                    f"e.g. `vecu {kind} show NAME > mine.toml`.")
    sh.add_argument("name", metavar="NAME", help=f"a shipped {kind} (`vecu {kind} list`) or a file")
    sh.add_argument("--path", action="store_true", help="print where the file is instead")
    sh.set_defaults(func=lambda args: _show(kind, args.name, args.path), uses_kernels=False)


def _list(kind: str, names_only: bool) -> int:
    files = shipped_files(kind)
    width = max(map(len, files), default=0)
    for name, path in files.items():
        print(name if names_only else f"{name:<{width}}  {describe(path)}")
    return 0


def _show(kind: str, name: str, path_only: bool) -> int:
    path = resolve(kind, name)
    read_toml(path)  # a directory, unreadable or not TOML: one line naming it
    if path_only:
        print(path)
    else:
        sys.stdout.write(path.read_text(encoding="utf-8"))
    return 0
