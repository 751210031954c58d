"""Bounded receive work per tick (RxBudget, docs/live.md 'Floods') and the command-handler
boundary (BusNode.handler_failed): a flood is taken in up to the budget, shed and counted past
it, and left in the bus beyond that; the broadcasts keep their rate, a tester is still heard,
and a request that makes a handler raise gets the protocol's negative answer, counted."""

from __future__ import annotations

import can
import pytest
from udsoncan import Response

from vecu.assembly import build_plant
from vecu.bus import RxBudget, open_bus
from vecu.clock import NS_PER_MS
from vecu.codec import DbcCodec
from vecu.config import RunConfig
from vecu.ecu.node import EcuNode
from vecu.ecu.speed_function import SpeedFunction
from vecu.ecu.throttle_function import ThrottleFunction
from vecu.estimators.throttle.ukf_fast import FastThrottleUKF
from vecu.faults import FaultKind, FaultTarget
from vecu.uds.config import UdsConfig
from vecu.uds.server import attach_uds

JUNK = can.Message(arbitration_id=0x555, data=bytes(8), is_extended_id=False)


@pytest.fixture
def setup(request):
    codec = DbcCodec()
    channel = f"flood-{request.node.name}"
    ecu_bus, tester = open_bus(channel=channel), open_bus(channel=channel)
    ecu = EcuNode(ecu_bus, codec, [ThrottleFunction(codec, FastThrottleUKF("arm")),
                                   SpeedFunction(codec)],
                  rx_budget=RxBudget(frames_per_tick=8, shed_per_tick=16,
                                     catch_up_ticks=getattr(request, "param", 0)))
    yield codec, ecu, tester
    ecu_bus.shutdown()
    tester.shutdown()


def _drain(bus: can.BusABC) -> list[can.Message]:
    out = []
    while (msg := bus.recv(0.0)) is not None:
        out.append(msg)
    return out


def test_a_tick_takes_its_budget_sheds_the_next_and_leaves_the_rest_in_the_bus(setup):
    codec, ecu, tester = setup
    for _ in range(100):
        tester.send(JUNK)
    ecu.tick(0)
    rx = ecu.rx
    assert (rx.received, rx.unknown_id, rx.shed) == (24, 8, 16)  # 76 still in the bus
    ids = [m.arbitration_id for m in _drain(tester)]
    assert 0x200 in ids  # the throttle estimate went out in the flooded tick
    ecu.tick(NS_PER_MS)
    assert (rx.received, rx.unknown_id, rx.shed) == (48, 16, 32)
    for k in range(2, 6):  # 100 = 4 ticks x 24 + 4
        ecu.tick(k * NS_PER_MS)
    assert (rx.received, rx.unknown_id, rx.shed) == (100, 36, 64)
    assert rx.received == rx.accepted + rx.ignored + rx.rejected + rx.diagnostic + rx.shed
    assert ecu.rx_peak == 24  # the most frames read in one tick: the budget's two parts
    # every 1 ms a throttle estimate, flood or not
    assert sum(m.arbitration_id == 0x200 for m in _drain(tester)) == 5


@pytest.mark.parametrize("setup", [20], indirect=True)
def test_a_backlog_is_caught_up_without_loss_and_only_a_lasting_flood_is_shed(setup):
    """catch_up_ticks = 20 (the default): a stalled host's backlog (100 frames) drains at 8 a
    tick in 13 ticks, nothing shed; a flood that keeps every tick full sheds from its 21st
    saturated tick on."""
    codec, ecu, tester = setup
    for _ in range(100):
        tester.send(JUNK)
    t = 0
    for _ in range(14):  # 13 ticks of 8 + one that empties the bus
        ecu.tick(t)
        t += NS_PER_MS
    rx = ecu.rx
    assert (rx.received, rx.unknown_id, rx.shed) == (100, 100, 0)
    assert ecu.rx_saturated == 0  # the bus emptied: the count starts again
    for k in range(25):  # 30 frames a tick: more than 8 + 16
        for _ in range(30):
            tester.send(JUNK)
        ecu.tick(t)
        t += NS_PER_MS
        assert rx.shed == (16 * (k - 19) if k >= 20 else 0), k
    assert rx.received == rx.accepted + rx.ignored + rx.rejected + rx.diagnostic + rx.shed


def test_the_shed_count_is_on_the_bus_in_ecu_diag(setup):
    codec, ecu, tester = setup
    diag = codec["ECU_Diag"]
    ecu.tick(0)
    assert [diag.decode(m.data)["DIAG_RxShed"] for m in _drain(tester)
            if m.arbitration_id == diag.frame_id] == [0]
    for _ in range(8 + 16 + 5):
        tester.send(JUNK)
    for k in range(1, 101):
        ecu.tick(k * NS_PER_MS)
    shed = [diag.decode(m.data)["DIAG_RxShed"] for m in _drain(tester)
            if m.arbitration_id == diag.frame_id]
    assert shed[-1] == 16 == ecu.rx.shed
    for _ in range(200):  # saturates at the signal's 7 bits
        for _ in range(24):
            tester.send(JUNK)
        ecu.tick(ecu._last_tick_ns + NS_PER_MS)
    for _ in range(100):
        ecu.tick(ecu._last_tick_ns + NS_PER_MS)
    shed = [diag.decode(m.data)["DIAG_RxShed"] for m in _drain(tester)
            if m.arbitration_id == diag.frame_id]
    assert shed[-1] == 127 and ecu.rx.shed == 16 + 200 * 16


def _read_vin_request() -> can.Message:
    return can.Message(arbitration_id=0x7E0, is_extended_id=False,
                       data=bytes([0x03, 0x22, 0xF1, 0x90]) + bytes([0xCC] * 4))


def test_a_uds_request_among_the_shed_frames_is_still_answered(setup):
    codec, ecu, tester = setup
    attach_uds(ecu, UdsConfig(), seed=1)
    for _ in range(12):  # the request arrives after the handled 8: in the shed part
        tester.send(JUNK)
    tester.send(_read_vin_request())
    for _ in range(30):
        tester.send(JUNK)
    for k in range(30):
        ecu.tick(k * NS_PER_MS)
    first = [m for m in _drain(tester) if m.arbitration_id == 0x7E8]
    assert first and first[0].data[0] >> 4 == 1  # a first frame (the VIN is 17 bytes)
    assert bytes(first[0].data[2:5]) == b"\x62\xf1\x90"
    assert ecu.rx.shed > 0 and ecu.rx.diagnostic == 1


def test_a_service_that_raises_answers_general_reject_and_the_node_goes_on(setup, monkeypatch):
    """The boundary, provoked: a service handler that raises (a stand-in for any bug a client's
    request reaches) gets NRC 0x10 on the bus, is counted, and the ECU keeps broadcasting."""
    codec, ecu, tester = setup
    uds = attach_uds(ecu, UdsConfig(), seed=1)
    assert uds is not None

    def broken(payload: bytes, t_ns: int) -> bytes:
        raise ZeroDivisionError("a bug a request reaches")

    fn, sessions, sub = uds._services[0x22]
    monkeypatch.setitem(uds._services, 0x22, (broken, sessions, sub))
    tester.send(_read_vin_request())
    for k in range(5):
        ecu.tick(k * NS_PER_MS)
    sent = _drain(tester)
    answers = [m for m in sent if m.arbitration_id == 0x7E8]
    assert len(answers) == 1
    response = Response.from_payload(bytes(answers[0].data[1:1 + answers[0].data[0]]))
    assert not response.positive and response.code == Response.Code.GeneralReject
    assert ecu.handler_errors == {"uds service 0x22: ZeroDivisionError": 1}
    assert sum(m.arbitration_id == 0x200 for m in sent) == 5


def test_a_diagnostic_server_whose_tick_raises_is_counted_and_the_node_goes_on(setup,
                                                                                 monkeypatch):
    codec, ecu, tester = setup
    uds = attach_uds(ecu, UdsConfig(), seed=1)

    def broken(t_ns: int) -> None:
        raise RuntimeError("a sampler bug")

    monkeypatch.setattr(uds, "tick", broken)
    for k in range(10):
        ecu.tick(k * NS_PER_MS)
    assert ecu.handler_errors == {"UdsServer.tick: RuntimeError": 10}
    assert sum(m.arbitration_id == 0x200 for m in _drain(tester)) == 10


def test_the_plant_obeys_a_fault_command_inside_a_flood_and_sheds_the_rest():
    codec = DbcCodec()
    plant_bus, tester = open_bus(channel="flood-plant"), open_bus(channel="flood-plant")
    try:
        plant = build_plant(RunConfig(duration_s=1.0, kill_tps_at_s=None), codec, plant_bus)
        plant.rx_budget = RxBudget(catch_up_ticks=0)  # shed from the first saturated tick
        plant.tick(0)
        _drain(tester)
        for _ in range(plant.rx_budget.frames_per_tick + 10):
            tester.send(JUNK)
        tester.send(codec["FI_Command"].frame({"FI_Target": int(FaultTarget.TPS),
                                               "FI_Kind": int(FaultKind.DEAD),
                                               "FI_Value": 0.0}, 0.0))
        for _ in range(500):
            tester.send(JUNK)
        plant.tick(NS_PER_MS)
        assert plant.rx_shed == plant.rx_budget.shed_per_tick - 1  # the command was kept
        assert plant.frames_received == plant.rx_budget.frames_per_tick + plant.rx_budget.shed_per_tick
        tps = codec["TPS_Sensor"]
        volts = [tps.decode(m.data)["TPS_Voltage"] for m in _drain(tester)
                 if m.arbitration_id == tps.frame_id]
        assert volts == [0.0]  # dead: 0 V on the bus in the same tick
    finally:
        plant_bus.shutdown()
        tester.shutdown()
