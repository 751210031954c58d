"""Command-line options shared by `vecu plant` and `vecu ecu` (the process ones by `vecu gateway`,
the bus ones by `vecu inject`)."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from vecu import argtypes
from vecu.functions import OPTIONAL

if TYPE_CHECKING:
    from vecu.live.options import LiveOptions


def add_bus_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--interface", help="python-can interface (default: python-can config, else virtual)")
    p.add_argument("--channel", help="python-can channel (default: config, else 'vecu'; "
                                     "udp_multicast: 239.74.163.2)")
    p.add_argument("--bitrate", type=argtypes.positive_int, help="bitrate for interfaces that need one")


def add_duration_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--duration", type=argtypes.live_seconds, metavar="S",
                   help=f"run S seconds, {argtypes.TICK_S:g}..{argtypes.RUN_MAX_S:g} (default: until "
                        "Ctrl-C / SIGTERM)")


def add_live_arguments(p: argparse.ArgumentParser) -> None:
    add_bus_arguments(p)
    add_duration_argument(p)
    p.add_argument("--seed", type=argtypes.seed, default=0, help="random seed, 0..2**63-1 (default 0)")
    p.add_argument("--noise-scale", type=argtypes.noise_scale, default=None, metavar="A",
                   help="process-noise scale alpha of the throttle model (1 = paper; "
                        f"0..{argtypes.NOISE_SCALE_MAX:g})")
    add_function_switches(p)
    add_process_arguments(p)


def add_process_arguments(p: argparse.ArgumentParser) -> None:
    """What every live process takes (`vecu plant`, `vecu ecu`, `vecu gateway`): its log,
    summary, ready file, pacing, status panel, receive filter and buffer, real-time, quiet."""
    p.add_argument("--log", type=argtypes.out_log, metavar="FILE", help="record every frame on the bus; format by suffix "
                                                 "(.log .asc .blf ...), flushed on every exit")
    p.add_argument("--summary", type=argtypes.out_file, metavar="FILE.json", help="write the JSON summary on exit")
    p.add_argument("--ready-file", type=argtypes.out_file, metavar="FILE",
                   help="write FILE when the bus is open and set-up is done (for scripts)")
    # default: vecu.live.options.DEFAULT_SPIN_US (not imported: the parser stays light)
    p.add_argument("--spin-us", type=argtypes.tick_us, default=50, metavar="US",
                   help="busy-wait the last US microseconds before each deadline, 0..1000 "
                        "(default 50)")
    status = p.add_mutually_exclusive_group()
    status.add_argument("--status", dest="status", action="store_true", default=None,
                        help="show the status panel on stderr (default: when it is a terminal)")
    status.add_argument("--no-status", dest="status", action="store_false",
                        help="never show the status panel")
    p.add_argument("--rx-filter", action="store_true",
                   help="receive only the CAN IDs this node consumes (kernel filters on SocketCAN: "
                        "other traffic never reaches the process, and is not counted)")
    p.add_argument("--rx-buffer-mb", type=argtypes.bounded(0.0625, 1024.0, unit="MiB"),
                   default=4.0, metavar="MB",
                   help="kernel receive buffer to ask for on socketcan / udp_multicast, in MiB: "
                        "how long the node may stall without losing frames (default 4: ~4000 "
                        "frames; above net.core.rmem_max needs CAP_NET_ADMIN)")
    p.add_argument("--realtime", action="store_true",
                   help="SCHED_FIFO and locked memory where the OS permits (CAP_SYS_NICE / "
                        "rtprio and memlock limits); a one-line note for what it refuses")
    p.add_argument("--cpu", type=argtypes.bounded(0, 4095, integer=True), metavar="N",
                   help="pin the process to CPU N (with --realtime: a core of its own)")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")


def add_function_switches(p: argparse.ArgumentParser,
                          help_text: str = "leave out the {} part/function") -> None:
    """--no-NAME for each ECU function a run may leave out (vecu.functions.OPTIONAL)."""
    for name in OPTIONAL:
        p.add_argument(f"--no-{name}", action="store_true", help=help_text.format(name))


def function_switches(args: argparse.Namespace) -> dict[str, bool]:
    """RunConfig's switches from the --no-NAME options: {name: enabled}."""
    return {name: not getattr(args, f"no_{name}") for name in OPTIONAL}


def live_options(args: argparse.Namespace, role: str) -> LiveOptions:
    from vecu.live.options import LiveOptions  # here: parsing needs no python-can

    return LiveOptions(role=role, duration_s=args.duration, interface=args.interface,
                       channel=args.channel, bitrate=args.bitrate, log_path=args.log,
                       summary_path=args.summary, ready_file=args.ready_file,
                       spin_us=max(0, args.spin_us), status=args.status,
                       rx_filter=args.rx_filter,
                       rx_buffer_bytes=round(args.rx_buffer_mb * (1 << 20)),
                       realtime=args.realtime, cpu=args.cpu)
