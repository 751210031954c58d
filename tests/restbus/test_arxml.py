"""A restbus from a real AUTOSAR 4 ARXML (tests/restbus/data/chassis.arxml, written for these
tests): cantools reads what the file says; every message at exactly its ARXML cycle time; the
profile 5 and profile 2 frames pass autosar-e2e's checks and cantools' own profile functions
(cantools.autosar, fed the ARXML's own E2E properties); an E2E.toml overrides the ARXML; a
disturbance breaks cantools' check exactly in its window; properties vecu cannot apply are
reported and the message is sent unprotected."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import can
import cantools
import e2e as autosar_e2e
import numpy as np
import pytest
from cantools.autosar import end_to_end as cantools_e2e

from tests.cli.test_smoke import vecu
from tests.restbus.test_restbus import collect
from vecu.codec import ArxmlE2E
from vecu.e2e import AliveCounterCheck, E2EConfigError
from vecu.errors import BadArgumentError
from vecu.restbus.node import RestbusNode
from vecu.restbus.spec import RestbusConfig, arxml_profile, arxml_protection, build_plans

ARXML = Path(__file__).parent / "data" / "chassis.arxml"
NS_PER_MS = 1_000_000
P02_IDS = (17, 34, 51, 68, 85, 102, 119, 136, 153, 170, 187, 204, 221, 238, 1, 254)
# what the file says, message by message: CAN ID, extended, cycle (ms), E2E
WRITTEN = {"BrakeStatus": (0x1A0, False, 10, ("PROFILE_05", [0x0B2C])),
           "WheelSpeeds": (0x1B0, False, 20, ("PROFILE_02", list(P02_IDS))),
           "BodyStatus": (0x3C0, False, 100, None),
           "EngineInfo": (0x18FF1234, True, 50, None),
           "SteerAngle": (0x0C8, False, 5, ("PROFILE_05", [0x03A5]))}  # an E2E transformer
P05 = {0x1A0: ("BrakeStatus", 0x0B2C), 0x0C8: ("SteerAngle", 0x03A5)}


@pytest.fixture(scope="module")
def db() -> cantools.database.Database:
    """The ARXML as cantools reads it (the oracle's view of the file)."""
    return cantools.database.load_file(str(ARXML))


def values_file(tmp_path: Path) -> str:
    """Signals that move, so that the CRCs cover changing data."""
    path = tmp_path / "values.toml"
    path.write_text('[[value]]\nsignal = "BrakeStatus.BrakePressure"\nkind = "sine"\n'
                    'offset = 100\namplitude = 90\nperiod_s = 0.37\n\n'
                    '[[value]]\nsignal = "WheelSpeeds.WheelSpeedFL"\nkind = "ramp"\n'
                    'start = 0\nend = 250\nperiod_s = 1.3\n')
    return str(path)


def test_cantools_reads_the_file_as_written(db):
    assert sorted(m.name for m in db.messages) == sorted(WRITTEN)
    for name, (can_id, ext, cycle, e2e) in WRITTEN.items():
        m = db.get_message_by_name(name)
        assert (m.frame_id, m.is_extended_frame, m.cycle_time) == (can_id, ext, cycle), name
        got = m.autosar.e2e
        assert (None if got is None else (got.category, got.data_ids)) == e2e, name
        if got is not None:
            assert got.payload_length == m.length == 8
    body = db.get_message_by_name("BodyStatus")
    assert {s.name: s.initial for s in body.signals} == {"DoorState": "Open", "CabinTemp": 21}
    assert db.get_message_by_name("EngineInfo").get_signal_by_name("EngineTorque").initial == -10
    assert sorted(db.get_message_by_name("BrakeStatus").senders) == ["ChassisECU"]


def test_every_message_at_exactly_its_arxml_cycle_time_from_its_init_values(db):
    plans, node, frames = collect(RestbusConfig((str(ARXML),)), 3.0)
    assert sorted(p.name for p in plans) == sorted(WRITTEN)
    for plan, st in zip(plans, node.states):
        cycle_ns = WRITTEN[plan.name][2] * NS_PER_MS
        assert plan.period_ns == cycle_ns, plan.name
        assert st.times_ns == list(range(0, 3000 * NS_PER_MS, cycle_ns)), plan.name
    first = {}
    for msg in frames:
        first.setdefault(msg.arbitration_id, msg)
    decoded = {m.name: m.decode(bytes(first[m.frame_id].data), decode_choices=False)
               for m in db.messages}
    assert decoded["BodyStatus"] == {"DoorState": 2, "CabinTemp": 21}
    assert decoded["EngineInfo"] == {"EngineSpeed": 800.0, "EngineTorque": -10.0}
    assert decoded["BrakeStatus"]["BrakePressure"] == 15.0
    assert decoded["WheelSpeeds"]["WheelSpeedFR"] == 50.1
    assert decoded["SteerAngle"]["SteeringWheelAngle"] == -15.0
    assert first[0x18FF1234].is_extended_id and not first[0x1A0].is_extended_id


def test_p05_and_p02_frames_pass_autosar_e2e_and_cantools_profile_functions(db, tmp_path):
    cfg = RestbusConfig((str(ARXML),), values_path=values_file(tmp_path), seed=3)
    plans, _, frames = collect(cfg, 40.0)
    by_name = {p.name: p for p in plans}
    assert by_name["BrakeStatus"].e2e.profile == "P05"
    assert by_name["BrakeStatus"].e2e_source == "ARXML (PROFILE_05)"
    assert by_name["WheelSpeeds"].e2e.profile == "P02"
    assert by_name["SteerAngle"].e2e.profile == "P05"  # from the E2E transformer's PROFILE-NAME
    assert by_name["BodyStatus"].e2e is None and by_name["EngineInfo"].e2e is None
    brake, wheels = db.get_message_by_name("BrakeStatus"), db.get_message_by_name("WheelSpeeds")
    counters = {0x1A0: AliveCounterCheck(256), 0x1B0: AliveCounterCheck(16),
                0x0C8: AliveCounterCheck(256)}
    seen = dict.fromkeys(counters, 0)
    crcs: dict[int, set[bytes]] = {k: set() for k in counters}
    for msg in frames:
        data = bytes(msg.data)
        if msg.arbitration_id in P05:
            name, data_id = P05[msg.arbitration_id]
            assert autosar_e2e.p05.e2e_p05_check(bytearray(data), data_id)
            assert cantools_e2e.check_profile5_crc(data, db.get_message_by_name(name)) is True
            assert counters[msg.arbitration_id].check(data[2])
        elif msg.arbitration_id == 0x1B0:
            assert autosar_e2e.p02.e2e_p02_check(bytearray(data), bytes(P02_IDS))
            assert cantools_e2e.check_profile2_crc(data, wheels) is True
            assert counters[0x1B0].check(data[1] & 0x0F)
        else:
            continue
        seen[msg.arbitration_id] += 1
        crcs[msg.arbitration_id].add(data[:2])
    assert seen == {0x1A0: 4000, 0x1B0: 2000, 0x0C8: 8000}
    assert min(len(crcs[k]) for k in (0x1A0, 0x1B0)) > 200  # the data (so the CRC) changed
    assert len(crcs[0x0C8]) == 256  # constant data: the counter alone moves the CRC
    # the oracle can fail: one flipped payload bit and cantools' check says so
    bad = bytearray(frames[0].data if frames[0].arbitration_id == 0x1A0 else frames[1].data)
    bad[4] ^= 0x01
    assert cantools_e2e.check_profile5_crc(bytes(bad), brake) is False


def test_an_e2e_toml_overrides_the_arxml_properties(db, tmp_path):
    e2e_file = tmp_path / "E2E.toml"
    e2e_file.write_text('[[e2e]]\nmessage = "BrakeStatus"\nprofile = "P05"\ndata_id = 0x1234\n\n'
                        '[[e2e]]\nid = 0x1B0\nprofile = "P11"\ndata_id = 0x1B0\n')
    plans, _, frames = collect(RestbusConfig((str(ARXML),), e2e_path=str(e2e_file)), 1.0)
    assert {p.name: p.e2e_source for p in plans if p.e2e is not None} == {
        "BrakeStatus": "E2E.toml", "WheelSpeeds": "E2E.toml",
        "SteerAngle": "ARXML (PROFILE_05)"}  # no entry: keeps the ARXML's
    brake, wheels = db.get_message_by_name("BrakeStatus"), db.get_message_by_name("WheelSpeeds")
    n = 0
    for msg in frames:
        data = bytes(msg.data)
        if msg.arbitration_id == 0x1A0:
            assert autosar_e2e.p05.e2e_p05_check(bytearray(data), 0x1234)
            assert cantools_e2e.check_profile5_crc(data, 0x1234) is True
            assert cantools_e2e.check_profile5_crc(data, brake) is False  # the ARXML's 0x0B2C
            n += 1
        elif msg.arbitration_id == 0x1B0:
            assert autosar_e2e.p11.e2e_p11_check(bytearray(data), 0x1B0)
            assert data[1] & 0x0F != 15  # P11's counter range, not P02's
            assert cantools_e2e.check_profile2_crc(data, wheels) is False
            n += 1
    assert n == 100 + 50


def test_cli_arxml_restbus_with_a_crc_disturbance_fails_cantools_check_in_its_window(
        db, tmp_path):
    log, summary = tmp_path / "x.log", tmp_path / "s.json"
    res = vecu("restbus", str(ARXML), "--duration", "2", "--log", str(log), "--summary",
               str(summary), "--disturb", "BrakeStatus:crc_wrong@0.5-1.0",
               "--disturb", "WheelSpeeds:crc_wrong@0.5-1.0",
               "--disturb", "SteerAngle:crc_wrong@0.5-1.0", "--quiet")
    assert res.returncode == 0, res.stderr
    s = json.loads(summary.read_text())
    assert s["per_message"] == {"BrakeStatus": 200, "WheelSpeeds": 100, "BodyStatus": 20,
                                "EngineInfo": 40, "SteerAngle": 400}
    assert s["e2e"] == {"BrakeStatus": "P05 from ARXML (PROFILE_05)",
                        "WheelSpeeds": "P02 from ARXML (PROFILE_02)",
                        "SteerAngle": "P05 from ARXML (PROFILE_05)",
                        "BodyStatus": "none", "EngineInfo": "none"}
    check = {0x1A0: (db.get_message_by_name("BrakeStatus"), cantools_e2e.check_profile5_crc),
             0x1B0: (db.get_message_by_name("WheelSpeeds"), cantools_e2e.check_profile2_crc),
             0x0C8: (db.get_message_by_name("SteerAngle"), cantools_e2e.check_profile5_crc)}
    verdicts: dict[int, list[tuple[int, bool]]] = {k: [] for k in check}
    for msg in can.LogReader(str(log)):
        if msg.arbitration_id in check and not msg.is_extended_id:
            m, fn = check[msg.arbitration_id]
            verdicts[msg.arbitration_id].append((round(msg.timestamp * 1000),
                                                 fn(bytes(msg.data), m)))
    for can_id, cycle in ((0x1A0, 10), (0x1B0, 20), (0x0C8, 5)):
        got = verdicts[can_id]
        assert [t for t, _ in got] == list(range(0, 2000, cycle))
        assert [t for t, ok in got if not ok] == list(range(500, 1000, cycle)), hex(can_id)


def test_arxml_categories_map_to_profiles():
    assert arxml_profile("PROFILE_05", 1) == "P05"
    assert arxml_profile("Profile5", 1) == "P05"
    assert arxml_profile("E2E_P05", 1) == "P05"  # the old first-number rule read P02 here
    assert arxml_profile("PROFILE_02", 16) == "P02"
    assert arxml_profile("PROFILE_11", 1) == "P11"
    assert arxml_profile(None, 16) == "P02"  # cantools' own rule: 16 data IDs
    assert arxml_profile("CRC8", 1) == "P05"  # ... and one data ID
    for category, n, why in (("PROFILE_04m", 1, "P04m"), ("PROFILE_22", 16, "P22"),
                             (None, 3, "3 data IDs")):
        with pytest.raises(E2EConfigError, match=why):
            arxml_profile(category, n)


def test_arxml_properties_vecu_cannot_apply_are_errors_of_the_mapping():
    from types import SimpleNamespace

    def msg(props, length=8):
        return SimpleNamespace(arxml_e2e=props, length=length)

    p05 = arxml_protection(msg(ArxmlE2E("PROFILE_05", (0x1B0,), 8)))
    assert (p05.profile, p05.data_id, p05.length) == ("P05", 0x1B0, 8)
    assert arxml_protection(msg(None)) is None
    for props, why in ((ArxmlE2E("PROFILE_04", (1,), 8), "P04 needs 12 bytes"),
                       (ArxmlE2E("PROFILE_05", tuple(range(16)), 8), "one data ID"),
                       (ArxmlE2E("PROFILE_02", (300,) * 16, 8), "16 values 0..255"),
                       (ArxmlE2E("PROFILE_05", (), 8), "without data IDs")):
        with pytest.raises(E2EConfigError, match=why):
            arxml_protection(msg(props))


def test_unusable_arxml_e2e_is_logged_and_the_message_sent_unprotected(tmp_path, caplog):
    text = ARXML.read_text().replace("<CATEGORY>PROFILE_05</CATEGORY>",
                                     "<CATEGORY>PROFILE_04m</CATEGORY>")
    path = tmp_path / "p04m.arxml"
    path.write_text(text)
    with caplog.at_level(logging.WARNING, logger="vecu.restbus"):
        plans, _, _ = build_plans(RestbusConfig((str(path),)))
    brake = next(p for p in plans if p.name == "BrakeStatus")
    assert brake.e2e is None and "P04m" in brake.e2e_source
    assert any("BrakeStatus (0x1A0)" in r.message and "E2E.toml overrides" in r.message
               for r in caplog.records)
    assert next(p for p in plans if p.name == "WheelSpeeds").e2e.profile == "P02"
    node = RestbusNode(plans, lambda msg: True, np.random.default_rng(0))
    with pytest.raises(BadArgumentError, match=r"BrakeStatus has no E2E protection \(ARXML E2E "
                                               r"not applied: .*P04m.*E2E\.toml\)"):
        node.check("BrakeStatus", "crc_wrong")
