"""The gateway's CAN side on the simulated clock: the plant and two real vecu ECUs with their UDS
servers (ECU A at 0x7E0/0x7E8, ECU B at 0x7E1/0x7E9 through the parameter tree), the DiagRouter
on its own python-can bus, and small ISO-TP responders (can-isotp) for what vecu's ECUs never do
(0x78 response-pending, other addressing formats). A test is the tester: it submits requests
and steps the clock."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import can
import isotp

from tests.uds.sim import SimRun
from vecu.assembly import PRIO_ECU, TICK_NS, build_functions, schedule_ecu
from vecu.bus import BusNode
from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.config import RunConfig
from vecu.ecu.node import EcuNode
from vecu.gateway.config import EcuRoute, GatewayConfig, default_config
from vecu.gateway.router import DiagRouter
from vecu.uds.server import UdsServer, attach_uds
from vecu.uds.transport import Endpoint, to_can

TESTER = 0x0E00
VIN_A, VIN_B, VIN_GW = "1VECU00SIM000000A", "1VECU00SIM000000B", "1VECU00GATEWAY001"


def throttle_only(**sets: object) -> RunConfig:
    return RunConfig(duration_s=600.0, kill_tps_at_s=None, speed=False, steering=False,
                     manifold=False).with_params(sets)


class Responder:
    """A UDS server stand-in built on can-isotp: each request is answered by `answer(request)`
    (a list of (delay_ms, response) steps; 0x78 response-pending steps included)."""

    def __init__(self, bus: can.BusABC, address: isotp.Address, now: Callable[[], int],
                 answer: Callable[[bytes], list[tuple[float, bytes]]]) -> None:
        self.bus, self.answer = bus, answer
        self.ep = Endpoint(0, 0, now, address=address)
        self.requests: list[bytes] = []
        self._due: list[tuple[int, bytes]] = []

    def tick(self, t_ns: int) -> None:
        while (msg := self.bus.recv(0.0)) is not None:
            self.ep.put(msg)
        self.ep.process()
        for request in self.ep.payloads():
            self.requests.append(request)
            self._due += [(t_ns + round(ms * NS_PER_MS), r) for ms, r in self.answer(request)]
        while self._due and self._due[0][0] <= t_ns:
            self.ep.send(self._due.pop(0)[1])
        self.ep.process()
        while self.ep.out:
            self.bus.send(to_can(self.ep.out.popleft(), t_ns / NS_PER_S))


class GatewaySim:
    """Plant, ECU A and ECU B, the router (and responders) on one virtual channel."""

    def __init__(self, config: GatewayConfig | None = None, *, ecu_b: bool = True,
                 routes: tuple[EcuRoute, ...] = ()) -> None:
        self.run = SimRun(throttle_only(**{"ecu.uds.vin": VIN_A}))
        run = self.run
        self.now = 0
        self.ecu_b: EcuNode | None = None
        self.uds_b: UdsServer | None = None
        if ecu_b:
            cfg_b = throttle_only(**{"ecu.uds.request_id": 0x7E1, "ecu.uds.response_id": 0x7E9,
                                     "ecu.uds.vin": VIN_B})
            self.ecu_b = EcuNode(run.bus(), run.codec, build_functions(cfg_b, run.codec).enabled())
            self.uds_b = attach_uds(self.ecu_b, cfg_b.params.ecu.uds, cfg_b.seed)
            schedule_ecu(run.sched, self.ecu_b)
        base = config or default_config()
        self.config = replace(base, vin=VIN_GW, ecus=base.ecus + routes)
        self.node = BusNode(run.bus(), "gateway")
        self.router = DiagRouter(self.node, self.config, lambda: self.now)
        self.listener = run.bus()  # what the requests caused on the bus
        run.sched.every(TICK_NS, self._tick, name="gateway", priority=PRIO_ECU + 5)
        self.replies: list[tuple[int, bytes]] = []

    def _tick(self, t_ns: int) -> None:
        self.now = t_ns
        self.router.step(t_ns)

    def responder(self, address: isotp.Address,
                  answer: Callable[[bytes], list[tuple[float, bytes]]]) -> Responder:
        peer = Responder(self.run.bus(), address, lambda: self.now, answer)
        self.run.sched.every(TICK_NS, peer.tick, name="responder", priority=PRIO_ECU)
        return peer

    def step(self, ms: int = 1) -> None:
        self.run.step(ms)

    def submit(self, target: int, request: bytes | str, source: int = TESTER,
               into: list[tuple[int, bytes]] | None = None) -> int | None:
        payload = bytes.fromhex(request) if isinstance(request, str) else request
        out = self.replies if into is None else into
        return self.router.submit(source, target, payload,
                                  lambda sa, uds: out.append((sa, bytes(uds))))

    def ask(self, target: int, request: bytes | str, max_ms: int = 200) -> list[tuple[int, bytes]]:
        """Submit, then step until a final (not 0x78) response came or max_ms passed: every
        reply, in order."""
        self.replies = []
        assert self.submit(target, request) is None
        for _ in range(max_ms):
            self.step()
            if self.replies and not _pending(self.replies[-1][1]):
                break
        return self.replies

    def collect(self, target: int, request: bytes | str, ms: int) -> list[tuple[int, bytes]]:
        self.replies = []
        assert self.submit(target, request) is None
        self.step(ms)
        return self.replies

    def frames(self) -> list[can.Message]:
        """The diagnostic frames (0x7C0-0x7FF, ISO-TP's other IDs of the tests) seen since the
        last call, in bus order."""
        out = []
        while (msg := self.listener.recv(0.0)) is not None:
            if msg.arbitration_id & 0x7C0 == 0x7C0 or msg.arbitration_id in (0x6F0, 0x6F8) \
                    or msg.arbitration_id >> 16 == 0x18DA:
                out.append(msg)
        return out

    def close(self) -> None:
        self.run.close()


def _pending(uds: bytes) -> bool:
    return len(uds) == 3 and uds[0] == 0x7F and uds[2] == 0x78
