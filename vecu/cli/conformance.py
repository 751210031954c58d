"""`vecu conformance list`: the diagnostic faults an ECU (`vecu ecu --diag-fault`) commits on
purpose, each with the rule a tester must follow (docs/conformance.md)."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from vecu import argtypes


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
    run = cmds.add_parser("run", help="judge a tester command against each fault",
                          description="One fault at a time: `vecu ecu` (and `vecu gateway` for "
                                      "a DoIP fault) commits it, the tester command runs with "
                                      "VECU_CAN_INTERFACE, VECU_CAN_CHANNEL, VECU_UDS_REQUEST_ID, "
                                      "VECU_UDS_RESPONSE_ID, VECU_UDS_FUNCTIONAL_ID, "
                                      "VECU_DOIP_HOST, VECU_DOIP_PORT, VECU_DOIP_TARGET in its "
                                      "environment, and is judged by its exit status (0: it got "
                                      "the answers, 1: it reported an error) and the frames it "
                                      "sent. Default bus: udp_multicast in a private network "
                                      "namespace (docs/conformance.md).")
    run.add_argument("--tester", required=True, metavar="COMMAND",
                     help="the tester, a shell command")
    run.add_argument("--faults", type=argtypes.checked(_fault_list, "fault list"), default=None, metavar="NAME[=V],...",
                     help="the faults to try (default: every ECU fault, or with --doip every "
                          "DoIP fault)")
    run.add_argument("--doip", action="store_true",
                     help="the tester speaks DoIP: the default faults are the DoIP ones")
    run.add_argument("--interface", default=None,
                     help="python-can interface (default: udp_multicast in a private network "
                          "namespace)")
    run.add_argument("--channel", default=None, help="python-can channel (with --interface)")
    run.add_argument("--timeout", type=argtypes.bounded(1.0, 3600.0, unit="s"), default=30.0,
                     metavar="S", help="a tester still running after S s is killed: hung "
                                       "(default 30)")
    run.add_argument("--doip-port", type=argtypes.bounded(1, 65535, integer=True),
                     default=13400, metavar="N", help="the gateway's DoIP port (default 13400)")
    run.add_argument("--junit", type=argtypes.out_file, metavar="OUT.xml",
                     help="write a JUnit file: one case per fault")
    run.add_argument("--report", type=argtypes.out_dir, metavar="DIR",
                     help="write DIR/index.html, the table")
    run.set_defaults(func=main_run, uses_kernels=False)


def _fault_list(text: str) -> tuple[Any, ...]:
    from vecu.uds.diag_faults.setting import parse_setting

    return tuple(parse_setting(part) for part in text.split(",") if part.strip())


def main_run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from vecu.errors import BadArgumentError
    from vecu.uds.diag_faults.catalogue import FAULTS
    from vecu.uds.diag_faults.setting import setting

    faults = args.faults or tuple(setting(n) for n, f in FAULTS.items() if f.doip == args.doip)
    if (args.interface is None) != (args.channel is None):
        raise BadArgumentError("--interface and --channel go together")
    for path in (args.junit, args.report):
        if path is not None and not Path(path).resolve().parent.is_dir():
            raise BadArgumentError(f"{path}: its directory does not exist")
    if args.interface is None:
        return _in_namespace(args, faults)
    from vecu.conformance.bench import BenchConfig, run_bench
    from vecu.conformance.report import write_html, write_junit

    cfg = BenchConfig(args.tester, faults, args.interface, args.channel, args.timeout,
                      args.doip_port)

    def show(v: Any) -> None:
        print(f"{v.fault:<26} {v.verdict.upper():<5} {v.evidence}", flush=True)

    verdicts = run_bench(cfg, show)
    if args.junit:
        write_junit(Path(args.junit), verdicts, args.tester)
    if args.report:
        write_html(Path(args.report), verdicts, args.tester)
    passed = sum(v.verdict == "pass" for v in verdicts)
    print(f"vecu conformance: {passed}/{len(verdicts)} faults handled as the standard asks")
    return 0


def _in_namespace(args: argparse.Namespace, faults: tuple[Any, ...]) -> int:
    """The bench again, inside a private network namespace on udp_multicast (loopback)."""
    from pathlib import Path

    from vecu.errors import UnavailableError
    from vecu.live.netns import namespace_prefix, run_in_namespace
    from vecu.live.options import UDP_DEFAULT_GROUP

    if namespace_prefix()[0] is None:
        raise UnavailableError(f"{namespace_prefix()[1]}; give --interface and --channel")
    argv = [sys.executable, "-m", "vecu", "conformance", "run", "--tester", args.tester,
            "--faults", ",".join(str(f) for f in faults), "--interface", "udp_multicast",
            "--channel", UDP_DEFAULT_GROUP, "--timeout", f"{args.timeout:g}",
            "--doip-port", str(args.doip_port)]
    for flag, path in (("--junit", args.junit), ("--report", args.report)):
        if path is not None:
            argv += [flag, str(Path(path).resolve())]
    res = run_in_namespace(argv, timeout=len(faults) * (args.timeout + 90) + 60)
    sys.stdout.write(res.stdout)
    sys.stderr.write(res.stderr)
    return res.returncode


def main_list(args: argparse.Namespace) -> int:
    from vecu.uds.diag_faults.catalogue import FAULTS

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


def _diag_fault_setting(text: str, doip: bool) -> Any:
    """A checked setting (vecu.uds.diag_faults.setting) of the ECU (doip False) or the gateway."""
    from vecu.errors import BadArgumentError
    from vecu.uds.diag_faults.setting import parse_setting

    setting = parse_setting(text)
    if setting.fault.doip != doip:
        who = ("a DoIP fault: `vecu gateway --diag-fault` commits it" if setting.fault.doip
               else "an ECU fault: `vecu ecu --diag-fault` commits it")
        raise BadArgumentError(f"{setting.fault.name} is {who}")
    return setting


def add_diag_fault_option(p: argparse.ArgumentParser, doip: bool) -> None:
    p.add_argument("--diag-fault", type=argtypes.checked(
                       lambda text: _diag_fault_setting(text, doip), "diagnostic fault"),
                   action="append", default=[],
                   metavar="NAME[=VALUE][@T0[-T1]]",
                   help="commit a diagnostic fault on purpose (repeatable): from T0 to T1 s "
                        "after start (default: always), or NAME[=VALUE]@request=N for the Nth "
                        "request only; the faults and their rules: `vecu conformance list"
                        f"{' --layer doip' if doip else ''}` (docs/conformance.md)")
