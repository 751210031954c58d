"""The bus as one live node sees it: own echoes dropped and counted, receive errors counted,
and (for the ECU) the time from a trigger frame's arrival to the send of the frame it produced.

What counts as the node's own frame depends on the interface (ECHO_RULES):
- udp_multicast delivers every datagram to every socket of the group, the sender's own included,
  and python-can marks them all as received (is_rx stays True): a frame carrying a CAN ID the DBC
  gives this node as sender is its own echo.
- socketcan loops a socket's own frames back only with `receive_own_messages` (never set here),
  and python-can's is_rx there means "not originated on this host" (it reads MSG_DONTROUTE, which
  the kernel sets for a frame sent by *any* local socket): a plant in another process looks like
  is_rx=False. So nothing received on SocketCAN is this node's own, whatever is_rx says.
- virtual and the hardware interfaces echo only with `receive_own_messages` and mark the echo
  is_rx=False, which is trusted there.
Own echoes are dropped and counted as `own_echo`. A frame with one of this node's IDs that is not
its own (another sender: a second node with the same role, or a replay such as `canplayer` of a
recording that holds this node's frames) is dropped too - this node consumes none of its own IDs
- and counted apart as `foreign_own_id`: a set-up to look at, never an input error.
"""

from __future__ import annotations

import logging
import os
import socket
import sys
from dataclasses import dataclass
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
# interfaces read from a kernel socket whose receive buffer bounds how long a stall can last
# without losing frames (udp_multicast: ~256 datagrams by default; SocketCAN: ~200 frames)
SOCKET_INTERFACES = frozenset({"udp_multicast", "socketcan"})


@dataclass(frozen=True)
class EchoRule:
    """How an interface shows a node its own frames (see the module docstring)."""

    own_ids_echo: bool  # every frame with one of the node's IDs is its own echo
    is_rx_marks_echo: bool  # is_rx=False marks the node's own echo


ECHO_RULES: dict[str, EchoRule] = {
    "udp_multicast": EchoRule(own_ids_echo=True, is_rx_marks_echo=False),
    "socketcan": EchoRule(own_ids_echo=False, is_rx_marks_echo=False),
}
DEFAULT_ECHO_RULE = EchoRule(own_ids_echo=False, is_rx_marks_echo=True)  # virtual, hardware


def echo_rule(interface: str) -> EchoRule:
    return ECHO_RULES.get(interface, DEFAULT_ECHO_RULE)


# Linux's SO_RCVBUFFORCE (asm-generic/socket.h): Python's socket module does not export it
SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33 if sys.platform.startswith("linux") else None)
DEFAULT_RCVBUF_BYTES = 4 << 20


def enlarge_receive_buffer(bus: can.BusABC, size: int = DEFAULT_RCVBUF_BYTES) -> int | None:
    """Ask the kernel for a larger receive buffer on the bus's socket (udp_multicast queues only
    about 256 datagrams by default, a SocketCAN raw socket about 200 frames: a 60 ms stall at 4k
    frames/s would lose frames). Tries
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
        for opt in (SO_RCVBUFFORCE, socket.SO_RCVBUF):
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
                 latency: FrameLatency | None = None,
                 rcvbuf_bytes: int = DEFAULT_RCVBUF_BYTES) -> None:
        self.bus = bus
        self.interface = interface
        self.own_ids = frozenset(own_ids)
        self.latency = latency
        self.rule = echo_rule(interface)
        self._echo = 0
        self.foreign_own_id = 0  # frames with this node's IDs from another sender (dropped)
        if self.rule.own_ids_echo and hasattr(bus, "skip_keys"):
            # FastUdpMulticastBus: drops them before decoding
            bus.skip_keys = self.own_ids
        self.received = 0     # frames handed to the node
        self.rx_errors = 0    # frames the interface could not deliver (e.g. undecodable datagram)
        self.error_frames = 0  # error frames (SocketCAN: CAN_ERR_FLAG), handed to the node
        self.rx_by_id: dict[Key, int] = {}
        self.tx_by_id: dict[Key, int] = {}
        self.rcvbuf_bytes = (enlarge_receive_buffer(bus, rcvbuf_bytes)
                             if interface in SOCKET_INTERFACES else None)

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
        rx_marks_echo = self.rule.is_rx_marks_echo
        ids_echo = self.rule.own_ids_echo
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
            if msg.is_error_frame:  # a controller's report, no ID of anyone's: to the node
                self.error_frames += 1
                return msg
            key = (msg.arbitration_id, msg.is_extended_id)
            if key in own or (rx_marks_echo and not msg.is_rx):
                if ids_echo or (rx_marks_echo and not msg.is_rx):
                    self._echo += 1
                else:
                    self.foreign_own_id += 1
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

        return {"received": self.received, "own_echo": self.own_echo,
                "foreign_own_id": self.foreign_own_id, "rx_errors": self.rx_errors,
                "error_frames": self.error_frames,
                "rcvbuf_bytes": self.rcvbuf_bytes,
                "rx_by_id": named(self.rx_by_id), "tx_by_id": named(self.tx_by_id)}
