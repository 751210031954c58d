"""`vecu restbus`: the rest of a user's bus from their DBC / ARXML files (docs/restbus.md)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from vecu import argtypes
from vecu.cli import configure_logging


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("restbus", help="simulate every message of your DBC / ARXML nodes, with "
                                       "AUTOSAR E2E and disturbances",
                       description="Send every message of the chosen nodes at its database cycle "
                                   "time (cyclic / on change / if active), from its start values "
                                   "or VALUES.toml, E2E-protected per E2E.toml; on the simulated "
                                   "clock (default) or a live bus (--realtime).")
    p.add_argument("databases", nargs="+", metavar="DB", help="DBC, ARXML, KCD or SYM files")
    p.add_argument("--node", action="append", default=[], metavar="NAME",
                   help="send this node's messages (repeatable; default: every node that sends "
                        "a message with a cycle time)")
    p.add_argument("--e2e", metavar="E2E.toml", help="AUTOSAR E2E profile per message")
    p.add_argument("--values", metavar="VALUES.toml", help="signal values over time")
    p.add_argument("--default-cycle", type=argtypes.bounded(0.1, 3_600_000.0), metavar="MS",
                   help="cycle time of messages the database gives none (default: skip them)")
    p.add_argument("--stagger", type=argtypes.bounded(0.0, 1000.0), default=0.0, metavar="MS",
                   help="first frame of the k-th message at k x MS (modulo its cycle) to spread "
                        "the bus load (default 0: all at once, as the database says)")
    p.add_argument("--disturb", action="append", default=[], metavar="SPEC",
                   help="TARGET:KIND[=VALUE][@START[-END]] e.g. ABS_Wheel:counter_freeze@1-2 "
                        "(repeatable; times in s)")
    p.add_argument("--duration", type=argtypes.bounded(0.001, 1e7), default=None, metavar="S",
                   help="seconds to run (default: 10 on the simulated clock, until Ctrl-C live)")
    p.add_argument("--seed", type=argtypes.seed, default=0, help="random seed, 0..2**63-1")
    p.add_argument("--interface", help="python-can interface (default: python-can config, "
                                       "else virtual)")
    p.add_argument("--channel", help="python-can channel (default: config, else 'vecu')")
    p.add_argument("--bitrate", type=argtypes.positive_int, help="bitrate where needed")
    p.add_argument("--realtime", action="store_true",
                   help="pace on the wall clock (absolute deadlines) on a live bus")
    p.add_argument("--log", type=argtypes.out_log, metavar="FILE", help="write every frame; format by suffix")
    p.add_argument("--summary", type=argtypes.out_file, metavar="FILE.json", help="write the JSON summary")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.set_defaults(func=main)


def parse_disturb(text: str):
    """TARGET:KIND[=VALUE][@START[-END]] -> ScheduledFault."""
    from vecu.errors import BadArgumentError
    from vecu.faults import ScheduledFault

    target, sep, rest = text.rpartition(":")
    if not sep or not target:
        raise BadArgumentError(f"--disturb {text!r}: expected TARGET:KIND[=VALUE][@START[-END]]")
    rest, _, when = rest.partition("@")
    kind, _, value = rest.partition("=")
    start, _, end = when.partition("-")
    try:
        v = float(value) if value else None
        t0 = float(start) if start else 0.0
        t1 = float(end) if end else None
    except ValueError:
        raise BadArgumentError(f"--disturb {text!r}: value and times must be numbers") from None
    if t0 < 0 or (t1 is not None and t1 <= t0):
        raise BadArgumentError(f"--disturb {text!r}: need 0 <= START < END")
    return ScheduledFault(target, kind.strip(), t0, t1, v)


def main(args: argparse.Namespace) -> int:
    configure_logging(args.quiet)
    from vecu.live.options import LiveOptions, bus_config
    from vecu.restbus.session import RestbusRun, run_restbus
    from vecu.restbus.spec import RestbusConfig

    duration = args.duration if args.duration is not None else (None if args.realtime else 10.0)
    channel = args.channel
    if args.realtime:  # as the live processes resolve it (udp_multicast: vecu's IPv4 group)
        channel = bus_config(LiveOptions(role="restbus", interface=args.interface,
                                         channel=args.channel, bitrate=args.bitrate))["channel"]
    run = RestbusRun(
        RestbusConfig(tuple(args.databases), tuple(args.node), args.e2e, args.values,
                      args.default_cycle, args.seed, stagger_ms=args.stagger),
        duration_s=duration, realtime=args.realtime, interface=args.interface,
        channel=channel, bitrate=args.bitrate, log_path=args.log,
        disturbances=tuple(parse_disturb(d) for d in args.disturb))
    result = run_restbus(run)
    s = result.summary
    if args.summary:
        Path(args.summary).write_text(json.dumps(s, indent=2) + "\n")
    if not args.quiet:
        print(f"vecu restbus: {s['messages']} messages, {s['frames_sent']} frames in "
              f"{s['duration_s']:.3g} s ({s['clock']} clock, {s['wall_s']:.2f} s wall); "
              f"{len(s['disturbances'])} disturbance events; send errors {s['send_errors']}"
              + (f"; not sent: {len(s['skipped'])} ({_reasons(s['skipped'])})"
                 if s["skipped"] else ""))
    if s["interrupted"]:  # Ctrl-C: the summary above is written; exit 130 (vecu.cli)
        from vecu.errors import Interrupted

        raise Interrupted(f"{s['duration_s']:.3g} s")
    return 0


def _reasons(skipped: dict[str, str]) -> str:
    """'reason: A, B; reason: C' (the summary JSON has each message's own)."""
    by: dict[str, list[str]] = {}
    for name, why in skipped.items():
        by.setdefault(why, []).append(name)
    return "; ".join(f"{why}: {', '.join(names)}" for why, names in by.items())
