"""The ECU alone (throttle function and UDS) with diagnostic faults, and a reference tester on
the simulated clock: can-isotp (vecu.uds.transport's clocked can-isotp, so N_Bs / N_Cr run on
the same clock as the ECU) for the transport, udsoncan's Response for the answers, P2 / P2*
as ISO 14229-2 asks. Every frame on the bus is kept with its simulated time (1 ms ticks)."""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import can
from udsoncan import Response

from vecu.assembly import TICK_NS, build_functions, schedule_ecu
from vecu.bus import open_bus
from vecu.clock import NS_PER_MS, SimClock
from vecu.codec import DbcCodec
from vecu.config import RunConfig
from vecu.ecu.node import EcuNode
from vecu.scheduler import Scheduler
from vecu.uds.diag_faults.engine import EcuDiagFaults, attach_diag_faults
from vecu.uds.diag_faults.setting import DiagFaultSetting
from vecu.uds.server import attach_uds
from vecu.uds.transport import Endpoint, to_can

REQ, RSP, FUNC = 0x7E0, 0x7E8, 0x7DF
SPR_REQUEST = bytes([0x3E, 0x80])
LONG_REQUEST = bytes([0x22, 0xF1, 0x90, 0xF1, 0x8C, 0xF1, 0x95, 0xF1, 0x86])  # FF + CF
FUNCTIONAL_REQUEST = bytes([0x22, 0xF1, 0x90])  # each ECU: 20 bytes, FF + 2 CF
P2_CLIENT_MS, P2_STAR_CLIENT_MS, GIVE_UP_MS = 1000, 5000, 3000
_channels = itertools.count()


@dataclass
class Exchange:
    request: bytes
    sent_ms: float | None = None
    answers: list[tuple[float, bytes]] = field(default_factory=list)  # every payload, in order
    final: bytes | None = None
    error: str = ""  # "timeout", "transport", ...


@dataclass
class Seen:
    t_ms: float
    msg: can.Message

    @property
    def id(self) -> int:
        return self.msg.arbitration_id

    @property
    def data(self) -> bytes:
        return bytes(self.msg.data)

    @property
    def pci(self) -> int:
        return self.msg.data[0] >> 4 if self.msg.data else -1


class FaultedEcu:
    def __init__(self, settings: list[DiagFaultSetting], wftmax: int = 10) -> None:
        channel = f"conformance-{next(_channels)}"
        config = RunConfig(duration_s=600.0, kill_tps_at_s=None, speed=False, steering=False,
                           manifold=False)
        self.buses = [open_bus("virtual", channel) for _ in range(3)]
        self.codec = DbcCodec()
        fns = build_functions(config, self.codec)
        self.ecu = EcuNode(self.buses[0], self.codec, fns.enabled())
        uds = attach_uds(self.ecu, config.params.ecu.uds, config.seed)
        assert uds is not None
        self.uds = uds
        engine = attach_diag_faults(uds, settings)
        assert engine is not None
        self.engine: EcuDiagFaults = engine
        self.sched = Scheduler(SimClock())
        schedule_ecu(self.sched, self.ecu)
        self.t_ns = 0
        now = lambda: self.t_ns  # noqa: E731
        params = {"wftmax": wftmax}
        self.rx = {RSP + k: Endpoint(RSP + k, REQ + k, now, params=params,
                                     errors=self._error) for k in range(8)}
        self.func = Endpoint(0x7FF, FUNC, now)
        self.frames: list[Seen] = []
        self.errors: list[str] = []

    def _error(self, exc: Exception) -> None:
        self.errors.append(type(exc).__name__)

    def close(self) -> None:
        for bus in self.buses:
            bus.shutdown()

    @property
    def now_ms(self) -> float:
        return self.t_ns / NS_PER_MS

    def step(self) -> list[tuple[int, bytes]]:
        """One tick: the ECU, then the tester's transport; the payloads the tester received."""
        self.t_ns += TICK_NS
        self.sched.run_until(self.t_ns)
        tester_bus, capture = self.buses[1], self.buses[2]
        while (msg := capture.recv(0.0)) is not None:
            self.frames.append(Seen(self.now_ms, msg))
        while (msg := tester_bus.recv(0.0)) is not None:
            ep = self.rx.get(msg.arbitration_id)
            if ep is not None:
                ep.put(msg)
        got = []
        for rid, ep in (*self.rx.items(), (0, self.func)):
            ep.process()
            while ep.out:
                tester_bus.send(to_can(ep.out.popleft(), self.t_ns / 1e9))
            got += [(rid, p) for p in ep.payloads()]
        return got

    def idle(self, ms: float) -> list[tuple[int, bytes]]:
        got = []
        for _ in range(round(ms)):
            got += self.step()
        return got

    def request(self, payload: bytes, repeat_busy: int = 3) -> Exchange:
        """A physical request as ISO 14229-2 asks of a client: the final answer within P2client,
        each 0x78 restarting the wait with P2*client; 0x21: repeat (at most repeat_busy)."""
        ex = Exchange(payload)
        self.rx[RSP].send(payload)
        start, errors = self.t_ns, len(self.errors)
        while self.rx[RSP].layer.transmitting():
            self.step()
            if self.t_ns - start > 2000 * NS_PER_MS:
                break
        if len(self.errors) > errors or self.rx[RSP].layer.transmitting():
            ex.error = "transport"  # can-isotp gave up the request (OVFLW, N_Bs, WAITs)
            return ex
        ex.sent_ms = self.now_ms
        deadline, give_up = self.now_ms + P2_CLIENT_MS, self.now_ms + GIVE_UP_MS
        while self.now_ms < min(deadline, give_up):
            for rid, p in self.step():
                if rid != RSP:
                    continue
                ex.answers.append((self.now_ms, p))
                if p[:1] == b"\x7f" and len(p) >= 3 and p[1] == payload[0] and p[2] == 0x78:
                    deadline = self.now_ms + P2_STAR_CLIENT_MS
                    continue
                if p[:1] == b"\x7f" and len(p) >= 3 and p[2] == 0x21 and repeat_busy:
                    again = self.request(payload, repeat_busy - 1)
                    again.answers[:0] = ex.answers
                    return again
                if p[0] not in (payload[0] + 0x40, 0x7F):
                    continue  # not an answer to this request (unsolicited / suppressed)
                ex.final = p
                return ex
        ex.error = "timeout"
        return ex

    def functional(self, payload: bytes, listen_ms: float = P2_CLIENT_MS) -> list[tuple[int, bytes]]:
        self.func.send(payload, functional=True)
        return self.idle(listen_ms)

    # --------------------------------------------------------------- evidence
    def on(self, can_id: int, after_ms: float = 0.0) -> list[Seen]:
        return [f for f in self.frames if f.id == can_id and f.t_ms >= after_ms]

    def fi_events(self) -> list[dict[str, float]]:
        fc = self.codec["FI_Event"]
        return [fc.decode(f.data) for f in self.frames if f.id == fc.frame_id]

    def check(self, response: bytes) -> Response:
        return Response.from_payload(response)
