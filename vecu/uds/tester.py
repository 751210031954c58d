"""A UDS tester on vecu's clock for scenarios: sends each step's request at its time over
can-isotp, collects the responses (request -> response latency on the same clock).

Deterministic on the simulated clock: schedule tick() as a 1 ms task before the ECU's."""

from __future__ import annotations

from dataclasses import dataclass

import can

from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.uds.config import UdsConfig, UdsStep
from vecu.uds.security import key_from_seed
from vecu.uds.transport import Endpoint, to_can

NO_RESPONSE_MS = 500.0  # a step without a final response after this has none
P2_STAR_MS = 5000.0     # after a 0x78: the wait restarts with P2* (ISO 14229-2 §7.2)


@dataclass
class StepResult:
    step: UdsStep
    sent_ns: int | None = None
    response: bytes | None = None
    latency_ms: float | None = None
    done: bool = False
    pending_ns: int | None = None  # the last 0x78 (response pending) for it

    def as_dict(self) -> dict:
        passed, _, want = self.step.judge(self.response)
        return {"at_s": self.step.at_s, "request": self.step.request.hex(" "),
                "response": None if self.response is None else self.response.hex(" "),
                "latency_ms": self.latency_ms, "passed": passed, "expected": want}


class SimTester:
    """Sends `steps` (sorted by time) on `bus` and records the responses."""

    def __init__(self, bus: can.BusABC, config: UdsConfig, steps: tuple[UdsStep, ...]) -> None:
        self.bus = bus
        self._now = 0
        now = self._now_ns
        self.phys = Endpoint(config.response_id, config.request_id, now)
        self.func = Endpoint(config.response_id, config.functional_id, now)
        self._rx_id = config.response_id
        self.results = [StepResult(s) for s in sorted(steps, key=lambda s: s.at_s)]
        self._next = 0
        self._waiting: list[StepResult] = []
        self._seed = b""

    def _now_ns(self) -> int:
        return self._now

    def tick(self, t_ns: int) -> None:
        self._now = t_ns
        phys = self.phys
        while (msg := self.bus.recv(0.0)) is not None:
            if msg.arbitration_id == self._rx_id and not msg.is_error_frame:
                phys.put(msg)
        phys.process()
        for payload in phys.payloads():
            self._answer(payload, t_ns)
        for res in list(self._waiting):
            since, limit = ((res.sent_ns, NO_RESPONSE_MS) if res.pending_ns is None
                            else (res.pending_ns, P2_STAR_MS))
            if t_ns - since > limit * NS_PER_MS:  # type: ignore[operator]  # waiting: sent, so sent_ns is set
                res.done = True
                self._waiting.remove(res)
        results = self.results
        while self._next < len(results) and round(results[self._next].step.at_s * NS_PER_S) <= t_ns:
            res = results[self._next]
            self._next += 1
            step = res.step
            request = step.request + (key_from_seed(self._seed) if step.key else b"")
            (self.func if step.functional else phys).send(request, functional=step.functional)
            res.sent_ns = t_ns
            self._waiting.append(res)
        phys.process()
        self.func.process()
        ts = t_ns / NS_PER_S
        for ep in (phys, self.func):
            while ep.out:
                self.bus.send(to_can(ep.out.popleft(), ts))

    def _answer(self, payload: bytes, t_ns: int) -> None:
        if payload[:1] == b"\x7f" and payload[2:3] == b"\x78":  # response pending: wait on
            for waiting in self._waiting:
                if waiting.step.request[:1] == payload[1:2]:
                    waiting.pending_ns = t_ns
            return
        if payload[:2] == b"\x67\x01":
            self._seed = payload[2:6]
        sid = payload[1] if payload[:1] == b"\x7f" and len(payload) > 1 else payload[0] - 0x40
        res = next((r for r in self._waiting if r.step.request[:1] == bytes([sid & 0xFF])), None)
        if res is None:
            return  # unsolicited, or for a request given up on
        self._waiting.remove(res)
        res.response = payload
        res.latency_ms = (t_ns - res.sent_ns) / NS_PER_MS  # type: ignore[operator]  # waiting: sent, so sent_ns is set
        res.done = True

    def summary(self) -> list[dict]:
        return [r.as_dict() for r in self.results]
