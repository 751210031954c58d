"""The XCP master of scenarios' [[xcp]] steps, on vecu's clock: it knows the slave's A2L layout
(names -> address, type), sends each step's commands at its time (CONNECT first, then SET_MTA
and DOWNLOADs for a write, SHORT_UPLOAD or SET_MTA + UPLOAD for a read) one at a time, and
judges the answers. Deterministic on the simulated clock: tick() is a 1 ms task before the
ECU's (as the UDS scenario tester). Tests use pyxcp as the master; this one runs scenarios.
"""

from __future__ import annotations

import math
import struct
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import can

from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.xcp.config import XcpConfig, XcpStep

NO_RESPONSE_MS = 100.0
ERRORS = {0x10: "ERR_CMD_BUSY", 0x11: "ERR_DAQ_ACTIVE", 0x20: "ERR_CMD_UNKNOWN",
          0x21: "ERR_CMD_SYNTAX", 0x22: "ERR_OUT_OF_RANGE", 0x23: "ERR_WRITE_PROTECTED",
          0x24: "ERR_ACCESS_DENIED", 0x25: "ERR_ACCESS_LOCKED", 0x26: "ERR_PAGE_NOT_VALID",
          0x27: "ERR_MODE_NOT_VALID", 0x28: "ERR_SEGMENT_NOT_VALID", 0x29: "ERR_SEQUENCE",
          0x2A: "ERR_DAQ_CONFIG", 0x30: "ERR_MEMORY_OVERFLOW", 0x31: "ERR_GENERIC"}
Layout = dict[str, tuple[int, str]]  # name -> (address, struct code)


@dataclass
class XcpStepResult:
    step: XcpStep
    error: str | None = None
    value: float | None = None
    latency_ms: float | None = None
    done: bool = False
    commands: deque[tuple[bytes, str]] = field(default_factory=deque)  # (CTO, role)
    sent_ns: int | None = None
    started_ns: int | None = None
    raw: bytes = b""

    def judge(self) -> tuple[bool, str, str]:
        s = self.step
        got = (f"error {self.error}" if self.error else
               "no response" if not self.done else
               "written" if self.value is None else f"{self.value:g}")
        wants, ok = [], self.done
        if s.expect_error is not None:
            wants.append(s.expect_error)
            ok &= self.error == s.expect_error
        else:
            ok &= self.error is None
            if s.expect is not None:
                wants.append(f"{s.expect:g} +- {s.tolerance:g}")
                ok &= self.value is not None and abs(self.value - s.expect) <= s.tolerance
            if s.expect_min is not None:
                wants.append(f">= {s.expect_min:g}")
                ok &= self.value is not None and self.value >= s.expect_min
            if s.expect_max is not None:
                wants.append(f"<= {s.expect_max:g}")
                ok &= self.value is not None and self.value <= s.expect_max
            if not wants:
                wants.append("accepted")
        return bool(ok), got, ", ".join(wants)

    def as_dict(self) -> dict[str, Any]:
        passed, got, want = self.judge()
        s = self.step
        what = " ".join(x for x in (f"write {s.write}={s.value:g}" if s.write else "",
                                    f"read {s.read}" if s.read else "") if x)
        return {"at_s": s.at_s, "step": what, "got": got, "expected": want, "passed": passed,
                "latency_ms": self.latency_ms}


class SimXcpMaster:
    """Runs `steps` (sorted by time) against the slave on `bus`; `layout`: the A2L's names."""

    def __init__(self, bus: can.BusABC, config: XcpConfig, layout: Layout,
                 steps: tuple[XcpStep, ...]) -> None:
        self.bus = bus
        self.cfg = config
        self.layout = layout
        self.results = [XcpStepResult(s) for s in sorted(steps, key=lambda s: s.at_s)]
        self._next = 0
        self._active: deque[XcpStepResult] = deque()
        self._connected = False
        self._waiting: XcpStepResult | None = None

    def _plan(self, res: XcpStepResult) -> None:
        s = res.step
        if not self._connected:
            res.commands.append((b"\xff\x00", "connect"))
            self._connected = True
        if s.write is not None:
            address, code = self.layout[s.write]
            value: Any = s.value
            if code in "iIBH":
                value = round(value)
            data = struct.pack("<" + code, value)
            res.commands.append((b"\xf6\x00\x00\x00" + struct.pack("<I", address), "mta"))
            for i in range(0, len(data), 6):
                chunk = data[i:i + 6]
                res.commands.append((bytes([0xF0, len(chunk)]) + chunk, "write"))
        if s.read is not None:
            address, code = self.layout[s.read]
            size = struct.calcsize(code)
            if size <= 7:
                res.commands.append((bytes([0xF4, size, 0, 0]) + struct.pack("<I", address),
                                     "read:" + code))
            else:
                res.commands.append((b"\xf6\x00\x00\x00" + struct.pack("<I", address), "mta"))
                res.commands.append((bytes([0xF5, size]), "read:" + code))

    def tick(self, t_ns: int) -> None:
        while (msg := self.bus.recv(0.0)) is not None:
            if msg.arbitration_id == self.cfg.slave_id and self._waiting is not None:
                self._answer(bytes(msg.data), t_ns)
        results = self.results
        while self._next < len(results) and round(results[self._next].step.at_s * NS_PER_S) <= t_ns:
            res = results[self._next]
            self._next += 1
            res.started_ns = t_ns
            self._plan(res)
            self._active.append(res)
        waiting = self._waiting
        if waiting is not None and t_ns - waiting.sent_ns > NO_RESPONSE_MS * NS_PER_MS:  # type: ignore[operator]  # set when the command went out
            waiting.done, self._waiting = False, None  # no response: judged as such
            waiting.commands.clear()
            self._active.popleft()
        if self._waiting is None and self._active:
            waiting = self._active[0]
            cto, _ = waiting.commands[0]
            self.bus.send(can.Message(arbitration_id=self.cfg.master_id, data=cto,
                                      is_extended_id=False, timestamp=t_ns / NS_PER_S))
            waiting.sent_ns = t_ns
            self._waiting = waiting

    def _answer(self, packet: bytes, t_ns: int) -> None:
        res = self._waiting
        assert res is not None
        _, role = res.commands.popleft()
        if packet[:1] == b"\xfe":
            res.error = ERRORS.get(packet[1], f"0x{packet[1]:02X}") if len(packet) > 1 else "?"
            res.commands.clear()
        elif role.startswith("read:"):
            code = role[5:]
            size = struct.calcsize(code)
            res.raw += packet[1:1 + size - len(res.raw)]
            if len(res.raw) < size:  # block mode: more responses follow
                res.commands.appendleft((b"", role))
                return
            value = struct.unpack("<" + code, res.raw)[0]
            res.value = float(value) if not isinstance(value, float) or math.isfinite(value) \
                else value
        self._waiting = None
        if not res.commands:
            res.done = True
            res.latency_ms = (t_ns - res.started_ns) / NS_PER_MS  # type: ignore[operator]  # set when the command went out
            self._active.popleft()

    def summary(self) -> list[dict[str, Any]]:
        return [r.as_dict() for r in self.results]


def layout_of(server: Any) -> Layout:
    """Names -> (address, struct code) of an XcpServer's A2L (scalars: VALUEs, measurements)."""
    out: Layout = {leaf.name: (leaf.address, leaf.code)
                   for leaf in server.segment.leaves if leaf.count == 1}
    out.update({m.name: (m.address, m.code) for m in server.measurements})
    return out
