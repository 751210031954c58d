"""Bus access, only through python-can; the one module that opens (or defines) a bus.

open_bus() takes python-can's own arguments (interface, channel, bitrate, anything else the
interface accepts) and honours python-can configuration (CAN_INTERFACE / CAN_CHANNEL environment
variables, ~/.canrc, can.ini or an explicit config file). With nothing configured anywhere it opens
the in-process `virtual` bus on channel "vecu"; `virtual` and `udp_multicast` buses come with a
cheaper poll (FastVirtualBus, FastUdpMulticastBus). Also here: python-can's own VirtualBus as a
benchmark baseline (open_baseline_virtual_bus), the in-process lane of simulated-clock runs
(SimLane: python-can Message objects shared between the nodes, copies only for edges such as a
log writer), the replay sink (SinkBus) and BusNode, the counted, never-raising sender the plant
and the ECU stand on, with the two guards every node shares: bounded receive work per tick
(RxBudget: a flood cannot stall a tick) and one boundary for command handlers (a client's request
that makes a handler raise is counted and logged once, never raised out of the tick).
"""

from __future__ import annotations

import logging
import queue
import socket
import struct
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import can
from can.interfaces.udp_multicast import UdpMulticastBus
from can.interfaces.virtual import VirtualBus
from can.typechecking import CanFilter

from vecu.can_message import Values, message
from vecu.clock import wall_time
from vecu.errors import UnavailableError

DEFAULT_INTERFACE = "virtual"
DEFAULT_CHANNEL = "vecu"


class BusOpenError(UnavailableError):
    """The requested bus cannot be opened; the message says which and why."""


def resolve_bus_config(interface: str | None = None, channel: Any = None,
                       config_file: str | None = None, **kwargs: Any) -> dict[str, Any]:
    """Merge explicit arguments with python-can's config sources; fall back to virtual/vecu."""
    given = {k: v for k, v in {"interface": interface, "channel": channel, **kwargs}.items()
             if v is not None}
    try:
        cfg = dict(can.util.load_config(path=config_file, config=given))
    except can.CanInterfaceNotImplementedError as exc:
        if interface is not None:
            raise BusOpenError(f"unknown python-can interface {interface!r}: {exc}") from exc
        cfg = dict(given)
    if not cfg.get("interface"):
        cfg["interface"] = DEFAULT_INTERFACE
    if cfg.get("channel") is None:
        cfg["channel"] = DEFAULT_CHANNEL
    if cfg["interface"] == "virtual":
        # keep the sender's (possibly simulated) timestamps on the receiving side
        cfg.setdefault("preserve_timestamps", True)
    return cfg


class FastVirtualBus(VirtualBus):
    """python-can's VirtualBus with a cheaper per-receiver copy in send().

    VirtualBus.send() gives every receiver a copy.deepcopy() of the frame (about 10 us, half of a
    send/recv pair); this copies the same fields explicitly, with its own data buffer, so
    receivers stay isolated from each other and from the sender. Channels, queues, timestamps and
    is_rx/channel marking are python-can's, so plain `virtual` buses in the same process share
    channels with it. Used by open_bus() whenever interface="virtual".
    """

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """BusABC.recv; a poll (timeout 0) without software filters goes straight to the queue
        (no clock reads, no per-frame debug log call: ~0.4 us instead of ~2.5 us)."""
        if timeout == 0 and self._filters is None:
            self._check_if_open()
            q = self.queue
            if not q.queue:  # empty: no exception round trip (a racing put is seen next poll)
                return None
            try:
                return q.get_nowait()
            except queue.Empty:
                return None
        return super().recv(timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if timeout != 0:
            return super()._recv_internal(timeout)
        self._check_if_open()
        try:  # a poll: skip the timed-wait machinery of queue.get(timeout=0)
            return self.queue.get_nowait(), False
        except queue.Empty:
            return None, False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._check_if_open()
        timestamp = msg.timestamp if self.preserve_timestamps else wall_time()
        all_sent = True
        for bus_queue in self.channel:
            own = bus_queue is self.queue
            if own and not self.receive_own_messages:
                continue
            copy = can.Message(
                timestamp=timestamp, arbitration_id=msg.arbitration_id,
                is_extended_id=msg.is_extended_id, is_remote_frame=msg.is_remote_frame,
                is_error_frame=msg.is_error_frame, channel=self.channel_id, dlc=msg.dlc,
                data=bytearray(msg.data), is_fd=msg.is_fd, is_rx=not own,
                bitrate_switch=msg.bitrate_switch, error_state_indicator=msg.error_state_indicator,
                check=False)
            try:
                bus_queue.put(copy, block=True, timeout=timeout)
            except queue.Full:
                all_sent = False
        if not all_sent:
            raise can.CanOperationError("Could not send message to one or more recipients")


Key = tuple[int, bool]  # (CAN ID, extended)


class FastUdpMulticastBus(UdpMulticastBus):
    """python-can's udp_multicast bus with a cheaper poll.

    BusABC.recv(0) costs a select() per datagram, the filter loop and python-can's unpacking
    (~15 us a frame). A poll (timeout 0, no software filters) here reads the socket with
    MSG_DONTWAIT instead of select() and decodes the datagram as python-can does (msgpack, the
    kernel receive timestamp, a checked can.Message). A frame whose (ID, extended) is in
    `skip_keys` - set by the owner to its own IDs, which this interface echoes to every socket
    of the group - is dropped after the msgpack decode, before a can.Message is built, and
    counted in `skipped`. Blocking waits, filters, or a python-can whose internals differ take
    python-can's own recv. Used by open_bus() whenever interface="udp_multicast"."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.skip_keys: frozenset[Key] = frozenset()
        self.skipped = 0
        mc = getattr(self, "_multicast", None)
        sock = getattr(mc, "_socket", None)
        self._sock = sock if isinstance(sock, socket.socket) else None
        self._bufsize = int(getattr(mc, "max_buffer", 4096))
        self._anc_size = (int(getattr(mc, "received_ancillary_buffer_size", 0))
                          if getattr(mc, "timestamp_nanosecond", False) else 0)
        self._ts_struct = str(getattr(mc, "received_timestamp_struct", "@ll"))
        self._no_fd = getattr(self, "_can_protocol", None) is not can.CanProtocol.CAN_FD
        try:
            import msgpack
            self._unpackb = msgpack.unpackb
        except ImportError:
            self._sock = None

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if timeout == 0 and self._sock is not None and self._filters is None:
            return self._poll()
        return super().recv(timeout)

    def _poll(self) -> can.Message | None:
        sock, anc_size = self._sock, self._anc_size
        while True:
            try:
                if anc_size:
                    data, anc, _, _ = sock.recvmsg(self._bufsize, anc_size, socket.MSG_DONTWAIT)
                else:
                    data, _ = sock.recvfrom(self._bufsize, socket.MSG_DONTWAIT)
                    anc = None
            except (BlockingIOError, InterruptedError):
                return None
            except OSError as exc:
                raise can.CanOperationError(f"failed to receive from the socket: {exc}") from exc
            try:
                fields = self._unpackb(data, raw=False)
                if (fields["arbitration_id"], fields["is_extended_id"]) in self.skip_keys:
                    self.skipped += 1
                    continue
                if anc:
                    sec, nsec = struct.unpack(self._ts_struct, anc[0][2])
                    fields["timestamp"] = sec + nsec * 1.0e-9
                else:
                    fields["timestamp"] = wall_time()
                msg = can.Message(check=True, **fields)
            except Exception as exc:  # an odd datagram: what python-can raises for it
                raise can.CanOperationError("could not unpack received message") from exc
            if msg.is_fd and self._no_fd:
                continue
            return msg


CANFD_MTU = 72  # struct canfd_frame: a SocketCAN interface with this MTU carries CAN FD


def socketcan_mtu(channel: Any) -> int | None:
    """The MTU of a SocketCAN interface (16: classic CAN, 72: CAN FD), None if unknown."""
    try:
        with open(f"/sys/class/net/{channel}/mtu", encoding="ascii") as f:
            return int(f.read().strip())
    except (OSError, ValueError):
        return None


def receive_filters(keys: Iterable[Key]) -> list[CanFilter]:
    """python-can filters (kernel filters on SocketCAN) passing exactly these (ID, extended)."""
    return [{"can_id": i, "can_mask": 0x1FFFFFFF if ext else 0x7FF, "extended": ext}
            for i, ext in sorted(keys)]


def open_bus(interface: str | None = None, channel: Any = None,
             config_file: str | None = None, **kwargs: Any) -> can.BusABC:
    """Open a python-can bus; errors become one clear BusOpenError line. A SocketCAN interface
    whose MTU allows CAN FD is opened with fd=True (unless the configuration says otherwise), so
    FD frames on it reach vecu instead of being held back by the kernel."""
    cfg = resolve_bus_config(interface, channel, config_file, **kwargs)
    if cfg["interface"] == "socketcan" and "fd" not in cfg:
        cfg["fd"] = socketcan_mtu(cfg["channel"]) == CANFD_MTU
    try:
        args = {k: v for k, v in cfg.items() if k != "interface"}
        if cfg["interface"] == "virtual":
            return FastVirtualBus(**args)
        if cfg["interface"] == "udp_multicast":
            return FastUdpMulticastBus(**args)
        return can.Bus(**cfg)
    except (can.CanError, OSError, ImportError, ValueError, TypeError) as exc:
        raise BusOpenError(
            f"cannot open bus interface={cfg['interface']!r} channel={cfg['channel']!r}: {exc}"
        ) from exc


def open_baseline_virtual_bus(channel: str) -> can.BusABC:
    """python-can's own VirtualBus (what open_bus() improves on), timestamps preserved: the
    baseline of `vecu bench --only bus`."""
    return can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)


class SinkBus(can.BusABC):
    """A bus that receives nothing and drops what is sent (the fast-mode replay ECU's bus:
    frames are handed in; the ECU hands what it sends to its estimate sinks)."""

    def __init__(self, channel: str = "sink") -> None:
        super().__init__(channel=channel)
        self.channel_info = "vecu sink"

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        pass

    def _recv_internal(self, timeout: float | None) -> tuple[None, bool]:
        return None, False

    def recv(self, timeout: float | None = None) -> None:  # type: ignore[override]  # never a frame
        return None


def virtual_channel_in_use(channel: Any) -> bool:
    """True when a python-can `virtual` bus of this process is open on `channel` (a user's
    listener, another run): a run on the simulated clock then keeps python-can's channel."""
    from can.interfaces import virtual

    with virtual.channels_lock:
        return bool(virtual.channels.get(channel))


class SimLane:
    """The in-process lane of a run on the simulated clock (one thread, one process): the buses
    of the plant, the ECU, a tester and a recorder, without python-can's per-receiver copies and
    locked queues. A frame sent is handed to every other endpoint's plain deque; receivers on the
    lane share the sender's Message and only read it (nothing in vecu changes a frame it has
    received or sent). An `edge` endpoint (a log writer, a user's listener) gets its own copy, made
    exactly as FastVirtualBus makes one (channel, is_rx, own data buffer), so what it sees and
    writes is what it would get from python-can's virtual bus. Live runs never use the lane."""

    def __init__(self, channel: str = DEFAULT_CHANNEL) -> None:
        self.channel = channel
        self.endpoints: list[LaneBus] = []

    def rewire(self) -> None:
        """After an endpoint joined or left: each endpoint's receivers, as send() uses them."""
        for sender in self.endpoints:
            own = sender.receive_own_messages
            sender._shared = [ep.queue.append for ep in self.endpoints
                              if not ep.edge and (ep is not sender or own)]
            sender._edges = [(ep.queue.append, ep is not sender) for ep in self.endpoints
                             if ep.edge and (ep is not sender or own)]

    def bus(self, *, edge: bool = False, receive_own_messages: bool = False) -> LaneBus:
        """A new endpoint on this lane (a python-can bus)."""
        return LaneBus(self, edge=edge, receive_own_messages=receive_own_messages)


class LaneBus(can.BusABC):
    """One endpoint of a SimLane: send() appends to the other endpoints' deques, recv() pops its
    own (never waits: on the simulated clock nothing arrives while a node waits)."""

    def __init__(self, lane: SimLane, *, edge: bool = False,
                 receive_own_messages: bool = False) -> None:
        super().__init__(channel=lane.channel)
        self.channel_info = f"vecu lane {lane.channel}"
        self.lane = lane
        self.edge = edge
        self.receive_own_messages = receive_own_messages
        self.queue: deque[can.Message] = deque()
        # receivers (SimLane.rewire): the deques that share the frame, and the edges' (deque,
        # is_rx) that get a copy
        self._shared: list[Callable[[can.Message], None]] = []
        self._edges: list[tuple[Callable[[can.Message], None], bool]] = []
        lane.endpoints.append(self)
        lane.rewire()

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        for append in self._shared:
            append(msg)
        for append, is_rx in self._edges:
            append(message(
                msg.timestamp, msg.arbitration_id, msg.is_extended_id, bytearray(msg.data),
                msg.is_fd, self.lane.channel, is_rx, msg.is_remote_frame,
                msg.is_error_frame, msg.dlc, msg.bitrate_switch, msg.error_state_indicator))

    def recv(self, timeout: float | None = None) -> can.Message | None:
        q = self.queue
        while q:
            msg = q.popleft()
            if self._filters is None or self._matches_filters(msg):
                return msg
        return None

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        q = self.queue
        return (q.popleft() if q else None), False

    def shutdown(self) -> None:
        if self in self.lane.endpoints:
            self.lane.endpoints.remove(self)
            self.lane.rewire()
        self.queue.clear()
        super().shutdown()


class MergedEdges(can.BusABC):
    """The log endpoints (edges) of several lanes read as one bus, as a log writer of a
    multi-bus run needs: recv() gives the earliest frame of any of them (ties: the first
    lane's), each frame keeping its lane's channel, or with `numbered` the lane's place, 1, 2, …
    (log formats whose channels are numbers: ASC, BLF)."""

    def __init__(self, edges: list[LaneBus], numbered: bool = False) -> None:
        super().__init__(channel="+".join(e.lane.channel for e in edges))
        self.edges = edges
        self._number = {e.lane.channel: i + 1 for i, e in enumerate(edges)} if numbered else None

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        raise can.CanOperationError("merged log endpoints only listen")

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        best = None
        for edge in self.edges:
            if edge.queue and (best is None or edge.queue[0].timestamp < best.queue[0].timestamp):
                best = edge
        if best is None:
            return None, False
        msg = best.queue.popleft()  # an edge's own copy: its channel may be renamed
        if self._number is not None:
            msg.channel = self._number[str(msg.channel)]
        return msg, False


MAX_LOGGED_SEND_ERRORS = 20


@dataclass(frozen=True)
class RxBudget:
    """A node's receive work per tick (docs/live.md 'Floods'): the first `frames_per_tick`
    frames read are handled and whatever else came stays in the bus (socket or queue) for the
    next tick, so a backlog after a host stall is caught up without loss. Only once
    `catch_up_ticks` ticks in a row ended with frames left (a flood, not a stall) are the next
    `shed_per_tick` frames of each such tick read and shed (counted, not decoded; a diagnostic
    request among them still reaches its server). 64 is ~3x what a saturated 1 Mbit/s classic
    CAN bus carries per 1 ms (~21 frames of 47 bits); the worst tick then costs ~0.5 ms."""

    frames_per_tick: int = field(default=64, metadata={"bounds": (1, 65535)})
    shed_per_tick: int = field(default=192, metadata={"bounds": (0, 1_000_000)})
    catch_up_ticks: int = field(default=20, metadata={"bounds": (0, 1_000_000)})


class EstimateSink(Protocol):
    """Where a node's frames go besides the bus (the ECU's estimate sinks; trace replay: the
    truth scorer and the `--out` writer): every frame the node sends, as it goes on the bus,
    with the values it carries, so that nothing decodes a frame the node has just encoded."""

    def on_estimate(self, values: Values | None, msg: can.Message, t_ns: int) -> None:
        """msg sent at the node's time t_ns; values: the signals it carries in the DBC's order
        as its decoder would give them (a codec framer's second result), None for a frame not
        made from values (ECU_Status, ECU_Diag, a diagnostic response)."""


class BusNode:
    """Base of the plant, ECU and restbus nodes: send() counts frames and failures instead of
    raising; shed() bounds a tick's receive work; handler_failed() is the boundary a command
    handler's error stops at."""

    def __init__(self, bus: can.BusABC, name: str, rx_budget: RxBudget = RxBudget(),
                 sinks: Sequence[EstimateSink] = ()) -> None:
        """sinks: each takes every frame sent, in order, at the node's time `now_ns`."""
        self.bus = bus
        self.node_name = name
        self.frames_sent = 0
        self.send_errors = 0
        self.sinks = tuple(sinks)
        self.now_ns = 0  # the time of what the node is handling (a subclass keeps it)
        self.rx_budget = rx_budget
        self.rx_shed = 0  # frames read past rx_budget.frames_per_tick and dropped undecoded
        self.rx_peak = 0  # the most frames read in one tick (at most the budget's two parts)
        self.rx_saturated = 0  # ticks in a row that ended with frames left in the bus
        self.handler_errors: dict[str, int] = {}  # by handler: requests whose handling raised
        self._log = logging.getLogger(f"vecu.{name}")

    def shed(self, keep: Callable[[can.Message], bool] | None = None) -> None:
        """After a tick's `frames_per_tick` frames: within `catch_up_ticks` such ticks in a row
        nothing more (the rest waits in the bus); past them read up to `shed_per_tick` more and
        drop them, counted in rx_shed, except those `keep(msg)` takes (True). Either way the
        tick's receive work is bounded whatever arrives. The first shed is logged. A node sets
        rx_saturated = 0 in a tick that emptied its bus."""
        budget = self.rx_budget
        self.rx_saturated += 1
        if self.rx_saturated <= budget.catch_up_ticks:
            self.rx_peak = max(self.rx_peak, budget.frames_per_tick)
            return
        recv = self.bus.recv
        before = self.rx_shed
        n = 0
        for n in range(self.rx_budget.shed_per_tick):  # noqa: B007 (n: how many were read)
            msg = recv(0.0)
            if msg is None:
                break
            if keep is None or not keep(msg):
                self.rx_shed += 1
        else:
            n = self.rx_budget.shed_per_tick
        self.rx_peak = max(self.rx_peak, self.rx_budget.frames_per_tick + n)
        if before == 0 and self.rx_shed:
            self._log.warning("%s: receive flood: frames beyond %d per tick are shed and counted "
                              "(rx_shed)", self.node_name, self.rx_budget.frames_per_tick)

    def handler_failed(self, handler: str, exc: BaseException) -> None:
        """The boundary of a command handler or periodic sampler (XCP, UDS, FI / RB commands):
        its error is counted by handler and logged once with its traceback; the node goes on
        ticking. Only what a client can provoke goes through here; a function's own error is a
        bug and propagates. Counted as "handler: ExceptionType"."""
        kind = f"{handler}: {type(exc).__name__}"
        n = self.handler_errors.get(kind, 0) + 1
        self.handler_errors[kind] = n
        if n == 1:
            self._log.error("%s: %s failed (counted in handler_errors; further ones not logged)",
                            self.node_name, kind, exc_info=exc)

    def send(self, msg: can.Message, values: Values | None = None) -> bool:
        """Send one frame; True when the bus took it (a failure is counted and logged). Then
        each sink takes it (values: what it carries, None for a frame not made from values)."""
        try:
            self.bus.send(msg)
            self.frames_sent += 1
            if self.sinks:
                for sink in self.sinks:
                    sink.on_estimate(values, msg, self.now_ns)
            return True
        except can.CanError as exc:
            self.send_errors += 1
            if self.send_errors <= MAX_LOGGED_SEND_ERRORS:
                self._log.warning("%s: send failed for 0x%X: %s", self.node_name,
                                  msg.arbitration_id, exc)
            return False
