"""A DoIP entity (ISO 13400-2:2012 / 2019) on non-blocking sockets, stepped by vecu's clock.

`DoipEntity.step(t_ns)` (every 1 ms from the gateway's scheduler) accepts connections, reads
every socket that is ready (selectors, no wait), runs the timers and flushes what is queued.
Nothing it receives can raise out of step(): a bad header or payload gets the generic NACK the
standard names (§7.1.4 Figure 9) and, where it says so, the socket closed; a bug inside a
handler stops at the node's boundary (BusNode.handler_failed: counted, logged once with its
traceback) and closes that one connection.

UDP (port 13400): vehicle identification requests (plain, by EID, by VIN: §7.3.3) answered with
0x0004 to the sender; entity status 0x4001 -> 0x4002, power mode 0x4003 -> 0x4004; the vehicle
announcement (0x0004) after start (A_DoIP_Announce_Wait, Num, Interval).
TCP_DATA (port 13400): routing activation 0x0005 -> 0x0006 (§7.4.3, the socket handler's alive
checks), alive check 0x0007 / 0x0008, diagnostic messages 0x8001 -> 0x8002 / 0x8003 handed to
the router, its answers back as 0x8001 (SA = the ECU's logical address); the
T_TCP_Initial_Inactivity and T_TCP_General_Inactivity timers.
"""

from __future__ import annotations

import contextlib
import logging
import selectors
import socket
from collections import Counter
from collections.abc import Callable
from typing import Any

from doipclient import messages as m

from vecu.bus import BusNode
from vecu.gateway import doip
from vecu.gateway.activation import ActivationHandler
from vecu.gateway.connection import Connection
from vecu.gateway.roles import FaultHook, Identity, Router
from vecu.gateway.settings import DoipSettings

log = logging.getLogger("vecu.gateway")

RECV_BYTES = 65536
MAX_READS_PER_STEP = 16  # per socket and step: one flooding tester cannot starve the others
OUT_LIMIT_BYTES = 1 << 20  # queued for a tester that does not read: beyond, it is closed
EXTRA_SOCKETS = 1  # connections beyond max_sockets that may ask (and be told 0x01)


def broadcast_address(bind: str) -> str:
    """Where announcements go: loopback's broadcast (127.255.255.255) for a loopback bind, the
    limited broadcast otherwise."""
    return "127.255.255.255" if bind.startswith("127.") else "255.255.255.255"


class DoipEntity:
    """The gateway's DoIP side: sockets, the socket table, counters (summary())."""

    def __init__(self, ident: Identity, settings: DoipSettings, router: Router,
                 node: BusNode, announce_delay_s: float, bind: str = "127.0.0.1",
                 port: int = 13400) -> None:
        """node: the gateway's bus node, whose handler_failed() is the boundary a bug inside
        a handler stops at (counted by kind, logged once with its traceback)."""
        self.node = node
        self.ident = ident
        self.s = settings
        self.router = router
        self.bind, self.port = bind, port
        self.sel = selectors.DefaultSelector()
        self.conns: dict[int, Connection] = {}  # by serial number
        self._serial = 0
        self.tcp: socket.socket | None = None
        self.udp: socket.socket | None = None
        self.announce_to = settings.announce_address or broadcast_address(bind)
        self.announce_delay_s = announce_delay_s
        first = settings.ns(announce_delay_s)
        self._announce_at = [first + k * settings.ns(settings.announce_interval_s)
                             for k in range(settings.announce_count)]
        self.activation = ActivationHandler(self)
        self.count: dict[str, Counter[str]] = {
            k: Counter() for k in ("connections", "closed", "activations", "generic_nacks",
                                   "diag_nacks", "diag", "udp", "alive_checks", "bad_input")}
        self._logged: set[str] = set()
        self.reserved_bytes = 0  # payload memory held by messages being received
        self.faults: FaultHook | None = None  # diagnostic faults (vecu.conformance.doip_faults)

    # ------------------------------------------------------------------ sockets
    def open(self) -> None:
        """Bind TCP_DATA and UDP_DISCOVERY (OSError: the caller reports the address)."""
        tcp = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            tcp.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            tcp.bind((self.bind, self.port))
            tcp.listen(16)
            tcp.setblocking(False)
            self.port = tcp.getsockname()[1]  # port 0: the one the system gave, for UDP too
            # testers on this host may listen on the same UDP port for announcements
            udp.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            udp.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
            udp.bind((self.bind, self.port))
            udp.setblocking(False)
        except OSError:
            tcp.close()
            udp.close()
            raise
        self.tcp, self.udp = tcp, udp
        self.sel.register(tcp, selectors.EVENT_READ, None)
        self.sel.register(udp, selectors.EVENT_READ, None)

    def close(self) -> None:
        for c in list(self.conns.values()):
            self.drop(c, "gateway stopped")
        for s in (self.tcp, self.udp):
            if s is not None:
                self.sel.unregister(s)
                s.close()
        self.tcp = self.udp = None
        self.sel.close()

    # ------------------------------------------------------------------ stepping
    def step(self, t_ns: int) -> None:
        """One pass: every ready socket, the timers, the queued output. Never raises: a bug
        outside a connection's handlers is counted and logged once too, and the next step runs."""
        try:
            self._step(t_ns)
        except Exception as exc:  # noqa: BLE001 - a bug: counted, logged once, the gateway runs on
            self.node.handler_failed("doip step", exc)

    def _step(self, t_ns: int) -> None:
        for key, _ in self.sel.select(0):
            sock = key.fileobj
            if sock is self.tcp:
                self._accept(t_ns)
            elif sock is self.udp:
                self._read_udp(t_ns)
            else:
                c = self.conns.get(key.data)
                if c is not None:
                    self._guarded(c, self._read_tcp, t_ns)
        while self._announce_at and t_ns >= self._announce_at[0]:
            self._announce_at.pop(0)
            self._send_udp(self._identity(), (self.announce_to, self.port), self.s.protocol_version,
                           "announcements")
        self.activation.tick(t_ns)
        if self.faults is not None:
            self.faults.tick(self, t_ns)
        for c in list(self.conns.values()):
            self._guarded(c, self._timers, t_ns)
            if c.out and not c.closed:
                self._guarded(c, lambda c, t: self._flush(c), t_ns)

    def _guarded(self, c: Connection, fn: Callable[[Connection, int], None], t_ns: int) -> None:
        try:
            fn(c, t_ns)
        except Exception as exc:  # noqa: BLE001 - a bug in a handler: this connection only
            self.node.handler_failed("doip tcp", exc)
            self.drop(c, "handler error")

    def _accept(self, t_ns: int) -> None:
        assert self.tcp is not None
        for _ in range(MAX_READS_PER_STEP):
            try:
                sock, peer = self.tcp.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                self.bad("accept_error", f"accept failed: {exc}")
                return
            if len(self.conns) >= self.s.max_sockets + EXTRA_SOCKETS:
                self.count["connections"]["refused"] += 1
                self.bad("too_many_connections", f"more TCP connections than "
                         f"{self.s.max_sockets + EXTRA_SOCKETS}: {peer} closed at once")
                sock.close()
                continue
            sock.setblocking(False)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._serial += 1
            c = Connection(self._serial, sock, peer, t_ns, self.s.protocol_version)
            self.conns[c.serial] = c
            self.sel.register(sock, selectors.EVENT_READ, c.serial)
            self.count["connections"]["accepted"] += 1

    def drop(self, c: Connection, reason: str) -> None:
        """Close the connection, release what it held, forget its routing."""
        if c.closed:
            return
        c.closed = True
        self._flush(c)
        self.release(c)
        self.count["closed"][reason] += 1
        self.conns.pop(c.serial, None)
        with contextlib.suppress(KeyError, ValueError):
            self.sel.unregister(c.sock)
        c.sock.close()
        if c.sa is not None:
            self.router.cancel(c.sa)
        self.activation.forget(c)

    # ------------------------------------------------------------------ output
    def send(self, c: Connection, msg: m.DoIPMessage) -> None:
        if c.closed:
            return
        data = doip.pack(msg, c.version)
        c.out += data if self.faults is None else self.faults.outgoing(c, data)
        self._flush(c)
        if len(c.out) > OUT_LIMIT_BYTES:
            self.bad("tester_not_reading", f"{c.peer}: more than {OUT_LIMIT_BYTES} bytes "
                     "unread by the tester: closed")
            self.drop(c, "tester not reading")

    def _flush(self, c: Connection) -> None:
        while c.out:
            try:
                n = c.sock.send(c.out)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                c.out.clear()
                if not c.closed:
                    self.drop(c, "send failed")
                return
            del c.out[:n]

    def _send_udp(self, msg: m.DoIPMessage, addr: Any, version: int, what: str) -> None:
        assert self.udp is not None
        try:
            self.udp.sendto(doip.pack(msg, version), addr)
            self.count["udp"][what] += 1
        except OSError as exc:
            self.bad("udp_send_failed", f"UDP send to {addr} failed: {exc}")

    # ------------------------------------------------------------------ counting
    def bad(self, kind: str, text: str) -> None:
        """A bad input (or a refused one): counted by kind, logged the first time per kind."""
        self.count["bad_input"][kind] += 1
        if kind not in self._logged:
            self._logged.add(kind)
            log.warning("DoIP: %s (further ones counted as bad_input.%s)", text, kind)

    def nack(self, c: Connection, code: int, kind: str, text: str, version: int) -> None:
        self.count["generic_nacks"][f"0x{code:02X}"] += 1
        self.bad(kind, f"{c.peer}: {text}: generic NACK 0x{code:02X}")
        c.out += doip.generic_nack(code, version if version in doip.PROTOCOL_VERSIONS
                                   else self.s.protocol_version)
        self._flush(c)

    def release(self, c: Connection) -> None:
        self.reserved_bytes -= c.reserved
        c.reserved = 0

    # ------------------------------------------------------------------ TCP
    def _read_tcp(self, c: Connection, t_ns: int) -> None:
        for _ in range(MAX_READS_PER_STEP):
            try:
                data = c.sock.recv(RECV_BYTES)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                self.drop(c, "reset by tester")
                return
            if not data:
                self.drop(c, "closed by tester")
                return
            c.last_rx_ns = t_ns
            self._feed(c, memoryview(data), t_ns)
            if c.closed or len(data) < RECV_BYTES:
                return

    def _feed(self, c: Connection, data: memoryview, t_ns: int) -> None:
        """Split the stream into messages: the header checked before any payload byte is
        kept; a discarded message's bytes are skipped as they arrive (never allocated)."""
        i, n = 0, len(data)
        while i < n and not c.closed:
            if c.skip:
                k = min(c.skip, n - i)
                c.skip -= k
                i += k
                continue
            if c.header is None:
                k = min(doip.HEADER_LEN - len(c.hbuf), n - i)
                c.hbuf += data[i:i + k]
                i += k
                if len(c.hbuf) < doip.HEADER_LEN:
                    return
                h = doip.Header.parse(c.hbuf)
                c.hbuf.clear()
                if self._check_tcp_header(c, h):
                    c.header = h
                    c.reserved = h.length
                    self.reserved_bytes += h.length
                    if h.length == 0:
                        self._complete(c, t_ns)
                continue
            k = min(c.header.length - len(c.payload), n - i)
            c.payload += data[i:i + k]
            i += k
            if len(c.payload) == c.header.length:
                self._complete(c, t_ns)

    def _complete(self, c: Connection, t_ns: int) -> None:
        h, payload = c.header, bytes(c.payload)
        assert h is not None
        c.header = None
        c.payload = bytearray()
        self.release(c)
        c.version = h.version
        msg = doip.unpack(h.payload_type, payload)
        if self.faults is not None and self.faults.intercept(self, c, msg, t_ns):
            return
        if isinstance(msg, m.RoutingActivationRequest):
            self.activation.request(c, msg, t_ns)
        elif isinstance(msg, m.DiagnosticMessage):
            self.diagnostic(c, msg)
        elif isinstance(msg, m.AliveCheckResponse):
            self.activation.alive(c, msg.source_address)
        elif isinstance(msg, m.AliveCheckRequest):  # a tester asking: the entity is alive
            self.count["alive_checks"]["answered_to_tester"] += 1
            self.send(c, m.AliveCheckResponse(self.ident.logical_address))

    def _check_tcp_header(self, c: Connection, h: doip.Header) -> bool:
        """Figure 9 in order; False: NACKed (and skipped or closed)."""
        s = self.s
        if not doip.pattern_ok(h):
            self.nack(c, doip.GenericNack.IncorrectPatternFormat, "incorrect_pattern",
                      f"header pattern {h.version:02X} {h.inverse:02X}", s.protocol_version)
            self.drop(c, "incorrect pattern")
            return False
        rule = doip.RULES.get(h.payload_type)
        if rule is None or not rule.tcp:
            self.nack(c, doip.GenericNack.UnknownPayloadType, "unknown_payload_type",
                      f"payload type 0x{h.payload_type:04X} on TCP", h.version)
            c.skip = h.length
            return False
        if h.length > s.max_payload:
            self.nack(c, doip.GenericNack.MessageTooLarge, "message_too_large",
                      f"payload length {h.length} > {s.max_payload}", h.version)
            c.skip = h.length
            return False
        if h.length > s.memory_bytes - self.reserved_bytes:
            self.nack(c, doip.GenericNack.OutOfMemory, "out_of_memory",
                      f"payload length {h.length}: {s.memory_bytes - self.reserved_bytes} "
                      "bytes free", h.version)
            c.skip = h.length
            return False
        if not doip.length_ok(rule, h.length):
            self.nack(c, doip.GenericNack.InvalidPayloadLength, "invalid_payload_length",
                      f"payload length {h.length} for type 0x{h.payload_type:04X}", h.version)
            self.drop(c, "invalid payload length")
            return False
        return True

    def _timers(self, c: Connection, t_ns: int) -> None:
        s = self.s
        if c.sa is None and t_ns - c.opened_ns > s.ns(s.initial_inactivity_s) \
                and not self.activation.pending_for(c):
            self.bad("no_routing_activation", f"{c.peer}: no routing activation within "
                     f"{s.initial_inactivity_s:g} s (T_TCP_Initial_Inactivity): closed")
            self.drop(c, "initial inactivity")
        elif c.sa is not None and t_ns - c.last_rx_ns > s.ns(s.general_inactivity_s):
            self.bad("inactive_tester", f"{c.peer}: silent for {s.general_inactivity_s:g} s "
                     "(T_TCP_General_Inactivity): closed")
            self.drop(c, "general inactivity")

    # ------------------------------------------------------------------ diagnostics
    def diagnostic(self, c: Connection, msg: m.DiagnosticMessage) -> None:
        """§7.8 Figure 11: SA check (0x02, socket closed), then the router's verdict."""
        sa, ta, uds = msg.source_address, msg.target_address, bytes(msg.user_data)
        if c.sa is None or sa != c.sa:
            self.count["diag_nacks"]["0x02"] += 1
            self.bad("invalid_source_address",
                     f"{c.peer}: diagnostic message from SA 0x{sa:04X}, routing active for "
                     f"{'none' if c.sa is None else f'0x{c.sa:04X}'}: NACK 0x02, closed")
            self.send(c, m.DiagnosticMessageNegativeAcknowledgement(
                ta, sa, doip.DiagNack.InvalidSourceAddress))
            self.drop(c, "invalid source address")
            return
        serial = c.serial

        def reply(source: int, data: bytes) -> None:
            conn = self.conns.get(serial)
            if conn is None or conn.closed:
                self.count["diag"]["responses_dropped"] += 1
                return
            self.count["diag"]["responses"] += 1
            self.send(conn, m.DiagnosticMessage(source, sa, bytearray(data)))

        code = self.router.submit(sa, ta, uds, reply)
        if code is None:
            self.count["diag"]["routed"] += 1
            self.send(c, m.DiagnosticMessagePositiveAcknowledgement(ta, sa, 0x00))
        else:
            self.count["diag_nacks"][f"0x{code:02X}"] += 1
            self.send(c, m.DiagnosticMessageNegativeAcknowledgement(ta, sa, code))

    # ------------------------------------------------------------------ UDP
    def _identity(self) -> m.VehicleIdentificationResponse:
        i = self.ident
        return m.VehicleIdentificationResponse(i.vin, i.logical_address, i.eid, i.gid,
                                               self.s.further_action)

    def _read_udp(self, t_ns: int) -> None:
        assert self.udp is not None
        for _ in range(MAX_READS_PER_STEP):
            try:
                data, addr = self.udp.recvfrom(RECV_BYTES)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                self.bad("udp_receive_error", f"UDP receive failed: {exc}")
                return
            try:
                self._datagram(data, addr)
            except Exception as exc:  # noqa: BLE001 - a bug: counted, logged once, the next one read
                self.node.handler_failed("doip udp", exc)

    def _udp_nack(self, code: int, addr: Any, version: int, kind: str, text: str) -> None:
        self.count["generic_nacks"][f"0x{code:02X}"] += 1
        self.bad(kind, f"UDP from {addr}: {text}: generic NACK 0x{code:02X}")
        self._send_udp(m.GenericDoIPNegativeAcknowledge(code), addr,
                       version if version in doip.PROTOCOL_VERSIONS else self.s.protocol_version,
                       "nacks")

    def _datagram(self, data: bytes, addr: Any) -> None:
        """One datagram, one DoIP message (§7.3.1): Figure 9's checks (no socket to close)."""
        if len(data) < doip.HEADER_LEN:
            self._udp_nack(doip.GenericNack.InvalidPayloadLength, addr, self.s.protocol_version,
                           "truncated_datagram", f"{len(data)} bytes, shorter than a header")
            return
        h = doip.Header.parse(data)
        if not doip.pattern_ok(h):
            self._udp_nack(doip.GenericNack.IncorrectPatternFormat, addr, self.s.protocol_version,
                           "incorrect_pattern", f"header pattern {h.version:02X} {h.inverse:02X}")
            return
        if h.payload_type in doip.ENTITY_MESSAGES:  # our own broadcast looped back, or a peer's
            self.count["udp"]["ignored"] += 1
            return
        rule = doip.RULES.get(h.payload_type)
        if rule is None or not rule.udp:
            self._udp_nack(doip.GenericNack.UnknownPayloadType, addr, h.version,
                           "unknown_payload_type", f"payload type 0x{h.payload_type:04X} on UDP")
            return
        if h.length > self.s.max_payload:
            self._udp_nack(doip.GenericNack.MessageTooLarge, addr, h.version,
                           "message_too_large", f"payload length {h.length}")
            return
        if not doip.length_ok(rule, h.length) or len(data) != doip.HEADER_LEN + h.length:
            self._udp_nack(doip.GenericNack.InvalidPayloadLength, addr, h.version,
                           "invalid_payload_length",
                           f"payload length {h.length} (datagram {len(data)} bytes)")
            return
        msg = doip.unpack(h.payload_type, data[doip.HEADER_LEN:])
        version = h.version if h.version in doip.PROTOCOL_VERSIONS else self.s.protocol_version
        i = self.ident
        if isinstance(msg, m.VehicleIdentificationRequestWithEID):
            self.count["udp"]["identification_by_eid"] += 1
            if bytes(msg.eid) != bytes(i.eid):
                return  # §7.3.3: only the entity with that EID answers
        elif isinstance(msg, m.VehicleIdentificationRequestWithVIN):
            self.count["udp"]["identification_by_vin"] += 1
            if msg.vin != i.vin:
                return
        elif isinstance(msg, m.VehicleIdentificationRequest):
            self.count["udp"]["identification"] += 1
        elif isinstance(msg, m.DoipEntityStatusRequest):
            registered = sum(1 for c in self.conns.values() if c.sa is not None)
            self._send_udp(m.EntityStatusResponse(0x00, self.s.max_sockets, registered,
                                                  self.s.max_data_size),
                           addr, version, "entity_status")
            return
        elif isinstance(msg, m.DiagnosticPowerModeRequest):
            self._send_udp(m.DiagnosticPowerModeResponse(self.s.power_mode), addr, version, "power_mode")
            return
        self._send_udp(self._identity(), addr, version, "identification_responses")

    # ------------------------------------------------------------------ summary
    def summary(self) -> dict[str, Any]:
        return {
            "bind": self.bind, "port": self.port, "announce_to": self.announce_to,
            "announce_delay_ms": round(self.announce_delay_s * 1000, 3),
            "max_sockets": self.s.max_sockets,
            **{k: dict(sorted(v.items())) for k, v in self.count.items()},
            "bad_input_total": sum(self.count["bad_input"].values()),
            "handler_errors": {k: n for k, n in self.node.handler_errors.items()
                               if k.startswith("doip")},
            "open_connections": len(self.conns),
        }
