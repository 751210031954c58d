"""The gateway's CAN side: requests by logical address through ISO-TP to two real vecu ECUs (and
can-isotp responders for what they never do), on the simulated clock. Responses are decoded with
udsoncan; what the router did is checked on the bus and in its summary."""

from __future__ import annotations

import struct

import isotp
import pytest
import udsoncan
from udsoncan import Response, services

from tests.gateway.sim import TESTER, VIN_A, VIN_B, VIN_GW, GatewaySim
from tests.uds.sim import DIDS
from vecu.faults import FaultTarget
from vecu.gateway.config import MAX_UDS_BYTES, EcuRoute, default_config
from vecu.gateway.diag import DID_ROUTE_COUNTERS, DID_ROUTES, DID_SESSION, DID_VIN
from vecu.gateway.router import Nack

ECU_A, ECU_B, GW, FUNC = 0x0010, 0x0011, 0x1000, 0xE400
SLOW, SILENT, FIXED, EXT, STALL = 0x0012, 0x0013, 0x0014, 0x0015, 0x0016
ROUTES = (EcuRoute("slow", SLOW, 0x7E2, 0x7EA, p2_ms=50.0, p2_star_ms=300.0),
          EcuRoute("silent", SILENT, 0x7E3, 0x7EB),
          EcuRoute("fixed", FIXED, 0x18DA40F1, 0x18DAF140, "normal_fixed_29bit",
                   target_address=0x40),
          EcuRoute("ext", EXT, 0x6F0, 0x6F8, "extended", target_address=0x55),
          EcuRoute("stall", STALL, 0x7E4, 0x7EC, p2_ms=50.0, p2_star_ms=300.0))


class Rows(udsoncan.DidCodec):
    """A gateway DID of `count` + rows (docs/gateway.md): the rows as tuples."""

    def __init__(self, fmt: str) -> None:
        self.fmt = ">" + fmt

    def decode(self, data: bytes) -> list[tuple[int, ...]]:  # type: ignore[override]  # rows, not one value
        size = struct.calcsize(self.fmt)
        assert len(data) == 1 + data[0] * size
        return [struct.unpack_from(self.fmt, data, 1 + i * size) for i in range(data[0])]

    def __len__(self) -> int:
        raise udsoncan.DidCodec.ReadAllRemainingData


GW_DIDS = {DID_VIN: DIDS[0xF190], DID_SESSION: DIDS[0xF186], DID_ROUTES: Rows("HBIIB"),
           DID_ROUTE_COUNTERS: Rows("HIIIIII")}


def read_dids(payload: bytes, dids: list[int], codecs=None) -> dict[int, object]:
    response = Response.from_payload(payload)
    assert response.positive, payload.hex(" ")
    return services.ReadDataByIdentifier.interpret_response(
        response, dids, {**DIDS, **(codecs or {})}).service_data.values


def nrc(payload: bytes) -> int:
    response = Response.from_payload(payload)
    assert not response.positive
    return response.code


def slow_answer(pendings: int):
    """0x78 `pendings` times, 40 ms apart, then the answer 40 ms later (each gap < P2)."""
    def answer(request: bytes) -> list[tuple[float, bytes]]:
        steps = [(40.0 * (i + 1), bytes([0x7F, request[0], 0x78])) for i in range(pendings)]
        return [*steps, (40.0 * (pendings + 1), bytes([request[0] + 0x40]) + request[1:3]
                         + b"\xab" * 3000)]
    return answer


@pytest.fixture(scope="module")
def gw():
    sim = GatewaySim(routes=ROUTES)
    sim.slow = sim.responder(isotp.Address(isotp.AddressingMode.Normal_11bits, txid=0x7EA,
                                           rxid=0x7E2), slow_answer(2))
    sim.step(50)
    yield sim
    sim.close()


def test_each_ecu_answers_at_its_logical_address_and_the_bus_shows_the_iso_tp(gw):
    gw.frames()
    a = gw.ask(ECU_A, "22 F1 90")
    b = gw.ask(ECU_B, "22 F1 90")
    assert [sa for sa, _ in a] == [ECU_A] and [sa for sa, _ in b] == [ECU_B]
    assert read_dids(a[0][1], [0xF190]) == {0xF190: VIN_A}
    assert read_dids(b[0][1], [0xF190]) == {0xF190: VIN_B}
    frames = [(m.arbitration_id, bytes(m.data)) for m in gw.frames()]
    # SF request, FF response (20 bytes), the gateway's flow control, CFs: per ECU
    assert frames[0] == (0x7E0, bytes.fromhex("03 22 F1 90 CC CC CC CC"))
    assert frames[1][0] == 0x7E8 and frames[1][1][:2] == b"\x10\x14"
    assert frames[2] == (0x7E0, bytes.fromhex("30 00 00 CC CC CC CC CC"))
    assert [i for i, _ in frames[3:5]] == [0x7E8, 0x7E8]
    assert frames[5] == (0x7E1, bytes.fromhex("03 22 F1 90 CC CC CC CC"))
    assert gw.uds_b is not None and gw.uds_b.stats.requests >= 1


def test_a_multi_frame_dtc_report_and_a_long_did_read_come_back_whole(gw):
    gw.run.kill(FaultTarget.TPS)
    gw.step(200)
    report = gw.ask(ECU_A, "19 0A")
    assert len(report) == 1 and len(report[0][1]) > 7  # multi-frame
    dtcs = services.ReadDTCInformation.interpret_response(
        Response.from_payload(report[0][1]), subfunction=0x0A).service_data.dtcs
    assert {d.id for d in dtcs} >= {0x012200, 0x012300, 0x012087, 0xC00100}
    assert next(d for d in dtcs if d.id == 0x012200).status.confirmed
    confirmed = gw.ask(ECU_B, "19 02 08")
    assert [d.id for d in services.ReadDTCInformation.interpret_response(
        Response.from_payload(confirmed[0][1]), subfunction=0x02).service_data.dtcs] == [0x012200]
    many = [0xF190, 0xF18C, 0xF195, 0xF186, 0x0001, 0x0100, 0x0101, 0x0102, 0x0103, 0x0104,
            0x0105, 0x010F]
    got = gw.ask(ECU_A, "22" + "".join(f"{d:04X}" for d in many))
    values = read_dids(got[0][1], many)
    assert values[0xF190] == VIN_A and values[0xF18C] == "VECU-00001"
    assert values[0x0105] != 0  # the dead TPS' status


def test_a_functional_request_collects_every_ecus_answer_and_the_gateways(gw):
    gw.frames()
    got = gw.collect(FUNC, "22 F1 90", 120)
    vins = {sa: read_dids(uds, [0xF190])[0xF190] for sa, uds in got}
    assert vins == {GW: VIN_GW, ECU_A: VIN_A, ECU_B: VIN_B}
    assert len(got) == 3
    sent = [(m.arbitration_id, bytes(m.data)) for m in gw.frames()
            if m.arbitration_id in (0x7DF, 0x7E2, 0x7E3)]
    assert sent == [(0x7DF, bytes.fromhex("03 22 F1 90 CC CC CC CC"))]  # one single frame
    row = gw.router.summary().functional
    assert row.requests >= 1 and row.responses >= 2
    # unsupported functional requests get no negative response (ISO 14229-1 7.5), from anyone
    assert gw.collect(FUNC, "22 12 34", 120) == []
    assert gw.collect(FUNC, "3E 80", 120) == []


def test_response_pending_is_relayed_and_the_gateway_waits_p2_star(gw):
    before = gw.router.summary().routes[2]
    got = gw.ask(SLOW, "22 01 02", max_ms=400)
    assert [sa for sa, _ in got] == [SLOW] * 3
    assert [nrc(uds) for _, uds in got[:2]] == [0x78, 0x78]
    final = Response.from_payload(got[2][1])
    assert final.positive and len(final.get_payload()) == 3 + 3000  # multi-frame, 3 kB
    after = gw.router.summary().routes[2]
    assert after.pending_relayed - before.pending_relayed == 2
    assert after.responses - before.responses == 1 and after.timeouts == before.timeouts
    assert after.latency_max_ms is not None and after.latency_max_ms >= 120  # > P2 (50 ms)


def test_after_response_pending_an_ecu_that_stalls_times_out_at_p2_star(gw):
    gw.responder(isotp.Address(isotp.AddressingMode.Normal_11bits, txid=0x7EC, rxid=0x7E4),
                 lambda r: [(10.0, bytes([0x7F, r[0], 0x78]))])
    stalls = lambda: gw.router.summary().routes[6]  # noqa: E731
    assert gw.collect(STALL, "31 01 02 01", 250) == [(STALL, b"\x7f\x31\x78")]
    assert stalls().timeouts == 0  # 240 ms after the 0x78: well past P2, inside P2*
    gw.step(70)
    assert stalls().timeouts == 1 and stalls().pending_relayed == 1 and gw.replies == [
        (STALL, b"\x7f\x31\x78")]


def test_a_silent_ecu_is_counted_not_responding_and_its_channel_is_free_again(gw):
    before = gw.router.summary().routes[3]
    gw.replies = []
    assert gw.submit(SILENT, "22 F1 90") is None
    gw.step(49)
    assert gw.router.summary().routes[3].timeouts == before.timeouts
    assert gw.submit(SILENT, "22 F1 90", source=0x0E01) == Nack.TargetUnreachable  # waiting
    gw.step(2)  # P2 (50 ms) from the request's frame on the bus: ECU not responding
    assert gw.router.summary().routes[3].timeouts == before.timeouts + 1
    assert gw.submit(SILENT, "22 F1 90") is None  # the channel is free again
    gw.step(60)
    assert gw.replies == []
    row = gw.router.summary().routes[3]
    assert row.timeouts - before.timeouts == 2 and row.responses == 0
    assert gw.collect(SILENT, "3E 80", 60) == []  # suppressed positive response: no timeout
    row = gw.router.summary().routes[3]
    assert row.timeouts - before.timeouts == 2 and row.suppressed == before.suppressed + 1
    counters = read_dids(gw.ask(GW, "22 FD 01")[0][1], [DID_ROUTE_COUNTERS], GW_DIDS)
    assert {la: (req, to) for la, req, _, _, to, _, _ in counters[DID_ROUTE_COUNTERS]}[
        SILENT] == (row.requests, row.timeouts)


def test_a_busy_channel_too_large_and_unknown_targets_are_refused_with_their_nack(gw):
    other = []
    assert gw.submit(SLOW, "22 01 02") is None
    assert gw.submit(SLOW, "22 01 02", source=0x0E01, into=other) == Nack.TargetUnreachable
    assert gw.submit(FUNC, "3E 00") == Nack.TargetUnreachable  # a channel is taken
    gw.step(300)
    assert other == [] and gw.replies[-1][1][:3] == b"\x62\x01\x02"
    assert gw.submit(ECU_A, b"\x22" * (MAX_UDS_BYTES + 1)) == Nack.DiagnosticMessageTooLarge
    assert gw.submit(FUNC, "22 F1 90 F1 8C F1 95 F1") == Nack.DiagnosticMessageTooLarge  # > SF
    assert gw.submit(0x0099, "22 F1 90") == Nack.UnknownTargetAddress
    assert gw.submit(ECU_A, b"") == Nack.TransportProtocolError
    summary = gw.router.summary()
    assert summary.routes[2].nacks == {"0x06": 1} and summary.functional.nacks["0x06"] == 1
    assert summary.routes[0].nacks["0x04"] == 1 and summary.unknown_target == 1
    # the largest request ISO-TP carries goes through whole (the ECU refuses its DID count)
    got = gw.ask(ECU_A, b"\x22" + b"\xf1\x90" * 2047, max_ms=100)
    assert nrc(got[0][1]) == Response.Code.IncorrectMessageLengthOrInvalidFormat
    assert gw.run.uds.stats.transport_errors == 0


def test_the_gateway_answers_for_itself_with_its_own_dids(gw):
    got = gw.ask(GW, "22 F1 90 FD 00")
    assert got[0][0] == GW
    values = read_dids(got[0][1], [DID_VIN, DID_ROUTES], GW_DIDS)
    assert values[DID_VIN] == VIN_GW
    routes = values[DID_ROUTES]
    assert routes[:2] == [(ECU_A, 0, 0x7E0, 0x7E8, 0xFF), (ECU_B, 0, 0x7E1, 0x7E9, 0xFF)]
    assert routes[4] == (FIXED, 2, 0x18DA40F1, 0x18DAF140, 0x40)
    assert routes[5] == (EXT, 3, 0x6F0, 0x6F8, 0x55) and routes[-1][:3] == (FUNC, 0, 0x7DF)
    session = Response.from_payload(gw.ask(GW, "10 03")[0][1])
    assert services.DiagnosticSessionControl.interpret_response(session).service_data \
        .p2_server_max == 0.05
    assert read_dids(gw.ask(GW, "22 F1 86")[0][1], [DID_SESSION]) == {DID_SESSION: 3}
    assert gw.ask(GW, "3E 00")[0][1] == b"\x7e\x00"
    assert gw.collect(GW, "3E 80", 5) == []
    for request, code in (("19 0A", 0x11), ("22 12 34", 0x31), ("22 F1", 0x13),
                          ("10 02", 0x12), ("3E 00 00", 0x13)):
        assert nrc(gw.ask(GW, request)[0][1]) == code, request
    gw.ask(GW, "10 01")
    own = gw.router.summary().gateway
    assert own.requests >= 10 and own.responses == own.requests - own.suppressed


def test_normal_fixed_and_extended_addressing_reach_their_ecus(gw):
    echo = lambda r: [(1.0, bytes([r[0] + 0x40]) + r[1:] + b"\x01" * 20)]  # noqa: E731
    fixed = gw.responder(isotp.Address(isotp.AddressingMode.NormalFixed_29bits,
                                       source_address=0x40, target_address=0xF1), echo)
    ext = gw.responder(isotp.Address(isotp.AddressingMode.Extended_11bits, txid=0x6F8,
                                     rxid=0x6F0, source_address=0x55, target_address=0xF1), echo)
    gw.frames()
    assert gw.ask(FIXED, "22 AA 01") == [(FIXED, bytes.fromhex("62 AA 01") + b"\x01" * 20)]
    assert gw.ask(EXT, "22 AA 02") == [(EXT, bytes.fromhex("62 AA 02") + b"\x01" * 20)]
    assert fixed.requests == [bytes.fromhex("22 AA 01")] and ext.requests == [
        bytes.fromhex("22 AA 02")]
    frames = [(m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in gw.frames()]
    assert (0x18DA40F1, True, bytes.fromhex("03 22 AA 01 CC CC CC CC")) in frames
    assert (0x6F0, False, bytes.fromhex("55 03 22 AA 02 CC CC CC")) in frames


def test_a_tester_that_leaves_gets_nothing_more_and_the_next_one_is_served(gw):
    lost: list = []
    assert gw.submit(SLOW, "22 01 02", source=0x0E05, into=lost) is None
    gw.step(10)
    gw.router.cancel(0x0E05)
    gw.step(300)
    assert lost == []
    assert [nrc(u) for _, u in gw.ask(SLOW, "22 01 03", max_ms=400)[:2]] == [0x78, 0x78]


def test_a_request_the_ecu_never_takes_is_a_transport_error_not_a_timeout():
    """A multi-frame request to an ID nobody serves: no flow control (N_Bs, 1 s in can-isotp),
    the request is dropped and counted as an ISO-TP error."""
    sim = GatewaySim(ecu_b=False, routes=(EcuRoute("nobody", SILENT, 0x7E3, 0x7EB),))
    try:
        assert sim.submit(SILENT, b"\x22" + b"\xf1\x90" * 10) is None
        sim.step(1100)
        row = sim.router.summary().routes[2]  # after the default ecu0, ecu1
        assert row.transport_errors == 1 and row.timeouts == 0 and sim.replies == []
        assert sim.submit(SILENT, "3E 00") is None  # the channel is free
    finally:
        sim.close()


def test_the_default_config_routes_to_the_two_default_ecus():
    cfg = default_config()
    assert [(r.logical_address, r.request_id) for r in cfg.ecus] == [(ECU_A, 0x7E0),
                                                                      (ECU_B, 0x7E1)]
    assert TESTER in range(cfg.tester_addresses[0], cfg.tester_addresses[1] + 1)


def test_junk_on_the_response_ids_never_breaks_the_router_and_is_counted():
    """Random frames (any PCI, any length, 29-bit twins) on the ECUs' response IDs while
    requests run: no exception, the errors counted, and the next request answered as before."""
    import random

    import can

    rnd = random.Random(40)
    sim = GatewaySim()
    try:
        sim.step(20)
        junk = sim.run.bus()
        ids = [0x7E8, 0x7E9, 0x7DF]
        for tick in range(300):
            if tick % 30 == 0:
                for target in (ECU_A, ECU_B):
                    sim.submit(target, "22 F1 90")
            for _ in range(rnd.randint(0, 12)):
                data = bytes(rnd.randrange(256) for _ in range(rnd.randint(0, 8)))
                junk.send(can.Message(arbitration_id=rnd.choice(ids), data=data,
                                      is_extended_id=rnd.random() < 0.1))
            sim.step()
        sim.step(100)
        rows = sim.router.summary().routes
        assert sum(r.transport_errors + r.late for r in rows) > 0
        vin = sim.ask(ECU_B, "22 F1 90")
        assert read_dids(vin[-1][1], [0xF190]) == {0xF190: VIN_B}
    finally:
        sim.close()


def test_a_flood_on_the_gateways_bus_is_shed_within_its_budget_and_requests_still_answered():
    """issue-39 bound on the gateway's CAN side: at most RxBudget frames read per 1 ms step,
    what is past frames_per_tick shed and counted, except frames on a route's response IDs."""
    import can

    sim = GatewaySim(ecu_b=False)
    try:
        sim.step(20)
        flood = sim.run.bus()
        junk = can.Message(arbitration_id=0x555, data=bytes(8), is_extended_id=False)
        for _ in range(2000):
            flood.send(junk)
        budget = sim.node.rx_budget
        answers = sim.ask(ECU_A, "22 F1 90", max_ms=400)
        assert read_dids(answers[-1][1], [0xF190]) == {0xF190: VIN_A}
        assert sim.node.rx_shed > 0
        assert budget.frames_per_tick < sim.node.rx_peak <= budget.frames_per_tick + budget.shed_per_tick
    finally:
        sim.close()
