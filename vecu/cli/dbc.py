"""`vecu dbc export DIR`: vecu's own DBC files, and one merged DBC of everything vecu sends, for
tools that decode a trace with a single database (cantools, SavvyCAN, …)."""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from vecu import argtypes
from vecu.cli.outputs import check_output_dir
from vecu.errors import BadFileError

MERGED = "vecu_all.dbc"  # estimates, truth, harness frames (and plug-ins' own messages) in one


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("dbc", help="hand out vecu's DBC files",
                       description="vecu's CAN databases (the README's DBC table).")
    dsub = p.add_subparsers(dest="dbc_command", required=True)
    e = dsub.add_parser(
        "export", help="write vecu's DBCs and one merged DBC into a directory",
        description="Write vecu.dbc (plant sensors, ECU estimates and diagnostics, test harness), "
                    f"vecu_truth.dbc (the debug truth frames of `vecu run --log`) and {MERGED}: "
                    "both in one file, which decodes every frame of a vecu trace on its own "
                    "(e.g. `python -m cantools decode DIR/vecu_all.dbc < run.log`).")
    e.add_argument("dir", metavar="DIR", help="directory to write into (created if missing)")
    e.add_argument("--instance", type=argtypes.bounded(0, 7, integer=True), default=0,
                   metavar="N", help=f"{MERGED} with ECU instance N's IDs (`vecu ecu --instance "
                                     "N`; default 0, the IDs of vecu.dbc)")
    e.add_argument("--force", action="store_true", help="overwrite files of the same names")
    e.set_defaults(func=main, uses_kernels=False)


def main(args: argparse.Namespace) -> int:
    from vecu.codec import DEFAULT_DBC, TRUTH_DBC, builtin_dbc_path
    from vecu.functions import function_codec

    check_output_dir(args.dir)  # a directory vecu can create and write, before any work
    out = Path(args.dir)
    targets = [out / DEFAULT_DBC, out / TRUTH_DBC, out / MERGED]
    clash = [str(t) for t in targets if t.exists()]
    if clash and not args.force:
        raise BadFileError(clash[0], "exists (--force overwrites)")
    text = function_codec(args.instance).dbc_text()
    try:
        out.mkdir(parents=True, exist_ok=True)
        for name in (DEFAULT_DBC, TRUTH_DBC):
            shutil.copyfile(builtin_dbc_path(name), out / name)
        (out / MERGED).write_text(text, encoding="utf-8")
    except OSError as exc:
        raise BadFileError(args.dir, f"cannot write: {exc.strerror}") from None
    for t in targets:
        print(t)
    return 0
