"""Options of a live process and the bus configuration they resolve to (cheap to import: the
`vecu` command line builds its parser from these without loading numpy or cantools)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from vecu.bus import resolve_bus_config

UDP_DEFAULT_GROUP = "239.74.163.2"  # python-can's IPv4 group (its IPv6 default fails on lo)
# busy-wait before each 1 ms deadline: 200 us cost a live node a fifth of a core, which a small
# machine's other processes (a logger) missed; with the timer slack at 1 us (LiveProcess) the
# sleep itself wakes within ~50 us, so 50 us keeps the ticks on time (docs/live.md)
DEFAULT_SPIN_US = 50


@dataclass(frozen=True)
class LiveOptions:
    """Command-line choices common to the live processes."""

    role: str                       # "plant" or "ecu"
    duration_s: float | None = None  # None: until SIGINT / SIGTERM
    interface: str | None = None
    channel: str | None = None
    bitrate: int | None = None
    log_path: str | None = None
    summary_path: str | None = None
    ready_file: str | None = None
    spin_us: int = DEFAULT_SPIN_US  # final busy-wait before each deadline
    status: bool | None = None      # None: when stderr is a terminal
    rx_filter: bool = False         # receive only the IDs the node consumes (set_filters)
    rx_buffer_bytes: int = 4 << 20  # the kernel receive buffer asked for (socket interfaces)
    realtime: bool = False          # SCHED_FIFO and locked memory where permitted
    cpu: int | None = None          # pin to this CPU


def bus_config(opts: LiveOptions) -> dict[str, Any]:
    """python-can configuration as open_bus resolves it; udp_multicast without a channel gets
    the IPv4 group."""
    cfg = resolve_bus_config(opts.interface, opts.channel, bitrate=opts.bitrate)
    if cfg["interface"] == "udp_multicast" and opts.channel is None and cfg["channel"] == "vecu":
        cfg["channel"] = UDP_DEFAULT_GROUP
    return cfg
