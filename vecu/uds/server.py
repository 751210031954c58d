"""The ECU's UDS server (ISO 14229-1) on ISO-TP (can-isotp): sessions, security, DIDs, DTCs,
IO control and routines. docs/uds.md is the tester's manual.

EcuNode hands it every frame on its IDs (on_frame) and calls tick() once per 1 ms base tick,
after the functions have broadcast: at most `frames_per_tick` CAN frames are taken in and sent
and `requests_per_tick` requests answered per tick (a request flood costs bounded time and
never delays a broadcast). A request is answered in the tick it completes (P2 is met with
49 ms to spare); time is the tick's (vecu's clock), so on the simulated clock the same requests
give the same responses at the same times.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import can
import numpy as np
from udsoncan import Response

from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.ecu.node import EcuNode
from vecu.uds.config import UdsConfig
from vecu.uds.dids import SNAPSHOT_DIDS, Did, build_dids
from vecu.uds.dtcs import AVAILABILITY_MASK, DtcMemory, DtcRecord
from vecu.uds.routines import ROUTINES, RUNNING, STOPPED, SelfTest
from vecu.uds.security import SecurityAccess
from vecu.uds.transport import Endpoint, to_can

log = logging.getLogger(__name__)
C = Response.Code
DEFAULT, PROGRAMMING, EXTENDED = 1, 2, 3
ALL, EXT = (DEFAULT, EXTENDED), (EXTENDED,)
# negative responses a functional request does not get (ISO 14229-1 7.5)
FUNCTIONAL_SILENT = {C.ServiceNotSupported, C.SubFunctionNotSupported, C.RequestOutOfRange,
                     C.SubFunctionNotSupportedInActiveSession,
                     C.ServiceNotSupportedInActiveSession}
Result = "bytes | int | None"


@dataclass
class UdsStats:
    requests: int = 0
    responses: int = 0           # sent
    positive: int = 0            # of the requests (sent or suppressed)
    negative: int = 0
    suppressed: int = 0          # no response: suppressPosRspMsgIndicationBit / functional NRC
    frames_dropped: int = 0      # CAN frames beyond the inbox (a flood)
    requests_dropped: int = 0    # complete requests beyond the request queue
    transport_errors: int = 0    # ISO-TP errors (bad sequence, timeouts, ...) reported by can-isotp
    echoes: int = 0              # frames on the response ID (own echoes, another server)
    resets: int = 0
    # the request's last CAN frame taken from the bus -> its response handed to ISO-TP, on the
    # ECU's clock (whole ticks: 0 when answered in the tick the request arrived; more when the
    # inbox, the request queue or the per-tick limits made it wait)
    latency_max_ms: float = 0.0


class DiagHook(Protocol):
    """What commits diagnostic faults on the server's path (vecu.uds.diag_faults.engine)."""

    def take(self, msg: can.Message, t_ns: int) -> bool: ...
    def poll(self, t_ns: int) -> None: ...
    def respond(self, request: bytes, functional: bool, response: bytes | None,
                t_ns: int) -> bytes | None: ...


def flow_control_block_size(config: UdsConfig) -> int:
    """The BS of the ECU's flow control: half the frames it takes in per tick."""
    return max(1, config.frames_per_tick // 2)


class UdsServer:
    """The diagnostic server of `node` (attach with node.attach(server))."""

    def __init__(self, node: EcuNode, config: UdsConfig, rng: np.random.Generator | None) -> None:
        """rng: security access seeds (None: the OS's entropy, vecu.uds.security)."""
        self.node = node
        self.cfg = config
        self._now = 0
        now = self._now_ns
        # flow control the ECU can absorb: a sender that obeys it sends at most block_size
        # consecutive frames before the next FC, which the ECU gives once it has taken them in
        # (frames_per_tick per tick from an inbox of 4x that), so no frame of a long request is
        # ever dropped (a BS of 0, "send everything", overran the inbox above ~900 bytes)
        fc = {"blocksize": flow_control_block_size(config)}
        self.phys = Endpoint(config.request_id, config.response_id, now, errors=self._tp_error,
                             params=fc)
        self.func = Endpoint(config.functional_id, config.response_id, now,
                             errors=self._tp_error, params=fc)
        self.ids = frozenset({(config.request_id, False), (config.functional_id, False),
                              (config.response_id, False)})
        self._inbox: deque[tuple[can.Message, int]] = deque()  # (frame, taken from the bus)
        self._inbox_max = 4 * config.frames_per_tick
        self._queue: deque[tuple[bytes, bool, int]] = deque()
        self._awake = False
        self.stats = UdsStats()
        self.hook: DiagHook | None = None  # diagnostic faults (vecu.uds.diag_faults.engine)
        self.suppressed: bytes | None = None  # the last positive response suppressPosRsp held
        self.session = DEFAULT
        self._s3_deadline = 0
        self.security = SecurityAccess(rng, config.security_attempts,
                                       round(config.security_delay_ms * NS_PER_MS))
        self.dids: dict[int, Did] = build_dids(node, config, now, lambda: self.session)
        self.dtcs = DtcMemory(node.monitors, [spec for fn in node.functions
                                               for spec in getattr(fn, "dtcs", tuple)()],
                              node.bus_dtc, self._snapshot)
        self.io: dict[int, float] = {}  # DID -> the value the ECU is made to see
        self.routines = {rid: SelfTest(node.monitors[name]) for rid, name in ROUTINES.items()
                         if name in node.monitors}
        self._services: dict[int, tuple[Callable[[bytes, int], object], tuple[int, ...], bool]] = {
            0x10: (self._session_control, ALL, True), 0x11: (self._ecu_reset, ALL, True),
            0x14: (self._clear_dtcs, ALL, False), 0x19: (self._read_dtcs, ALL, True),
            0x22: (self._read_dids, ALL, False), 0x27: (self._security_access, EXT, True),
            0x28: (self._communication_control, EXT, True),
            0x2E: (self._write_did, EXT, False), 0x2F: (self._io_control, EXT, False),
            0x31: (self._routine_control, EXT, True), 0x3E: (self._tester_present, ALL, True),
            0x85: (self._dtc_setting, EXT, True)}

    def _now_ns(self) -> int:
        return self._now

    def _tp_error(self, exc: Exception) -> None:
        self.stats.transport_errors += 1
        if self.stats.transport_errors <= 20:
            log.warning("uds iso-tp: %s: %s", type(exc).__name__, exc)

    # ------------------------------------------------------------- node side
    def on_frame(self, msg: can.Message, t_ns: int) -> None:
        if self.hook is None or not self.hook.take(msg, t_ns):
            self.deliver(msg, t_ns)

    def deliver(self, msg: can.Message, t_ns: int) -> None:
        if msg.arbitration_id == self.cfg.response_id:
            self.stats.echoes += 1
        elif len(self._inbox) >= self._inbox_max:
            self.stats.frames_dropped += 1
        else:
            self._inbox.append((msg, t_ns))
            self._awake = True

    def tick(self, t_ns: int) -> None:
        self._now = t_ns
        self.dtcs.update(t_ns)
        if self._awake or self.hook is not None:
            self._work(t_ns)

    def _work(self, t_ns: int) -> None:
        cfg, inbox, queue, stats = self.cfg, self._inbox, self._queue, self.stats
        functional_id = cfg.functional_id
        rx_ns = {}  # endpoint -> when its last frame taken in this tick came
        if self.hook is not None:
            self.hook.poll(t_ns)
        for _ in range(min(len(inbox), cfg.frames_per_tick)):
            msg, t_rx = inbox.popleft()
            ep = self.func if msg.arbitration_id == functional_id else self.phys
            ep.put(msg)
            rx_ns[ep] = t_rx
        self.phys.process()
        self.func.process()
        for ep, functional in ((self.phys, False), (self.func, True)):
            for payload in ep.payloads():
                if len(queue) >= cfg.request_queue:
                    stats.requests_dropped += 1
                else:
                    queue.append((payload, functional, rx_ns.get(ep, t_ns)))
        for _ in range(min(len(queue), cfg.requests_per_tick)):
            payload, functional, t_rx = queue.popleft()
            response = self.handle(payload, functional, t_ns)
            if self.hook is not None:
                response = self.hook.respond(payload, functional, response, t_ns)
            stats.latency_max_ms = max(stats.latency_max_ms, (t_ns - t_rx) / NS_PER_MS)
            if response is not None:
                self.phys.send(response)
        self.phys.process()
        sent = 0
        ts = t_ns / NS_PER_S
        for ep in (self.phys, self.func):
            while ep.out and sent < cfg.frames_per_tick:
                self.node.send(to_can(ep.out.popleft(), ts))
                sent += 1
        if self.session != DEFAULT and t_ns >= self._s3_deadline:
            log.info("uds: S3 timeout, back to the default session")
            self._enter(DEFAULT)
        running = False
        for routine in self.routines.values():
            routine.poll(t_ns)
            running |= routine.state == RUNNING
        self._awake = bool(inbox or queue or running or self.session != DEFAULT
                           or self.phys.busy or self.func.busy)

    # -------------------------------------------------------------- requests
    def handle(self, payload: bytes, functional: bool, t_ns: int) -> bytes | None:
        """The response to one request (None: no response)."""
        self._now = t_ns
        stats = self.stats
        stats.requests += 1
        if self.session != DEFAULT:
            self._s3_deadline = t_ns + round(self.cfg.s3_ms * NS_PER_MS)
        sid = payload[0] if payload else 0
        service = self._services.get(sid)
        spr = False
        if service is None:
            result: object = C.ServiceNotSupported
        elif self.session not in service[1]:
            result = C.ServiceNotSupportedInActiveSession
        elif service[2] and len(payload) < 2:
            result = C.IncorrectMessageLengthOrInvalidFormat
        else:
            spr = service[2] and sid != 0x19 and bool(payload[1] & 0x80)
            try:
                result = service[0](payload, t_ns)
            except Exception as exc:  # noqa: BLE001 - the handler boundary (ISO 14229-1 NRC 0x10)
                self.node.handler_failed(f"uds service 0x{sid:02X}", exc)
                result, spr = C.GeneralReject, False
        if isinstance(result, int):
            stats.negative += 1
            if functional and result in FUNCTIONAL_SILENT:
                stats.suppressed += 1
                return None
            stats.responses += 1
            return bytes([0x7F, sid, result])
        stats.positive += 1
        if spr:
            stats.suppressed += 1
            self.suppressed = bytes([sid + 0x40]) + result  # type: ignore[operator]  # bytes here
            return None
        stats.responses += 1
        return bytes([sid + 0x40]) + result  # type: ignore[operator]  # an int (negative response) returned above: bytes here

    def _enter(self, session: int) -> None:
        self.security.lock()
        self.session = session
        self._awake = True  # S3 runs from now
        self._s3_deadline = self._now + round(self.cfg.s3_ms * NS_PER_MS)
        if session == DEFAULT:  # what a non-default session enabled ends with it
            self.node.set_broadcast(True)
            if not self.dtcs.enabled:
                self.dtcs.resume()
            for did in list(self.io):
                self._release(did)

    def _release(self, did: int) -> None:
        self.io.pop(did, None)
        message, signal = self.dids[did].io  # type: ignore[misc]  # only IO-controllable DIDs (io set) are released
        self.node.set_override(message, signal, None)

    # 0x10
    def _session_control(self, p: bytes, t_ns: int) -> bytes | int:
        sub = p[1] & 0x7F
        if sub not in (DEFAULT, PROGRAMMING, EXTENDED):
            return C.SubFunctionNotSupported
        if len(p) != 2:
            return C.IncorrectMessageLengthOrInvalidFormat
        if sub == PROGRAMMING:  # no bootloader: entered only from extended, and never ready
            return (C.SubFunctionNotSupportedInActiveSession if self.session == DEFAULT
                    else C.ConditionsNotCorrect)
        self._enter(sub)
        p2 = min(round(self.cfg.p2_ms), 0xFFFF)
        p2s = min(round(self.cfg.p2_star_ms / 10), 0xFFFF)
        return bytes([sub]) + p2.to_bytes(2, "big") + p2s.to_bytes(2, "big")

    # 0x11
    def _ecu_reset(self, p: bytes, t_ns: int) -> bytes | int:
        sub = p[1] & 0x7F
        if sub not in (1, 2, 3):  # hard, key off/on, soft
            return C.SubFunctionNotSupported
        if len(p) != 2:
            return C.IncorrectMessageLengthOrInvalidFormat
        self.stats.resets += 1
        self._enter(DEFAULT)
        self.dtcs.new_operation_cycle()
        for routine in self.routines.values():
            routine.state = 0
        return bytes([sub])

    # 0x3E
    def _tester_present(self, p: bytes, t_ns: int) -> bytes | int:
        if p[1] & 0x7F != 0:
            return C.SubFunctionNotSupported
        if len(p) != 2:
            return C.IncorrectMessageLengthOrInvalidFormat
        return b"\x00"

    # 0x14
    def _clear_dtcs(self, p: bytes, t_ns: int) -> bytes | int:
        if len(p) != 4:
            return C.IncorrectMessageLengthOrInvalidFormat
        group = int.from_bytes(p[1:4], "big")
        if group == 0xFFFFFF:
            numbers = list(self.dtcs.records)
        elif group in self.dtcs.records:
            numbers = [group]
        else:
            return C.RequestOutOfRange
        self.dtcs.clear(numbers, t_ns)
        return b""

    # 0x19
    def _read_dtcs(self, p: bytes, t_ns: int) -> bytes | int:
        sub, dtcs = p[1], self.dtcs
        records = list(dtcs.records.values())
        if sub in (0x01, 0x02):
            if len(p) != 3:
                return C.IncorrectMessageLengthOrInvalidFormat
            match = [r for r in records if r.status & p[2] & AVAILABILITY_MASK]
            if sub == 0x01:  # format 0x01: ISO 14229-1 DTC format
                return bytes([sub, AVAILABILITY_MASK, 0x01]) + len(match).to_bytes(2, "big")
            return bytes([sub, AVAILABILITY_MASK]) + b"".join(_dtc_bytes(r) for r in match)
        if sub == 0x0A:
            if len(p) != 2:
                return C.IncorrectMessageLengthOrInvalidFormat
            return bytes([sub, AVAILABILITY_MASK]) + b"".join(_dtc_bytes(r) for r in records)
        if sub in (0x04, 0x06):
            if len(p) != 6:
                return C.IncorrectMessageLengthOrInvalidFormat
            rec = dtcs.records.get(int.from_bytes(p[2:5], "big"))
            number = p[5]
            if rec is None or number not in ((0x01, 0xFF) if sub == 0x04 else (0x01, 0x02, 0xFF)):
                return C.RequestOutOfRange
            out = bytes([sub]) + _dtc_bytes(rec)
            if sub == 0x04:
                if rec.snapshot is not None:
                    out += bytes([0x01, rec.snapshot_count]) + rec.snapshot
                return out
            if number in (0x01, 0xFF):
                out += bytes([0x01, rec.occurrences])
            if number in (0x02, 0xFF):
                out += bytes([0x02, dtcs.aging_counter(rec, t_ns)])
            return out
        return C.SubFunctionNotSupported

    def _snapshot(self) -> tuple[bytes, int]:
        dids = [self.dids[d] for d in SNAPSHOT_DIDS if d in self.dids]
        return b"".join(d.did.to_bytes(2, "big") + d.value() for d in dids), len(dids)

    # 0x22
    def _read_dids(self, p: bytes, t_ns: int) -> bytes | int:
        n = len(p) - 1
        if n == 0 or n % 2 or n // 2 > self.cfg.max_dids_per_request:
            return C.IncorrectMessageLengthOrInvalidFormat
        out = b""
        for i in range(1, len(p), 2):
            d = self.dids.get(int.from_bytes(p[i:i + 2], "big"))
            if d is not None:
                out += p[i:i + 2] + d.value()
        if not out:
            return C.RequestOutOfRange
        if len(out) + 1 > 4095:
            return C.ResponseTooLong
        return out

    # 0x27
    def _security_access(self, p: bytes, t_ns: int) -> bytes | int:
        sub = p[1] & 0x7F
        if sub not in (1, 2):
            return C.SubFunctionNotSupported
        if len(p) != (2 if sub == 1 else 6):
            return C.IncorrectMessageLengthOrInvalidFormat
        sec = self.security
        result = sec.request_seed(t_ns) if sub == 1 else sec.send_key(t_ns, p[2:6])
        if isinstance(result, int):
            if result == C.ExceedNumberOfAttempts:
                log.warning("uds: security access: %d invalid keys, locked for %g ms",
                            sec.failed, self.cfg.security_delay_ms)
            return result
        return bytes([sub]) + result

    # 0x28
    def _communication_control(self, p: bytes, t_ns: int) -> bytes | int:
        sub = p[1] & 0x7F
        if sub not in (0, 1):  # enableRxAndTx, enableRxAndDisableTx
            return C.SubFunctionNotSupported
        if len(p) != 3:
            return C.IncorrectMessageLengthOrInvalidFormat
        kind, subnet = p[2] & 0x03, p[2] >> 4
        if p[2] & 0x0C or kind == 0 or subnet not in (0x0, 0xF):
            return C.RequestOutOfRange
        if kind & 0x01:  # normal communication messages (the ECU has no network management)
            self.node.set_broadcast(sub == 0)
        return bytes([sub])

    # 0x85
    def _dtc_setting(self, p: bytes, t_ns: int) -> bytes | int:
        sub = p[1] & 0x7F
        if sub not in (1, 2):
            return C.SubFunctionNotSupported
        if len(p) not in (2, 5):
            return C.IncorrectMessageLengthOrInvalidFormat
        if len(p) == 5 and p[2:5] != b"\xff\xff\xff":
            return C.RequestOutOfRange
        if sub == 1:
            self.dtcs.resume()
        else:
            self.dtcs.enabled = False
        return bytes([sub])

    # 0x2E
    def _write_did(self, p: bytes, t_ns: int) -> bytes | int:
        if len(p) < 4:
            return C.IncorrectMessageLengthOrInvalidFormat
        d = self.dids.get(int.from_bytes(p[1:3], "big"))
        if d is None or d.write is None:
            return C.RequestOutOfRange
        if not self.security.unlocked:
            return C.SecurityAccessDenied
        if len(p) != 3 + d.size:
            return C.IncorrectMessageLengthOrInvalidFormat
        value = d.decode(p[3:])
        if value is None:
            return C.RequestOutOfRange
        d.write(value)
        return p[1:3]

    # 0x2F
    def _io_control(self, p: bytes, t_ns: int) -> bytes | int:
        if len(p) < 4:
            return C.IncorrectMessageLengthOrInvalidFormat
        did = int.from_bytes(p[1:3], "big")
        d = self.dids.get(did)
        option = p[3]
        if d is None or d.io is None or option > 3:
            return C.RequestOutOfRange
        if len(p) != (4 + d.size if option == 3 else 4):
            return C.IncorrectMessageLengthOrInvalidFormat
        if not self.security.unlocked:
            return C.SecurityAccessDenied
        if option in (0, 1):  # returnControlToECU, resetToDefault: the ECU's own value again
            own = self.node.own_value(*d.io)  # the sensor's, if a frame came while forced
            self._release(did)
            return p[1:4] + (d.value() if own is None else d.encode(own))
        value = d.read() if option == 2 else d.decode(p[4:])  # freeze / shortTermAdjustment
        if value is None:
            return C.ConditionsNotCorrect if option == 2 else C.RequestOutOfRange
        self.io[did] = float(value)
        self.node.set_override(d.io[0], d.io[1], float(value))
        return p[1:4] + d.encode(value)

    # 0x31
    def _routine_control(self, p: bytes, t_ns: int) -> bytes | int:
        sub = p[1] & 0x7F
        if sub not in (1, 2, 3):
            return C.SubFunctionNotSupported
        if len(p) != 4:
            return C.IncorrectMessageLengthOrInvalidFormat
        routine = self.routines.get(int.from_bytes(p[2:4], "big"))
        if routine is None:
            return C.RequestOutOfRange
        if sub == 1:
            routine.start(t_ns)
            self._awake = True
        elif sub == 2:
            if routine.state != RUNNING:
                return C.RequestSequenceError
            routine.state = STOPPED
        elif routine.state == 0:
            return C.RequestSequenceError
        return bytes([sub]) + p[2:4] + routine.record()

    def summary(self) -> dict:
        """For the run summary: counters and the DTCs that are not clean."""
        from dataclasses import asdict

        return {**asdict(self.stats), "session": self.session,
                "security_unlocked": self.security.unlocked,
                "failed_keys": self.security.failed_total,
                "dtcs": {r.spec.code: r.status for r in self.dtcs.records.values()
                         if r.status & ~0x50}}


def _dtc_bytes(rec: DtcRecord) -> bytes:
    return rec.spec.number.to_bytes(3, "big") + bytes([rec.status & AVAILABILITY_MASK])


def attach_uds(node: EcuNode, config: UdsConfig, seed: int | None) -> UdsServer | None:
    """Serve UDS on `node` (None when ecu.uds.enabled is false); security seeds come from
    `seed` (the named stream 'uds.security': the simulated clock, reproducible), or from the
    OS's entropy when it is None (a live ECU)."""
    if not config.enabled:
        return None
    from vecu.rng import rng_streams

    rng = None if seed is None else rng_streams(seed, ("uds.security",))["uds.security"]
    server = UdsServer(node, config, rng)
    node.attach(server)
    return server
