"""vecu's plant and ECU with a restbus of a user's DBC on one bus, from a scenario: the restbus's
frames and disturbances on the bus (FI_Event frames, the intended check failures), the ECU
counting the foreign IDs without losing a tick, and the scenario's bad input as one line."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import can
import e2e as autosar_e2e
import pytest

from vecu.e2e import AliveCounterCheck
from vecu.runner import run
from vecu.scenario.loader import ScenarioError, load_scenario

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "vecu" / "data" / "scenarios" / "restbus_body_e2e.toml"


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    log = tmp_path_factory.mktemp("rb") / "run.log"
    sc = load_scenario(SCENARIO)
    res = run(replace(sc.config, log_path=str(log), channel="rb-scenario"))
    return res.summary, list(can.LogReader(str(log)))


def test_plant_ecu_and_restbus_share_the_bus_and_the_ecu_loses_no_tick(result):
    s, frames = result
    rb = s["restbus"]
    assert rb["messages"] == 6 and rb["frames_sent"] > 300
    assert s["overruns"] == 0 and s["throttle"]["missing_broadcasts"] == 0
    # every restbus frame reached the ECU and was counted as a foreign ID, nothing else broke
    rx = s["frames"]["ecu_rx"]
    foreign = sum(1 for m in frames if m.arbitration_id in (0x1B0, 0x1B1, 0x3A0, 0x3B0, 0x400)
                  or m.is_extended_id)
    assert rx["unknown_id"] == foreign == rb["frames_sent"]
    assert rx["crc_errors"] == rx["counter_errors"] == 0  # the TPS frames stay valid
    assert s["throttle"]["dtc"] == "confirmed"  # the TPS killed at 1.0 s, found within 3 ms
    assert 1.0 <= s["throttle"]["detection_time_s"] <= 1.003


def test_restbus_disturbances_are_recorded_and_seen_by_an_independent_checker(result):
    _, frames = result
    fi = [m for m in frames if m.arbitration_id == 0x6F1]
    ids = [int.from_bytes(m.data[0:2], "little") for m in fi]
    assert ids.count(0x1B0) == 2 and ids.count(0x1B1) == 2 and ids.count(0x3A0) == 1
    assert ids.count(0x100) == 1  # the TPS fault, by the plant
    counter = AliveCounterCheck(256)
    bad_counter, bad_crc = [], []
    for m in frames:
        t = round(m.timestamp * 1000)
        if m.arbitration_id == 0x1B0:
            assert autosar_e2e.p05.e2e_p05_check(bytearray(m.data), 0x01B0)
            if not counter.check(m.data[2]):
                bad_counter.append(t)
        elif m.arbitration_id == 0x1B1 and not autosar_e2e.p11.e2e_p11_check(
                bytearray(m.data), 0x01B1):
            bad_crc.append(t)
    assert bad_counter and min(bad_counter) >= 500 and max(bad_counter) <= 800
    assert len(bad_counter) >= 25
    assert bad_crc == list(range(600, 900, 20))


def test_a_restbus_fault_the_restbus_cannot_do_is_one_line_naming_the_key(tmp_path):
    text = SCENARIO.read_text().replace('kind = "counter_freeze"', 'kind = "melt"')
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace('"restbus/', f'"{SCENARIO.parent}/restbus/'))
    with pytest.raises(ScenarioError, match=r"key 'faults\[0\]\.kind': unknown restbus "
                                            r"disturbance 'melt'"):
        load_scenario(bad)


def test_a_missing_restbus_database_is_named(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('duration_s = 1.0\n[restbus]\ndatabases = ["nope.dbc"]\n')
    with pytest.raises(ScenarioError, match=r"key 'restbus': .*nope\.dbc: no such database"):
        load_scenario(bad)


def test_live_run_with_a_restbus_counts_every_foreign_frame_and_keeps_its_cycles(tmp_path):
    """The same scenario on the wall clock (vecu run --realtime's path), 1 s: the restbus's
    frames arrive at the ECU on python-can's virtual bus, each counted, none lost, none late
    by a whole cycle (frame count = duration / cycle for every message)."""
    sc = load_scenario(SCENARIO)
    res = run(replace(sc.config, duration_s=1.0, realtime=True, interface="virtual",
                      channel="rb-live-scenario", faults=(), restbus_disturbances=(),
                      keep_series=False))
    s = res.summary
    rb = s["restbus"]
    assert s["frames"]["ecu_rx"]["unknown_id"] == rb["frames_sent"]
    want = {"ABS_WheelSpeeds": 100, "ABS_BrakePressure": 50, "BCM_Lights": 10,
            "BCM_Info": 5, "GW_VehicleSpeed": 10}
    # every release sent or skipped (late by a whole cycle), + BCM_Doors' two changes in 1 s
    assert rb["frames_sent"] + rb["skipped_releases"] == sum(want.values()) + 2
    for name, n in want.items():
        assert rb["per_message"][name] <= n + 1, (name, rb["per_message"])
