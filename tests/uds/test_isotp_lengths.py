"""Every request length 1..4095 from a tester that sends as fast as the ECU's
flow control allows (can-isotp, STmin 0) gets the answer ISO 14229 owes, while the 1 ms
broadcast keeps every tick; what the ECU cannot take gets a flow control overflow, never
silence. Simulated clock; the live sweep (can-isotp and scapy) is tests/live/test_isotp_live.py."""

from __future__ import annotations

import can
import pytest

from tests.uds.isotp_sweep import MAX_LENGTH, expected, request
from vecu.assembly import TICK_NS, build_functions, schedule_ecu
from vecu.bus import open_bus
from vecu.clock import SimClock
from vecu.codec import DbcCodec
from vecu.config import RunConfig
from vecu.ecu.node import EcuNode
from vecu.scheduler import Scheduler
from vecu.uds.server import attach_uds
from vecu.uds.transport import Endpoint, to_can


class EcuAlone:
    """The ECU (throttle function, UDS) alone on a virtual channel with a can-isotp tester:
    the plant is not needed for transport, and leaving it out keeps 4095 sweeps fast."""

    def __init__(self, channel: str) -> None:
        config = RunConfig(duration_s=600.0, kill_tps_at_s=None, speed=False, steering=False,
                           manifold=False)
        self.buses = [open_bus("virtual", channel) for _ in range(2)]
        self.fns = build_functions(config, DbcCodec())
        self.ecu = EcuNode(self.buses[0], DbcCodec(), self.fns.enabled())
        self.uds = attach_uds(self.ecu, config.params.ecu.uds, config.seed)
        self.sched = Scheduler(SimClock())
        schedule_ecu(self.sched, self.ecu)
        self.t_ns = 0
        self.tester = Endpoint(0x7E8, 0x7E0, lambda: self.t_ns)  # can-isotp, STmin 0, BS 0
        self.flow_controls: list[bytes] = []  # the ECU's FC frames (PCI byte, BS, STmin)

    def step(self) -> None:
        self.t_ns += TICK_NS
        self.sched.run_until(self.t_ns)

    def exchange(self, payload: bytes, max_ticks: int = 200) -> tuple[list[bytes], int]:
        """Send `payload` at full speed; (the answers, ticks until the first)."""
        bus, tester = self.buses[1], self.tester
        tester.send(payload)
        answers: list[bytes] = []
        for ticks in range(max_ticks):
            while (msg := bus.recv(0.0)) is not None:
                if msg.arbitration_id == 0x7E8:
                    if msg.data[0] >> 4 == 3:
                        self.flow_controls.append(bytes(msg.data[:3]))
                    tester.put(msg)
            tester.process()
            while tester.out:
                bus.send(to_can(tester.out.popleft()))
            answers += tester.payloads()
            if answers:
                return answers, ticks
            sent = self.fns.throttle.estimates_sent
            self.step()
            assert self.fns.throttle.estimates_sent == sent + 1, "a tick without its broadcast"
        return answers, max_ticks

    def close(self) -> None:
        for bus in self.buses:
            bus.shutdown()


def test_every_length_from_1_to_4095_gets_its_answer_at_full_speed():
    run = EcuAlone("isotp-sweep")
    try:
        run.step()
        wrong = {}
        slowest = 0
        for length in range(1, MAX_LENGTH + 1):
            answers, ticks = run.exchange(request(length))
            if answers != [expected(length)]:
                wrong[length] = answers
            slowest = max(slowest, ticks)
        assert wrong == {}
        stats = run.uds.stats
        assert stats.requests == MAX_LENGTH and stats.responses == MAX_LENGTH
        assert stats.frames_dropped == 0 and stats.transport_errors == 0
        assert stats.requests_dropped == 0
        # 585 consecutive frames in blocks of 16, one block a tick: 37 blocks, ~40 ms
        assert slowest <= 45
    finally:
        run.close()


def test_a_request_longer_than_4095_bytes_gets_a_flow_control_overflow():
    """ISO 15765-2: a first frame announcing more than the receiver can take is answered with
    FC overflow (flow status 2), so the sender aborts at once instead of waiting for an answer
    that never comes. 4096 bytes: the escape first frame (length 0 in 12 bits, then 32 bits)."""
    run = EcuAlone("isotp-overflow")
    try:
        run.step()
        bus = run.buses[1]
        first = bytes([0x10, 0x00]) + (4096).to_bytes(4, "big") + b"\x22\xf1"
        bus.send(can.Message(arbitration_id=0x7E0, data=first, is_extended_id=False))
        run.step()
        got = [bytes(m.data) for m in iter(lambda: bus.recv(0.0), None)
               if m.arbitration_id == 0x7E8]
        assert [g[:1] for g in got] == [b"\x32"]  # FC, flow status 2: overflow
        answers, _ = run.exchange(request(33))  # and the next request is answered as ever
        assert answers == [expected(33)]
    finally:
        run.close()


@pytest.mark.parametrize("request_hex,want", [
    ("22" + "F190" * 16, "62" + ("F190" + b"1VECU00SIM0000001".hex()) * 16),  # 33 bytes
    ("22" + "00" * 999, "7F2213"),    # odd DID bytes
    ("22" + "F190" * 2047, "7F2213"),  # 4095 bytes: more DIDs than max_dids_per_request
])
def test_the_ecus_flow_control_paces_a_long_request_in_blocks_of_16(request_hex, want):
    """FC CTS, BS 16 (= ecu.uds.frames_per_tick // 2), STmin 0, once per block: with BS 0
    ("send everything") a 4095-byte request overran the ECU's 128-frame inbox, no answer."""
    run = EcuAlone("isotp-fc")
    try:
        run.step()
        answers, _ = run.exchange(bytes.fromhex(request_hex), max_ticks=400)
        assert answers == [bytes.fromhex(want)]
        assert run.uds is not None
        assert run.uds.stats.frames_dropped == 0 and run.uds.stats.transport_errors == 0
        cfs = -(-(len(request_hex) // 2 - 6) // 7)
        assert run.flow_controls == [bytes([0x30, 16, 0])] * -(-cfs // 16)
    finally:
        run.close()
