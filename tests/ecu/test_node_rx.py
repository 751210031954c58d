"""The ECU under hostile input: every bad frame is counted, nothing raises, output never stops."""

from __future__ import annotations

import math
import struct

import can
import pytest

from vecu.bus import open_bus
from vecu.clock import NS_PER_MS
from vecu.codec import DbcCodec
from vecu.ecu.node import EcuNode
from vecu.ecu.speed_function import SpeedFunction
from vecu.ecu.throttle_function import ThrottleFunction
from vecu.estimators.throttle.ukf_fast import FastThrottleUKF


@pytest.fixture
def setup():
    codec = DbcCodec()
    ecu_bus = open_bus(channel="ecu-rx-test")
    tester = open_bus(channel="ecu-rx-test")
    ecu = EcuNode(ecu_bus, codec, [ThrottleFunction(codec, FastThrottleUKF("arm")),
                                   SpeedFunction(codec)])
    yield codec, ecu, tester
    ecu_bus.shutdown()
    tester.shutdown()


def tps_frame(codec, counter, volts, crc_ok=True, dlc=None):
    data = bytearray(codec["TPS_Sensor"].encode(
        {"TPS_CRC": 0, "TPS_AliveCounter": counter, "TPS_Voltage": volts}))
    if not crc_ok:
        data[0] ^= 0x5A
    if dlc is not None:
        data = (data + bytes(8))[:dlc]
    return can.Message(arbitration_id=0x100, data=data, is_extended_id=False)


def watt_frame(u, power_bytes):
    return can.Message(arbitration_id=0x101, is_extended_id=False,
                       data=struct.pack("<HH", int(u * 1000), 0) + power_bytes)


def test_each_kind_of_bad_frame_lands_in_its_own_counter(setup):
    codec, ecu, _ = setup
    t = 0
    good = [tps_frame(codec, 0, 2.0), tps_frame(codec, 1, 2.1)]
    bad = {
        "dlc_errors": [tps_frame(codec, 2, 2.0, dlc=3), tps_frame(codec, 2, 2.0, dlc=8)],
        "crc_errors": [tps_frame(codec, 2, 2.0, crc_ok=False)],
        "counter_errors": [tps_frame(codec, 9, 2.0)],
        "value_errors": [watt_frame(3.0, struct.pack("<f", math.nan)),
                         watt_frame(3.0, struct.pack("<f", 1e9))],
        "unknown_id": [can.Message(arbitration_id=0x555, data=[1]),
                       can.Message(arbitration_id=0x100, data=[0] * 4, is_extended_id=True)],
        "remote_frames": [can.Message(arbitration_id=0x100, is_remote_frame=True, dlc=4,
                                      is_extended_id=False)],
        "error_frames": [can.Message(is_error_frame=True)],
    }
    for msg in good:
        ecu.receive(msg, t)
    for msgs in bad.values():
        for msg in msgs:
            ecu.receive(msg, t)
    rx = ecu.rx
    for counter, msgs in bad.items():
        assert getattr(rx, counter) == len(msgs), counter
    assert rx.accepted == 2
    assert rx.received == 2 + sum(len(m) for m in bad.values())
    assert rx.rejected == sum(len(m) for m in bad.values())


def test_own_frames_echoed_back_are_ignored_not_errors(setup):
    codec, ecu, _ = setup
    echo = codec["ECU_ThrottleEstimate"].frame(
        {"THR_CRC": 0, "THR_AliveCounter": 0, "THR_Source": 0, "THR_Angle": 1.0,
         "THR_AngleEst": 1.0, "THR_AngleEstStd": 1.0, "THR_TpsStatus": 0, "THR_Validity": 1},
        0.0)
    ecu.receive(echo, 0)
    assert ecu.rx.ignored == 1 and ecu.rx.rejected == 0


def test_ecu_keeps_broadcasting_through_garbage_and_reports_it_in_status(setup):
    codec, ecu, tester = setup
    garbage = [can.Message(arbitration_id=i, data=bytes([i % 256] * (i % 9)), is_extended_id=False)
               for i in range(0x0F0, 0x110)]
    for k in range(200):
        t = k * NS_PER_MS
        for msg in garbage[k % len(garbage):k % len(garbage) + 3]:
            tester.send(msg)
        tester.send(watt_frame(5.0, struct.pack("<f", math.inf if k % 7 == 0 else 12.0)))
        ecu.tick(t)
    est_frames, speed_frames, status = 0, 0, None
    est = codec["ECU_ThrottleEstimate"]
    while (msg := tester.recv(0.0)) is not None:
        if msg.arbitration_id == est.frame_id:
            est_frames += 1
            assert est.crc_ok(msg.data)
            v = est.decode(msg.data)
            assert math.isfinite(v["THR_Angle"])
        elif msg.arbitration_id == codec["ECU_SpeedEstimate"].frame_id:
            speed_frames += 1
        elif msg.arbitration_id == codec["ECU_Status"].frame_id:
            status = codec["ECU_Status"].decode(msg.data)
    assert est_frames == 200  # one per tick, no gap
    assert speed_frames == 100  # every 2 ms, with or without ESC_Motion frames
    assert status is not None
    assert status["ECU_RxValueErrors"] > 0 and status["ECU_RxUnknownIds"] > 0
    assert status["ECU_RxDlcErrors"] > 0 and status["ECU_RxTimeouts"] == 1  # no TPS at all
    assert ecu.rx.rejected > 100


def test_remote_frames_are_reported_in_ecu_diag(setup):
    """Remote frames are counted and broadcast (DIAG_RemoteFrames, saturating), not only kept in
    the run summary; none seen -> 0, so a clean run's ECU_Diag bytes do not change."""
    codec, ecu, tester = setup
    diag = codec["ECU_Diag"]

    def last_diag() -> dict:
        got = None
        while (msg := tester.recv(0.0)) is not None:
            if msg.arbitration_id == diag.frame_id:
                got = diag.decode(msg.data)
        return got

    ecu.tick(0)
    assert last_diag()["DIAG_RemoteFrames"] == 0
    for i in range(3):
        tester.send(can.Message(arbitration_id=0x100 + i, is_remote_frame=True, dlc=4,
                                is_extended_id=False))
    ecu.tick(100 * NS_PER_MS)
    assert ecu.rx.remote_frames == 3
    assert last_diag()["DIAG_RemoteFrames"] == 3
    for _ in range(300):
        ecu.receive(can.Message(arbitration_id=0x7FF, is_remote_frame=True), 0)
    ecu.tick(200 * NS_PER_MS)
    assert last_diag()["DIAG_RemoteFrames"] == 255
