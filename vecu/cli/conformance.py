"""`vecu conformance list`: the diagnostic faults an ECU (`vecu ecu --diag-fault`) commits on
purpose, each with the rule a tester must follow (docs/conformance.md)."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from typing import Any


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("conformance", help="diagnostic faults for tester conformance",
                       description="Named diagnostic faults (UDS, ISO-TP, DoIP) that the ECU "
                                   "commits on purpose with `vecu ecu --diag-fault "
                                   "NAME[=VALUE][@T0[-T1]]` or `@request=N`, each with the "
                                   "client behaviour ISO 14229-2 / 15765-2 / 13400-2 asks "
                                   "(docs/conformance.md).")
    cmds = p.add_subparsers(dest="conformance_command", required=True)
    lst = cmds.add_parser("list", help="list the faults and their rules")
    lst.add_argument("--json", action="store_true", help="print JSON instead of a table")
    lst.add_argument("--layer", choices=("uds", "isotp-rx", "isotp-tx", "doip"), default=None,
                     help="only the faults of this layer")
    lst.set_defaults(func=main_list)


def main_list(args: argparse.Namespace) -> int:
    from vecu.conformance.catalogue import FAULTS

    rows = [f for f in FAULTS.values() if args.layer in (None, f.layer)]
    if args.json:
        print(json.dumps([f.as_dict() for f in rows], indent=1))
        return 0
    lines = []
    for f in rows:
        param = f"={f.param.upper()} ({f.range_text()}, default {f.default:g})" if f.param else ""
        lines += [f"{f.name}{param}  [{f.layer}]  {f.does}",
                  f"    client must: {f.expect}; exit {f.outcome}"
                  + (f"; bus rule {f.rule}" if f.rule else ""),
                  f"    {f.clause}"]
    try:
        sys.stdout.write("\n".join(lines) + "\n")
        sys.stdout.flush()
    except BrokenPipeError:  # `vecu conformance list | head`
        sys.stderr.close()
    return 0


def diag_fault_type(doip: bool) -> Callable[[str], Any]:
    """argparse type of --diag-fault: a checked setting (vecu.conformance.setting) of the ECU
    (doip False) or the gateway (True); an unknown name or a bad value: one line naming the
    known faults."""

    def parse(text: str) -> Any:
        from vecu.conformance.setting import parse_setting
        from vecu.errors import BadArgumentError

        try:
            setting = parse_setting(text)
        except BadArgumentError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
        if setting.fault.doip != doip:
            who = ("a DoIP fault: `vecu gateway --diag-fault` commits it" if setting.fault.doip
                   else "an ECU fault: `vecu ecu --diag-fault` commits it")
            raise argparse.ArgumentTypeError(f"{setting.fault.name} is {who}")
        return setting

    parse.__name__ = "diagnostic fault"
    return parse


def add_diag_fault_option(p: argparse.ArgumentParser, doip: bool) -> None:
    p.add_argument("--diag-fault", type=diag_fault_type(doip), action="append", default=[],
                   metavar="NAME[=VALUE][@T0[-T1]]",
                   help="commit a diagnostic fault on purpose (repeatable): from T0 to T1 s "
                        "after start (default: always), or NAME[=VALUE]@request=N for the Nth "
                        "request only; the faults and their rules: `vecu conformance list"
                        f"{' --layer doip' if doip else ''}` (docs/conformance.md)")
