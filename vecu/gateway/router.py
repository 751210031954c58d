"""Routing diagnostic messages into CAN (ISO 13400-2 clause 7.8 / 2019: 7.9, the DoIP entity
as a gateway): a tester's UDS request for a logical address goes through that ECU's ISO-TP
channel (ISO 15765-2, can-isotp on vecu's clock: vecu.uds.transport) and each response comes
back to the tester with the ECU's logical address as its source.

- Physical: one request in flight per channel (a second one, from any tester, is refused with
  NACK 0x06 target unreachable). P2 runs from the request's last frame on the bus; each 0x78
  requestCorrectlyReceived-ResponsePending (ISO 14229-1 10.x) is relayed and restarts the wait at
  P2*. No response in time: the request is counted "ECU not responding" (timeouts) and the tester
  gets nothing more: it already has the positive ack (0x8002, "the message was put into the
  target network's transmit buffer"), and ISO 13400-2 has no later NACK; its own P2 / P6 timer
  ends the request (doipclient: a TimeoutError, udsoncan: TimeoutException). A request with
  suppressPosRspMsgIndicationBit and no answer within P2 is complete, not a timeout.
- Functional (the functional logical address): one single frame on the functional CAN ID; every
  ECU's response within its P2 (P2* after its 0x78) is relayed as its own reply, and the
  gateway answers for itself too.
- The gateway's own logical address: vecu.gateway.diag answers.

The gateway loop calls on_frame() for each received frame (or step(), which reads the node's
bus) and tick() every 1 ms; replies are made from tick(), never from inside submit(), so a DoIP
entity sends its ack before any response.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import can
import isotp
from doipclient.messages import DiagnosticMessageNegativeAcknowledgement
from udsoncan import Response
from udsoncan.BaseService import BaseService

from vecu.bus import BusNode
from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.gateway.config import ADDRESSING, MAX_UDS_BYTES, EcuRoute, GatewayConfig
from vecu.gateway.diag import COUNTER_FIELDS, GatewayUds
from vecu.stats import RunningStats
from vecu.uds.transport import Endpoint, NowNs, to_can

log = logging.getLogger(__name__)
Nack = DiagnosticMessageNegativeAcknowledgement.NackCodes  # ISO 13400-2 Table 26 (2019: 28)
RESPONSE_PENDING = Response.Code.RequestCorrectlyReceived_ResponsePending
Reply = Callable[[int, bytes], None]  # (source logical address, UDS response)
MAX_LOGGED = 20
INBOX_FRAMES = 4096        # frames a channel holds before process() (a flood beyond: dropped)
OWN_QUEUE = 64             # the gateway's own answers not yet delivered (beyond: NACK 0x05)
FUNCTIONAL_MAX = 7         # ISO 15765-2: a functional request is one single frame (classic CAN)
MODES = {(False, False): isotp.AddressingMode.Normal_11bits,
         (True, False): isotp.AddressingMode.Normal_29bits,
         (False, True): isotp.AddressingMode.Extended_11bits,
         (True, True): isotp.AddressingMode.Extended_29bits}


def isotp_address(route: EcuRoute) -> isotp.Address:
    """can-isotp's Address of a route (config.ADDRESSING's formats)."""
    wide, prefixed, fixed = ADDRESSING[route.addressing]
    if fixed:
        return isotp.Address(isotp.AddressingMode.NormalFixed_29bits,
                             target_address=route.target_address,
                             source_address=route.source_address)
    return isotp.Address(MODES[(wide, prefixed)], txid=route.request_id, rxid=route.response_id,
                         target_address=route.target_address if prefixed else None,
                         source_address=route.source_address if prefixed else None)


@dataclass
class RouteCounters:
    requests: int = 0          # accepted and handed to ISO-TP (the own / functional rows: taken)
    responses: int = 0         # final responses relayed to the tester
    pending_relayed: int = 0   # 0x78 response-pending relayed
    timeouts: int = 0          # ECU not responding: nothing within P2 / P2*
    suppressed: int = 0        # a suppressPosRspMsgIndicationBit request, no answer: complete
    transport_errors: int = 0  # ISO-TP errors can-isotp reported (a request lost sending: ended)
    late: int = 0              # responses with no request waiting (after a timeout): dropped
    frames_dropped: int = 0    # frames beyond INBOX_FRAMES
    nacks: dict[int, int] = field(default_factory=dict)  # NACK code -> count
    latency: RunningStats = field(default_factory=RunningStats)  # request sent -> final, ms

    def nack(self, code: int) -> int:
        self.nacks[code] = self.nacks.get(code, 0) + 1
        return code


@dataclass(frozen=True)
class RouteSummary:
    name: str
    logical_address: int
    requests: int
    responses: int
    pending_relayed: int
    timeouts: int
    suppressed: int
    transport_errors: int
    late: int
    frames_dropped: int
    nacks: dict[str, int]          # "0x06" -> count
    latency_mean_ms: float | None  # request's last frame on the bus -> final response
    latency_max_ms: float | None


@dataclass(frozen=True)
class RouterSummary:
    routes: tuple[RouteSummary, ...]  # the ECUs, in config order
    functional: RouteSummary
    gateway: RouteSummary             # requests the gateway answered itself
    unknown_target: int               # NACK 0x03: no route for the target address


@dataclass
class Pending:
    """A request on a channel: who gets the answers and until when it waits."""

    source: int
    reply: Reply | None  # None: the tester went away (cancel): answers are dropped
    sid: int
    spr: bool            # suppressPosRspMsgIndicationBit set
    functional: bool
    deadline_ns: int | None = None  # None while ISO-TP is still sending the request
    sent_ns: int = 0
    pending_seen: bool = False      # a 0x78 came: waiting P2*


def _suppressed(uds: bytes) -> bool:
    service = BaseService.from_request_id(uds[0])
    return service is not None and service.use_subfunction() and len(uds) > 1 \
        and bool(uds[1] & 0x80)


class Channel:
    """One ECU route: its ISO-TP endpoint, the request in flight and its counters."""

    def __init__(self, route: EcuRoute, now_ns: NowNs) -> None:
        self.route = route
        self.counters = RouteCounters()
        self.pending: Pending | None = None
        self.send_failed = False  # an ISO-TP error while the request was being sent
        self.ep = Endpoint(route.response_id, route.request_id, now_ns, errors=self._error,
                           address=isotp_address(route))

    def _error(self, exc: Exception) -> None:
        c = self.counters
        c.transport_errors += 1
        if c.transport_errors <= MAX_LOGGED:
            log.warning("gateway %s iso-tp: %s: %s", self.route.name, type(exc).__name__, exc)
        p = self.pending
        if p is not None and p.deadline_ns is None:
            self.send_failed = True  # the request did not get through (no flow control ...)

    @property
    def active(self) -> bool:
        return self.pending is not None or self.ep.busy


class DiagRouter:
    """The CAN side of the gateway on `node`'s bus; time comes from `now_ns` (vecu's clock).
    Not thread-safe: submit / cancel / on_frame / tick from the gateway loop's one thread."""

    def __init__(self, node: BusNode, config: GatewayConfig, now_ns: NowNs) -> None:
        self.node = node
        self.cfg = config
        self._now_ns = now_ns
        self.channels = [Channel(r, now_ns) for r in config.ecus]
        self._by_address = {ch.route.logical_address: ch for ch in self.channels}
        self._by_id: dict[tuple[int, bool], list[Channel]] = {}
        for ch in self.channels:
            self._by_id.setdefault((ch.route.response_id, ch.route.extended_ids), []).append(ch)
        wide = config.functional_addressing == "normal_29bit"
        mode = isotp.AddressingMode.Normal_29bits if wide else isotp.AddressingMode.Normal_11bits
        # transmit only: rxid is never fed (can-isotp needs one different from txid)
        self._func = Endpoint(0, 0, now_ns, address=isotp.Address(
            mode, txid=config.functional_id, rxid=config.functional_id ^ 1))
        self._func_sent = False  # the functional frame is on the bus: its channels' P2 runs
        self.functional = RouteCounters()
        self.own = RouteCounters()
        self.unknown_target = 0
        self.uds = GatewayUds(config, self._counter_rows)
        self._own_out: deque[tuple[Reply, int, bytes]] = deque()  # (reply, source, response)

    # ----------------------------------------------------------------- tester side
    def submit(self, source: int, target: int, uds: bytes, reply: Reply) -> int | None:
        """Route one diagnostic message; None when accepted (reply() follows from tick()),
        else the ISO 13400-2 diagnostic message NACK code and nothing is sent."""
        uds = bytes(uds)
        if target == self.cfg.logical_address:
            if len(self._own_out) >= OWN_QUEUE:
                return self.own.nack(Nack.OutOfMemory)
            self._answer_own(source, uds, reply, functional=False)
            return None
        if target == self.cfg.functional_address:
            return self._submit_functional(source, uds, reply)
        ch = self._by_address.get(target)
        if ch is None:
            self.unknown_target += 1
            return int(Nack.UnknownTargetAddress)
        c = ch.counters
        if len(uds) > MAX_UDS_BYTES:
            return c.nack(Nack.DiagnosticMessageTooLarge)
        if not uds:  # ISO-TP carries no empty message
            return c.nack(Nack.TransportProtocolError)
        if ch.active:
            return c.nack(Nack.TargetUnreachable)
        ch.ep.send(uds)
        ch.pending = Pending(source, reply, uds[0], _suppressed(uds), False)
        c.requests += 1
        return None

    def _answer_own(self, source: int, uds: bytes, reply: Reply, functional: bool) -> None:
        """The gateway's own answer, delivered from the next tick (after the DoIP ack)."""
        self.own.requests += 1  # physical and functional
        response = self.uds.handle(uds, functional, self._now_ns())
        if response is None:
            self.own.suppressed += 1
        elif len(self._own_out) < OWN_QUEUE:
            self._own_out.append((reply, source, response))

    def _submit_functional(self, source: int, uds: bytes, reply: Reply) -> int | None:
        c = self.functional
        if len(uds) > FUNCTIONAL_MAX:
            return c.nack(Nack.DiagnosticMessageTooLarge)
        if not uds:
            return c.nack(Nack.TransportProtocolError)
        if self._func.busy or any(ch.active for ch in self.channels):
            return c.nack(Nack.TargetUnreachable)
        self._func.send(uds, functional=True)
        self._func_sent = False
        spr = _suppressed(uds)
        for ch in self.channels:
            ch.pending = Pending(source, reply, uds[0], spr, True)
        c.requests += 1
        self._answer_own(source, uds, reply, functional=True)  # the gateway is an ECU too
        return None

    def cancel(self, source: int) -> None:
        """The tester's connection is gone: its answers still on the way are dropped (the
        channel stays busy until its ECU answers or times out, so no one else gets them)."""
        for ch in self.channels:
            if ch.pending is not None and ch.pending.source == source:
                ch.pending.reply = None
        self._own_out = deque(item for item in self._own_out if item[1] != source)

    # ----------------------------------------------------------------- bus side
    def on_frame(self, msg: can.Message, t_ns: int) -> None:
        """A frame from the bus (any ID: those of no route's responses are ignored)."""
        for ch in self._by_id.get((msg.arbitration_id, msg.is_extended_id), ()):
            if ch.ep.frames_in >= INBOX_FRAMES:
                ch.counters.frames_dropped += 1
            else:
                ch.ep.put(msg)

    def step(self, t_ns: int) -> None:
        """Read the node's bus within its RxBudget (docs/live.md 'Floods': a flood is shed and
        counted, never stalls the step; a frame on a route's response ID is never shed), then
        tick()."""
        node, by_id, on_frame = self.node, self._by_id, self.on_frame
        n = node.rx_budget.frames_per_tick
        recv = node.bus.recv
        while (msg := recv(0.0)) is not None:
            on_frame(msg, t_ns)
            n -= 1
            if not n:
                def keep(m: can.Message) -> bool:
                    if (m.arbitration_id, m.is_extended_id) not in by_id:
                        return False
                    on_frame(m, t_ns)
                    return True

                node.shed(keep)
                break
        else:
            node.rx_saturated = 0
        self.tick(t_ns)

    def tick(self, t_ns: int) -> None:
        ts = t_ns / NS_PER_S
        while self._own_out:
            reply, _, response = self._own_out.popleft()
            self.own.responses += 1
            reply(self.cfg.logical_address, response)
        func = self._func
        if func.busy:
            func.process()
            while func.out:
                self.node.send(to_can(func.out.popleft(), ts))
            self._func_sent = True
        for ch in self.channels:
            if ch.active:
                self._work(ch, t_ns, ts)

    def _work(self, ch: Channel, t_ns: int, ts: float) -> None:
        ep = ch.ep
        ep.process()
        while ep.out:
            self.node.send(to_can(ep.out.popleft(), ts))
        p = ch.pending
        if p is not None and ch.send_failed:
            ch.pending = p = None  # counted in transport_errors; the tester's P2 ends it
        ch.send_failed = False
        if p is not None and p.deadline_ns is None and not ep.out \
                and not ep.layer.transmitting() and (not p.functional or self._func_sent):
            p.sent_ns = t_ns  # the request's last frame is on the bus: P2 from here
            p.deadline_ns = t_ns + round(ch.route.p2_ms * NS_PER_MS)
        for payload in ep.payloads():
            self._response(ch, payload, t_ns)
        p = ch.pending
        if p is not None and p.deadline_ns is not None and t_ns >= p.deadline_ns:
            self._expire(ch, p)

    def _response(self, ch: Channel, payload: bytes, t_ns: int) -> None:
        p, c = ch.pending, ch.counters
        if p is None or p.deadline_ns is None:
            c.late += 1
            return
        rows = self.functional if p.functional else c
        if len(payload) == 3 and payload[0] == 0x7F and payload[1] == p.sid \
                and payload[2] == RESPONSE_PENDING:
            rows.pending_relayed += 1
            p.pending_seen = True
            p.deadline_ns = t_ns + round(ch.route.p2_star_ms * NS_PER_MS)
        else:
            rows.responses += 1
            rows.latency.add((t_ns - p.sent_ns) / NS_PER_MS)
            ch.pending = None
        if p.reply is not None:
            p.reply(ch.route.logical_address, payload)

    def _expire(self, ch: Channel, p: Pending) -> None:
        ch.pending = None
        c = ch.counters
        if p.functional:
            return  # an ECU may rightly stay silent on a functional request (ISO 14229-1 7.5)
        if p.spr and not p.pending_seen:
            c.suppressed += 1
            return
        c.timeouts += 1
        if c.timeouts <= MAX_LOGGED:
            log.warning("gateway: ECU not responding: %s (0x%04X) gave no response to SID "
                        "0x%02X within %s", ch.route.name, ch.route.logical_address, p.sid,
                        f"P2* {ch.route.p2_star_ms:g} ms" if p.pending_seen
                        else f"P2 {ch.route.p2_ms:g} ms")

    # ----------------------------------------------------------------- figures
    def _counter_rows(self) -> list[tuple[int, list[int]]]:
        rows = [(ch.route.logical_address, ch.counters) for ch in self.channels]
        rows.append((self.cfg.functional_address, self.functional))
        return [(la, [sum(c.nacks.values()) if name == "nacks" else getattr(c, name)
                      for name in COUNTER_FIELDS]) for la, c in rows]

    def summary(self) -> RouterSummary:
        def row(name: str, la: int, c: RouteCounters) -> RouteSummary:
            n = c.latency.n
            return RouteSummary(
                name, la, c.requests, c.responses, c.pending_relayed, c.timeouts, c.suppressed,
                c.transport_errors, c.late, c.frames_dropped,
                {f"0x{k:02X}": v for k, v in sorted(c.nacks.items())},
                c.latency.mean if n else None, c.latency.max_abs if n else None)

        return RouterSummary(
            tuple(row(ch.route.name, ch.route.logical_address, ch.counters)
                  for ch in self.channels),
            row("functional", self.cfg.functional_address, self.functional),
            row("gateway", self.cfg.logical_address, self.own), self.unknown_target)
