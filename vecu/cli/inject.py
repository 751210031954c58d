"""`vecu inject`: send one FI_Command frame to a running plant (fault on, or 'clear')."""

from __future__ import annotations

import argparse
import math

from vecu import argtypes
from vecu.errors import BadArgumentError, UnavailableError
from vecu.live.args import add_bus_arguments


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("inject", help="send a fault command (FI_Command) to a running plant",
                       description="Send one FI_Command frame on the bus; the plant applies it to "
                                   "the sensor at its next 1 ms tick.")
    add_bus_arguments(p)
    p.add_argument("--target", required=True, help="sensor: tps or swa")
    p.add_argument("--kind", required=True,
                   help="dead, short_supply, stuck, frames_stop, offset, gain, noise, or clear")
    p.add_argument("--value", type=argtypes.finite, metavar="X",
                   help="offset (V for TPS, deg for SWA; default 0.5), gain G in [0,1] (0.5), "
                        "noise sigma (0.3)")
    p.add_argument("--at", type=argtypes.bounded(0.0, 86_400.0), default=0.0, metavar="S",
                   help="send S seconds after this command starts (default: at once)")
    p.add_argument("--restbus", nargs="+", metavar="DB",
                   help="disturb a running `vecu restbus` instead: --target MESSAGE[.SIGNAL] of "
                        "these databases, --kind a restbus disturbance or clear (docs/restbus.md)")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.set_defaults(func=main)


def command_values(target: str, kind: str, value: float | None) -> dict[str, float]:
    """FI_Command signal values; raises BadArgumentError with a clear message on bad input."""
    import numpy as np

    from vecu.codec import DbcCodec
    from vecu.faults import (
        FaultInjector,
        FaultKind,
        FaultTarget,
        parse_kind,
    )

    tgt = FaultTarget.__members__.get(target.strip().upper())
    if tgt is None:
        raise BadArgumentError(f"unknown target {target!r} (known: "
                               f"{', '.join(t.name.lower() for t in FaultTarget)})")
    k = FaultKind.CLEAR if kind.strip().lower() == "clear" else parse_kind(kind)
    if value is not None and not (math.isfinite(value) and -32.768 <= value <= 32.767):
        raise BadArgumentError(f"--value must be within -32.768..32.767, got {value}")
    if k != FaultKind.CLEAR:  # the plant's own checks, signal and frame faults alike
        FaultInjector(np.random.default_rng(0), DbcCodec()).check(tgt, k, value)
    if value is None:
        value = k.default
    return {"FI_Target": int(tgt), "FI_Kind": int(k), "FI_Value": value}


def main(args: argparse.Namespace) -> int:
    import can

    from vecu.bus import open_bus
    from vecu.clock import NS_PER_S, WallClock
    from vecu.codec import DbcCodec
    from vecu.live.options import LiveOptions, bus_config

    if not (math.isfinite(args.at) and 0.0 <= args.at <= 86_400.0):
        raise BadArgumentError(f"--at: expected 0..86400 s, got {args.at}")
    if args.restbus:  # a running `vecu restbus` (RB_Command, docs/restbus.md)
        from vecu.restbus.commands import command_for
        frame = command_for(tuple(args.restbus), args.target, args.kind.strip().lower(),
                            args.value)
    else:
        frame = DbcCodec()["FI_Command"].frame(
            command_values(args.target, args.kind, args.value), 0.0)
    cfg = bus_config(LiveOptions(role="inject", interface=args.interface,
                                 channel=args.channel, bitrate=args.bitrate))
    bus = open_bus(**cfg)
    try:
        clock = WallClock()
        clock.start()
        clock.wait_until(round(args.at * NS_PER_S))
        try:
            bus.send(frame, timeout=1.0)
        except (can.CanError, OSError) as exc:  # python-can's errors; some interfaces: OSError
            raise UnavailableError(f"cannot send {'RB' if args.restbus else 'FI'}_Command on "
                                   f"{cfg['interface']} {cfg['channel']}: {exc}") from exc
    finally:
        bus.shutdown()
    if not args.quiet:
        print(f"vecu inject: sent {'RB' if args.restbus else 'FI'}_Command {args.target} "
              f"{args.kind}"
              f"{'' if args.value is None else f' {args.value:g}'} on {cfg['interface']} "
              f"{cfg['channel']}")
    return 0
