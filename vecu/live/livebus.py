"""The bus as one live node sees it: own echoes dropped and counted, receive errors counted,
and (for the ECU) the time from a trigger frame's arrival to the send of the frame it produced.

Some interfaces deliver a node's own frames back to it: udp_multicast always (every socket in
the group gets every datagram, and python-can marks them as received: is_rx stays True), virtual
and socketcan when receive_own_messages is set (those mark them is_rx=False). A live node drops
every frame that is marked is_rx=False or carries a CAN ID that the DBC gives this node as sender,
and counts it as `own_echo`. On a bus that does not echo, a non-zero own_echo therefore means
another node sends one of this node's IDs: a bus configuration error worth looking at.
"""

from __future__ import annotations

import logging
import os
import socket
from typing import Any

import can

from vecu.clock import wall_time
from vecu.codec import DbcCodec
from vecu.stats import DurationHistogram

log = logging.getLogger(__name__)

MAX_LOGGED_RX_ERRORS = 20
Key = tuple[int, bool]

# interfaces whose received frames carry the arrival time (kernel receive timestamp)
ARRIVAL_TIMESTAMP_INTERFACES = frozenset({"udp_multicast", "socketcan"})


def enlarge_receive_buffer(bus: can.BusABC, size: int = 4 << 20) -> int | None:
    """Ask the kernel for a larger receive buffer on the bus's socket (udp_multicast queues only
    about 256 datagrams by default: a 60 ms stall at 4k frames/s would lose frames). Tries
    SO_RCVBUFFORCE (needs CAP_NET_ADMIN), then SO_RCVBUF (capped by net.core.rmem_max); returns
    the size the kernel reports, or None for buses without a socket."""
    try:
        fd = bus.fileno()
    except (NotImplementedError, AttributeError, OSError):
        return None
    if not isinstance(fd, int) or fd < 0:
        return None
    try:
        sock = socket.socket(fileno=os.dup(fd))
    except OSError:
        return None
    with sock:
        for opt in (getattr(socket, "SO_RCVBUFFORCE", None), socket.SO_RCVBUF):
            if opt is None:
                continue
            try:
                sock.setsockopt(socket.SOL_SOCKET, opt, size)
                break
            except OSError:
                continue
        return sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)


def sent_ids(codec: DbcCodec, node: str) -> set[Key]:
    """CAN IDs the DBC(s) give `node` (e.g. PLANT, VECU, TESTER) as a sender."""
    return codec.sent_by(node)


class FrameLatency:
    """Trigger frame in -> response frame out, for one (trigger, response) pair of CAN IDs.

    'In' is the trigger frame's receive timestamp when the interface gives the arrival time
    (kernel timestamp on udp_multicast and socketcan), else the moment the node took it from
    the bus; 'out' is the return of send() for the next response frame. Both on the system's
    real-time clock (wall_time), like the kernel timestamps.
    """

    def __init__(self, trigger: Key, response: Key, arrival_timestamps: bool) -> None:
        self.trigger = trigger
        self.response = response
        self.arrival_timestamps = arrival_timestamps
        self.hist = DurationHistogram()
        self._pending_s: float | None = None

    def on_rx(self, msg: can.Message) -> None:
        self._pending_s = msg.timestamp if self.arrival_timestamps else wall_time()

    def on_tx(self) -> None:
        if self._pending_s is not None:
            self.hist.record(int((wall_time() - self._pending_s) * 1e9))
            self._pending_s = None


class LiveBus:
    """Wraps a python-can bus for one node: recv() never returns the node's own frames and never
    raises; send() is python-can's. Counts frames per CAN ID in both directions."""

    def __init__(self, bus: can.BusABC, own_ids: set[Key], interface: str,
                 latency: FrameLatency | None = None) -> None:
        self.bus = bus
        self.interface = interface
        self.own_ids = frozenset(own_ids)
        self.latency = latency
        self._echo = 0
        if hasattr(bus, "skip_keys"):  # FastUdpMulticastBus: drops them before decoding
            bus.skip_keys = self.own_ids
        self.received = 0     # frames handed to the node
        self.rx_errors = 0    # frames the interface could not deliver (e.g. undecodable datagram)
        self.rx_by_id: dict[Key, int] = {}
        self.tx_by_id: dict[Key, int] = {}
        self.rcvbuf_bytes = enlarge_receive_buffer(bus) if interface == "udp_multicast" else None

    @property
    def own_echo(self) -> int:
        """Own frames dropped (here, or already by the bus: FastUdpMulticastBus.skipped)."""
        return self._echo + getattr(self.bus, "skipped", 0)

    @property
    def channel_info(self) -> str:
        return self.bus.channel_info

    def recv(self, timeout: float | None = None) -> can.Message | None:
        recv = self.bus.recv
        own = self.own_ids
        while True:
            try:
                msg = recv(timeout)
            except (can.CanError, ValueError, TypeError) as exc:
                self.rx_errors += 1
                if self.rx_errors <= MAX_LOGGED_RX_ERRORS:
                    log.warning("receive error on %s: %s", self.interface, exc)
                return None  # end this drain; the next one tries again
            if msg is None:
                return None
            key = (msg.arbitration_id, msg.is_extended_id)
            if not msg.is_rx or key in own:
                self._echo += 1
                timeout = 0.0
                continue
            self.received += 1
            by_id = self.rx_by_id
            by_id[key] = by_id.get(key, 0) + 1
            lat = self.latency
            if lat is not None and key == lat.trigger:
                lat.on_rx(msg)
            return msg

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.bus.send(msg, timeout)
        key = (msg.arbitration_id, msg.is_extended_id)
        by_id = self.tx_by_id
        by_id[key] = by_id.get(key, 0) + 1
        lat = self.latency
        if lat is not None and key == lat.response:
            lat.on_tx()

    def shutdown(self) -> None:
        self.bus.shutdown()

    def counts(self, codec: DbcCodec) -> dict[str, Any]:
        def named(d: dict[Key, int]) -> dict[str, int]:
            out = {}
            for key, n in sorted(d.items()):
                fc = codec.by_id.get(key)
                out[fc.name if fc else f"0x{key[0]:X}"] = n
            return out

        return {"received": self.received, "own_echo": self.own_echo, "rx_errors": self.rx_errors,
                "rcvbuf_bytes": self.rcvbuf_bytes,
                "rx_by_id": named(self.rx_by_id), "tx_by_id": named(self.tx_by_id)}
