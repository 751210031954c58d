"""The routing engine between two buses, fed frames that vecu's database encodes, every routed
frame decoded by cantools on the other side: values through physical units, saturation, choices
by name, a multiplexed target, E2E re-protection checked by autosar-e2e, ID translation, rate
limit, timeout substitutes and the firewall."""

from __future__ import annotations

import collections
import copy
import re
from pathlib import Path

import can
import cantools
import e2e as autosar_e2e
import pytest

from vecu.codec import DbcCodec
from vecu.gateway.routes_config import load_routing_config
from vecu.gateway.routing import RoutingEngine

from .routing_setup import DATA, TWO_BUSES, write_config

MS = 1_000_000
VECU = DbcCodec()
BODY = cantools.database.load_file(str(DATA / "body.dbc"))


_SENT: collections.Counter[str] = collections.Counter()


def _frame(name: str, values: dict[str, float], t_ns: int):
    """name's frame as its sender makes it: its alive counter (P11: 0..14) one up each call."""
    fc = VECU[name]
    full = {**fc.start_values, **values}
    for sig in fc.start_values:
        if sig.endswith("_AliveCounter"):
            full[sig] = values.get(sig, _SENT[name] % 15)
    _SENT[name] += 1
    return fc.frame(full, t_ns / 1e9)


@pytest.fixture
def engine(tmp_path):
    return RoutingEngine(load_routing_config(write_config(tmp_path)))


def _run(engine, feed: dict[int, list], until_ms: int):
    """feed: ms -> frames on powertrain; returns every (ms, bus, frame) the engine sent."""
    sent = []
    for ms in range(until_ms):
        for f in feed.get(ms, []):
            engine.receive("powertrain", f, ms * MS)
        sent += [(ms, bus, m) for bus, m in engine.tick(ms * MS)]
    return sent


def test_signals_repacked_into_another_database_with_e2e(engine):
    feed = {ms: [_frame("ECU_SpeedEstimate", {"SPD_VehSpeed": 36.0 + ms / 10}, ms * MS),
                 _frame("ECU_ThrottleEstimate", {"THR_Angle": 12.5 + ms / 100, "THR_Source": 1},
                        ms * MS)]
            for ms in range(0, 100, 2)}
    sent = _run(engine, feed, 100)
    dyn = [(ms, m) for ms, bus, m in sent if m.arbitration_id == 1280]
    assert [ms for ms, _ in dyn] == list(range(0, 100, 20))  # its database cycle: 20 ms
    last_counter = None
    for ms, m in dyn:
        assert m.channel == "vehicle"
        got = BODY.decode_message(1280, bytes(m.data), decode_choices=False)
        src_speed = VECU["ECU_SpeedEstimate"].decode(bytes(feed[ms][0].data))["SPD_VehSpeed"]
        src_thr = VECU["ECU_ThrottleEstimate"].decode(bytes(feed[ms][1].data))
        assert got["VEH_Speed"] == pytest.approx(src_speed / 3.6, abs=0.005)  # km/h -> m/s
        assert got["VEH_Throttle"] == pytest.approx(src_thr["THR_Angle"], abs=0.025)
        assert BODY.get_message_by_name("VEH_Dynamics").get_signal_by_name(
            "VEH_Source").choices[int(got["VEH_Source"])] == "estimate"
        assert autosar_e2e.p11.e2e_p11_check(bytearray(m.data), 0x421)
        counter = m.data[1] & 0x0F
        assert last_counter is None or counter == (last_counter + 1) % 15
        last_counter = counter
    stats = engine.summary()["routes"]["routes[1] powertrain->vehicle"]
    assert stats["out"] == 5 and stats["latency_us"]["max"] == 0.0  # no delay configured


def test_saturation_is_counted_and_the_frame_carries_the_limit(engine):
    sent = _run(engine, {0: [_frame("ECU_SpeedEstimate", {"SPD_VehSpeed": 250.0}, 0)]}, 1)
    (m,) = [m for _, _, m in sent if m.arbitration_id == 1280]
    assert BODY.decode_message(1280, bytes(m.data))["VEH_Speed"] == 50.0  # 250 km/h > 50 m/s
    assert engine.summary()["routes"]["routes[1] powertrain->vehicle"]["saturated"] == {
        "VEH_Speed": 1}


def test_a_broken_source_crc_is_dropped(engine):
    good = _frame("ECU_ThrottleEstimate", {"THR_Angle": 40.0}, 0)
    bad = _frame("ECU_ThrottleEstimate", {"THR_Angle": 80.0}, MS)
    bad.data[0] ^= 0xFF
    sent = _run(engine, {0: [good], 1: [bad]}, 41)
    values = [BODY.decode_message(1280, bytes(m.data))["VEH_Throttle"]
              for _, _, m in sent if m.arbitration_id == 1280]
    assert values == [40.0, 40.0, 40.0]
    assert engine.summary()["routes"]["routes[1] powertrain->vehicle"]["dropped"] == {"e2e": 1}


def test_a_repeated_source_counter_is_dropped_a_jump_is_used(engine):
    """The source's alive counter after its CRC: the same frame again (counter repeated, a
    stale frame) is dropped and counted; a frame after lost ones (counter jumped) is used."""
    first = _frame("ECU_ThrottleEstimate", {"THR_Angle": 40.0}, 0)
    _frame("ECU_ThrottleEstimate", {"THR_Angle": 50.0}, MS)  # lost on the way
    jumped = _frame("ECU_ThrottleEstimate", {"THR_Angle": 60.0}, 2 * MS)
    sent = _run(engine, {0: [first], 1: [copy.deepcopy(first)], 21: [jumped]}, 61)
    values = [BODY.decode_message(1280, bytes(m.data))["VEH_Throttle"]
              for _, _, m in sent if m.arbitration_id == 1280]
    assert values == [40.0, 40.0, 60.0, 60.0]  # at 0, 20 (the copy at 1 ms dropped), 40, 60 ms
    assert engine.summary()["routes"]["routes[1] powertrain->vehicle"]["dropped"] == {
        "e2e_repeated": 1}


def test_timeout_gives_the_target_its_initial_value(engine):
    feed = {0: [_frame("ECU_ThrottleEstimate", {"THR_Angle": 40.0, "THR_Source": 0}, 0)]}
    sent = _run(engine, feed, 141)
    by_ms = {ms: BODY.decode_message(1280, bytes(m.data), decode_choices=False)
             for ms, _, m in sent if m.arbitration_id == 1280}
    assert by_ms[80]["VEH_Throttle"] == 40.0 and by_ms[80]["VEH_Source"] == 0
    # silent 100 ms: start values (VEH_Source's GenSigStartValue 3 "invalid", VEH_Throttle 0)
    assert by_ms[100]["VEH_Throttle"] == 0.0 and by_ms[100]["VEH_Source"] == 3
    assert engine.summary()["routes"]["routes[1] powertrain->vehicle"]["timeouts"] == 1


def test_frame_route_translates_the_id_rate_limits_and_keeps_e2e(engine):
    feed = {ms: [_frame("ECU_SpeedEstimate", {"SPD_VehSpeed": float(ms)}, ms * MS)]
            for ms in range(0, 60, 2)}
    sent = [(ms, m) for ms, _, m in _run(engine, feed, 60) if m.arbitration_id == 0x420]
    assert [ms for ms, _ in sent] == [0, 20, 40]  # at most one per 20 ms, the latest wins
    for ms, m in sent:
        assert bytes(m.data) == bytes(feed[ms][0].data)  # untouched payload
    stats = engine.summary()["routes"]["routes[0] powertrain->vehicle"]
    # 30 in: 3 out, 26 replaced by a newer one, the one of 58 ms waiting for 60 ms
    assert stats["in"] == 30 and stats["out"] == 3 and stats["dropped"] == {"rate_limit": 26}
    assert stats["latency_us"]["max"] == 0.0 and stats["queue_peak"] == 1
    # an E2E-protected frame copied keeps passing the receiver's check (data ID: its source ID)
    thr = _frame("ECU_ThrottleEstimate", {"THR_Angle": 5.0}, 0)
    assert autosar_e2e.p11.e2e_p11_check(bytearray(thr.data), 0x200)


def test_multiplexed_target_carries_its_selector(engine):
    feed = {0: [_frame("CHS_Lateral", {"LAT_YawRate": 12.5}, 0)],
            5: [_frame("CHS_Lateral", {"LAT_YawRate": 12.5}, 5 * MS)],
            9: [_frame("CHS_Lateral", {"LAT_YawRate": -3.0}, 9 * MS)]}
    sent = [(ms, m) for ms, _, m in _run(engine, feed, 20) if m.arbitration_id == 1296]
    assert [ms for ms, _ in sent] == [0, 9]  # on change only
    decoded = [BODY.decode_message(1296, bytes(m.data)) for _, m in sent]
    assert decoded == [{"VEH_Page": 2, "VEH_Yaw": 12.5}, {"VEH_Page": 2, "VEH_Yaw": -3.0}]


def test_deny_rules_drop_before_any_route(tmp_path):
    engine = RoutingEngine(load_routing_config(write_config(tmp_path, TWO_BUSES + """
[[routes]]
from = "vehicle"
to = "powertrain"
ids = [0x7E0, 0x123]
[[deny]]
from = "vehicle"
ids = [0x7E0, 0x7DF]
""")))
    for ms, can_id in enumerate((0x7E0, 0x123, 0x7DF, 0x7E0)):
        engine.receive("vehicle", can.Message(arbitration_id=can_id, data=b"\x02\x10\x03",
                                              is_extended_id=False), ms * MS)
    sent = [m for ms in range(4) for _, m in engine.tick(ms * MS)]
    assert [m.arbitration_id for m in sent] == [0x123]  # 0x7E0 is routed, but denied first
    assert engine.summary()["denied"] == {"deny[0]": 3}
    assert engine.summary()["routes"]["routes[0] vehicle->powertrain"]["in"] == 1


def test_frame_routes_match_the_id_and_its_11_or_29_bit_format(tmp_path):
    """ids = [0x123] takes the 11-bit 0x123 only; id + mask above 0x7FF takes 29-bit frames."""
    engine = RoutingEngine(load_routing_config(write_config(tmp_path, TWO_BUSES + """
[[routes]]
from = "vehicle"
to = "powertrain"
ids = [0x123]
[[routes]]
from = "vehicle"
to = "powertrain"
id = 0x18FF0000
mask = 0x1FFF0000
""")))
    frames = [(0x123, False), (0x123, True), (0x18FF0123, True), (0x0123, False),
              (0x18FE0001, True), (0x18FF7FFF, True)]
    for ms, (can_id, ext) in enumerate(frames):
        engine.receive("vehicle", can.Message(arbitration_id=can_id, data=bytes([ms]),
                                              is_extended_id=ext), ms * MS)
    sent = [m for ms in range(len(frames)) for _, m in engine.tick(ms * MS)]
    assert [(m.arbitration_id, m.is_extended_id, m.data[0]) for m in sent] == [
        (0x123, False, 0), (0x18FF0123, True, 2), (0x123, False, 3), (0x18FF7FFF, True, 5)]


def test_a_frame_route_forwards_e2e_untouched(tmp_path):
    """A protected frame copied by a frame route still passes the receiver's check
    (autosar-e2e P11, data ID = its CAN ID), counter and CRC as the sender made them."""
    engine = RoutingEngine(load_routing_config(write_config(tmp_path, TWO_BUSES + """
[[routes]]
from = "powertrain"
to = "vehicle"
messages = ["ECU_ThrottleEstimate"]
""")))
    feed = {ms: [_frame("ECU_ThrottleEstimate", {"THR_Angle": ms * 1.5, "THR_AliveCounter": ms},
                        ms * MS)] for ms in range(15)}
    sent = _run(engine, feed, 15)
    assert len(sent) == 15
    for ms, bus, m in sent:
        assert bus == "vehicle" and m.arbitration_id == 0x200
        assert bytes(m.data) == bytes(feed[ms][0].data)
        assert autosar_e2e.p11.e2e_p11_check(bytearray(m.data), 0x200)
        assert m.data[1] & 0x0F == ms


def test_a_signal_route_min_interval_keeps_the_latest_values(tmp_path):
    engine = RoutingEngine(load_routing_config(write_config(tmp_path, TWO_BUSES + """
[[routes]]
from = "powertrain"
to = "vehicle"
target = "VEH_Mux"
send = "on_change"
min_interval_ms = 10
signals = { VEH_Yaw = "CHS_Lateral.LAT_YawRate" }
""")))
    feed = {ms: [_frame("CHS_Lateral", {"LAT_YawRate": ms + 1.0}, ms * MS)] for ms in range(25)}
    sent = _run(engine, feed, 25)
    assert [ms for ms, _, _ in sent] == [0, 10, 20]
    assert [BODY.decode_message(1296, bytes(m.data))["VEH_Yaw"] for _, _, m in sent] == [
        1.0, 11.0, 21.0]  # the values of the frames of 0, 10 and 20 ms: the latest then
    stats = engine.summary()["routes"]["routes[0] powertrain->vehicle"]
    assert stats["in"] == 25 and stats["out"] == 3


def test_onto_a_third_party_database(tmp_path, thirdparty):
    """vecu's speed estimate into a database nobody here wrote (cantools' test vehicle.dbc:
    RT_DL1MK3_Speed, a 29-bit ID, Speed in m/s on 32 bits): every routed value is the source
    frame's, decoded by cantools on both sides, converted km/h -> m/s."""
    dbc = thirdparty / "dbc" / "vehicle.dbc"
    path = write_config(tmp_path, f'''
[buses.powertrain]
dbc = ["vecu"]
[buses.vehicle]
dbc = ["{dbc}"]
[[routes]]
from = "powertrain"
to = "vehicle"
target = "RT_DL1MK3_Speed"
send = "on_change"
signals = {{ Speed = "ECU_SpeedEstimate.SPD_VehSpeed" }}
''')
    engine = RoutingEngine(load_routing_config(path))
    vehicle = cantools.database.load_file(str(dbc))
    target = vehicle.get_message_by_name("RT_DL1MK3_Speed")
    speeds = [0.0, 12.34, 99.99, 250.0, 250.0, 3.21]
    feed = {ms: [_frame("ECU_SpeedEstimate", {"SPD_VehSpeed": v}, ms * MS)]
            for ms, v in enumerate(speeds)}
    sent = _run(engine, feed, len(speeds))
    assert [ms for ms, _, _ in sent] == [1, 2, 3, 5]  # on change (0 km/h is the start value)
    for ms, bus, m in sent:
        assert bus == "vehicle" and m.is_extended_id and m.arbitration_id == target.frame_id
        src = VECU["ECU_SpeedEstimate"].decode(bytes(feed[ms][0].data))["SPD_VehSpeed"]
        got = target.decode(bytes(m.data))["Speed"]
        assert got == pytest.approx(src / 3.6, abs=1e-5)


def test_an_arxml_source_protection_is_checked(tmp_path):
    """A source message whose ARXML names AUTOSAR P05 (tests/restbus/data/chassis.arxml,
    BrakeStatus, data ID 0x0B2C): frames autosar-e2e protected pass, a broken CRC is dropped."""
    arxml = Path(__file__).parents[1] / "restbus" / "data" / "chassis.arxml"
    engine = RoutingEngine(load_routing_config(write_config(tmp_path, f"""
[buses.chassis]
dbc = ["{arxml}"]
[buses.vehicle]
dbc = ["body.dbc"]
[[routes]]
from = "chassis"
to = "vehicle"
target = "VEH_Dynamics"
send = "on_change"
signals = {{ VEH_Chk = "BrakeStatus.BrakePressure" }}
""")))
    brake = cantools.database.load_file(str(arxml)).get_message_by_name("BrakeStatus")
    sent = []
    for ms, (pressure, broken) in enumerate(((12.0, False), (30.0, True), (7.0, False))):
        data = bytearray(brake.encode({"BrakeStatus_Crc": 0, "BrakeStatus_Counter": ms,
                                       "BrakePressure": pressure, "BrakePedalPressed": 1}))
        autosar_e2e.p05.e2e_p05_protect(data, data_id=0x0B2C, increment_counter=False)
        if broken:
            data[0] ^= 0x01
        engine.receive("chassis", can.Message(arbitration_id=brake.frame_id, data=data,
                                              is_extended_id=False), ms * MS)
        sent += [m for _, m in engine.tick(ms * MS)]
    assert [BODY.decode_message(1280, bytes(m.data))["VEH_Chk"] for m in sent] == [12, 7]
    assert engine.summary()["routes"]["routes[0] chassis->vehicle"]["dropped"] == {"e2e": 1}


def test_p02_reprotection_with_its_data_id_list(tmp_path):
    ids = list(range(0x10, 0x20))
    engine = RoutingEngine(load_routing_config(write_config(tmp_path, TWO_BUSES + f"""
[[routes]]
from = "powertrain"
to = "vehicle"
target = "VEH_Dynamics"
signals = {{ VEH_Speed = "ECU_SpeedEstimate.SPD_VehSpeed" }}
e2e = {{ profile = "P02", data_id_list = {ids} }}
""")))
    feed = {ms: [_frame("ECU_SpeedEstimate", {"SPD_VehSpeed": ms / 10}, ms * MS)]
            for ms in range(0, 400, 2)}
    sent = [m for _, _, m in _run(engine, feed, 400)]
    assert len(sent) == 20
    for n, m in enumerate(sent):
        assert autosar_e2e.p02.e2e_p02_check(bytearray(m.data), bytes(ids), length=0)
        assert m.data[1] & 0x0F == n % 16  # P02's counter: 0..15


def test_check_and_forward_drops_frames_failing_their_e2e_check(tmp_path):
    """e2e_check = true: a frame route passes the frames whose protection (the source
    database's, autosar-e2e's check) holds and drops and counts the others."""
    engine = RoutingEngine(load_routing_config(write_config(tmp_path, TWO_BUSES + """
[[routes]]
from = "powertrain"
to = "vehicle"
messages = ["ECU_ThrottleEstimate"]
e2e_check = true
""")))
    feed = {}
    for ms in range(20):
        f = _frame("ECU_ThrottleEstimate", {"THR_Angle": ms * 1.5, "THR_AliveCounter": ms % 15},
                   ms * MS)
        if ms % 4 == 3:
            f.data[5] ^= 0x01  # one bit flipped after the CRC was computed
        feed[ms] = [f]
    sent = _run(engine, feed, 20)
    assert [bytes(m.data) for _, _, m in sent] == [bytes(feed[ms][0].data) for ms in range(20)
                                                    if ms % 4 != 3]
    assert all(autosar_e2e.p11.e2e_p11_check(bytearray(m.data), 0x200) for _, _, m in sent)
    route = engine.summary()["routes"]["routes[0] powertrain->vehicle"]
    assert route["in"] == 20 and route["out"] == 15 and route["dropped"] == {"e2e": 5}


@pytest.mark.parametrize("route, problem", [
    ('messages = ["ECU_SpeedEstimate"]\ne2e_check = true',
     "routes[0].e2e_check': no message of the route names an E2E protection"),
    (('target = "VEH_Mux"\nsend = "on_change"\nsignals = { VEH_Yaw = "CHS_Lateral.LAT_YawRate" }'
     '\ne2e_check = true'), "routes[0].e2e_check': belongs to a frame route"),
])
def test_e2e_check_errors(tmp_path, route, problem):
    from vecu.gateway.config import GatewayConfigError

    with pytest.raises(GatewayConfigError, match=re.escape(problem)):
        load_routing_config(write_config(tmp_path, TWO_BUSES + f"""
[[routes]]
from = "powertrain"
to = "vehicle"
{route}
"""))
