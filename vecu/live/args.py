"""Command-line options shared by `vecu plant` and `vecu ecu` (and the bus ones by `vecu inject`)."""

from __future__ import annotations

import argparse
import math

from vecu.live.options import LiveOptions


def positive_seconds(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds, got {text!r}") from None
    if not (v > 0 and math.isfinite(v)):
        raise argparse.ArgumentTypeError(f"expected a positive number of seconds, got {text!r}")
    return v


def add_bus_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--interface", help="python-can interface (default: python-can config, else virtual)")
    p.add_argument("--channel", help="python-can channel (default: config, else 'vecu'; "
                                     "udp_multicast: 239.74.163.2)")
    p.add_argument("--bitrate", type=int, help="bitrate for interfaces that need one")


def add_live_arguments(p: argparse.ArgumentParser) -> None:
    add_bus_arguments(p)
    p.add_argument("--duration", type=positive_seconds, metavar="S",
                   help="run S seconds (default: until Ctrl-C / SIGTERM)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--noise-scale", type=float, default=None, metavar="A",
                   help="process-noise scale alpha of the throttle model (1 = paper)")
    p.add_argument("--no-speed", action="store_true", help="leave out the speed part/function")
    p.add_argument("--no-steering", action="store_true", help="leave out the steering part/function")
    p.add_argument("--no-manifold", action="store_true", help="leave out the manifold part/function")
    p.add_argument("--log", metavar="FILE", help="record every frame on the bus; format by suffix "
                                                 "(.log .asc .blf ...), flushed on every exit")
    p.add_argument("--summary", metavar="FILE.json", help="write the JSON summary on exit")
    p.add_argument("--ready-file", metavar="FILE",
                   help="write FILE when the bus is open and set-up is done (for scripts)")
    p.add_argument("--spin-us", type=int, default=200, metavar="US",
                   help="busy-wait the last US microseconds before each deadline (default 200)")
    status = p.add_mutually_exclusive_group()
    status.add_argument("--status", dest="status", action="store_true", default=None,
                        help="show the status panel on stderr (default: when it is a terminal)")
    status.add_argument("--no-status", dest="status", action="store_false",
                        help="never show the status panel")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")


def live_options(args: argparse.Namespace, role: str) -> LiveOptions:
    return LiveOptions(role=role, duration_s=args.duration, interface=args.interface,
                       channel=args.channel, bitrate=args.bitrate, log_path=args.log,
                       summary_path=args.summary, ready_file=args.ready_file,
                       spin_us=max(0, args.spin_us), status=args.status)
