"""A gap the host caused is not a silent sensor (issue 14 item 12): time the ECU itself was not
running (base-tick releases it skipped) is not charged against a sensor's receive deadline, and
on a live bus (host_gap_ms > 0) a silence of every frame - the sending process stalled - is
excused up to host_gap_ms; a silence of the sensor's frames alone is a timeout as before.

Deterministic: the ECU's ticks and the frames are driven by hand on the in-process bus."""

from __future__ import annotations

import struct

import can
import pytest

from vecu.bus import open_bus
from vecu.clock import NS_PER_MS
from vecu.codec import DbcCodec
from vecu.ecu.node import EcuNode
from vecu.ecu.sensor_monitor import (
    SOURCE_ESTIMATE,
    SOURCE_SENSOR,
    DtcState,
    SensorStatus,
)
from vecu.ecu.throttle_function import ThrottleFunction
from vecu.estimators.throttle.ukf_fast import FastThrottleUKF

MS = NS_PER_MS


class Rig:
    """An ECU (throttle function) and a sender of TPS_Sensor + ETB_Wattmeter frames."""

    def __init__(self, channel: str, host_gap_ms: float = 0.0) -> None:
        self.codec = DbcCodec()
        self.ecu_bus = open_bus(channel=channel)
        self.sender = open_bus(channel=channel)
        self.thr = ThrottleFunction(self.codec, FastThrottleUKF("arm"))
        self.ecu = EcuNode(self.ecu_bus, self.codec, [self.thr], host_gap_ms=host_gap_ms)
        self._sent = 0
        self.sources: list[int] = []

    def tps(self) -> None:
        k = self._sent = self._sent + 1
        volts = 2.0 + 0.003 * ((k * 7919) % 13 - 6)  # sensor noise: never 'stuck'
        data = self.codec["TPS_Sensor"].encode(
            {"TPS_CRC": 0, "TPS_AliveCounter": k % 15, "TPS_Voltage": volts})
        self.sender.send(can.Message(arbitration_id=0x100, data=data, is_extended_id=False))

    def watt(self) -> None:
        self.sender.send(can.Message(arbitration_id=0x101, is_extended_id=False,
                                     data=struct.pack("<HH", 2000, 0) + struct.pack("<f", 4.0)))

    def host_report(self, skipped: int, late: int = 0) -> None:
        """The sender's PLANT_Host: its own count of skipped and late ticks so far."""
        data = self.codec["PLANT_Host"].encode({"PH_SkippedSends": skipped, "PH_LateSends": late,
                                                "PH_MaxLateness": 0, "PH_Counter": 0})
        self.sender.send(can.Message(arbitration_id=self.codec["PLANT_Host"].frame_id,
                                     data=data, is_extended_id=False))

    def tick(self, ms: int) -> SensorStatus:
        self.ecu.tick(ms * MS)
        self.sources.append(self.thr.source)
        return self.thr.status

    def run(self, first_ms: int, last_ms: int, tps: bool = True, watt: bool = True) -> list:
        """A frame pair (as chosen) and an ECU tick every ms; the statuses."""
        out = []
        for ms in range(first_ms, last_ms + 1):
            if tps:
                self.tps()
            if watt:
                self.watt()
            out.append(self.tick(ms))
        return out

    def close(self) -> None:
        self.ecu_bus.shutdown()
        self.sender.shutdown()


@pytest.fixture
def rig(request):
    made = []

    def make(host_gap_ms: float = 0.0) -> Rig:
        made.append(Rig(f"host-gap-{request.node.name}-{len(made)}", host_gap_ms))
        return made[-1]

    yield make
    for r in made:
        r.close()


def test_an_ecu_stall_of_10_ms_with_the_sender_stalled_too_is_no_timeout(rig):
    """The whole host stalled: no ECU tick and no frame from 20 to 30 ms. Was: the ECU's tick at
    30 ms (before the sender's frames came back) charged 11 ms of silence to the TPS."""
    r = rig()
    assert set(r.run(0, 19)) == {SensorStatus.OK}
    assert r.tick(30) == SensorStatus.OK        # back first: nothing on the bus yet
    assert set(r.run(31, 40)) == {SensorStatus.OK}
    mon = r.thr.monitor
    assert mon.timeouts == 0 and mon.status_history == [] and mon.dtc_item.confirmations == 0
    assert mon.host_gaps == 1
    assert r.sources[20] == SOURCE_ESTIMATE  # the 11 ms old sample is not broadcast as fresh
    assert r.sources[21:] == [SOURCE_SENSOR] * 10


def test_a_silent_sensor_is_a_timeout_after_3_ms_of_the_ecu_running(rig):
    r = rig()
    r.run(0, 19)
    st = r.run(20, 30, tps=False)  # wattmeter frames go on: the TPS alone is silent
    assert st[:2] == [SensorStatus.OK] * 2 and st[2] == SensorStatus.TIMEOUT
    assert r.thr.monitor.first_fault_ns == 22 * MS and r.thr.monitor.dtc == DtcState.CONFIRMED


def test_live_a_silent_sensor_whose_companion_frames_go_on_is_a_timeout_after_3_ms(rig):
    r = rig(host_gap_ms=50)
    r.run(0, 19)
    st = r.run(20, 30, tps=False)
    assert st.index(SensorStatus.TIMEOUT) == 2 and r.thr.monitor.host_gaps == 0


def test_a_silent_sensor_across_an_ecu_stall_times_out_on_running_time(rig):
    """TPS dead from 20 ms; the ECU stalls from 21 to 30 ms (the wattmeter frames queue up):
    the 8 ms it did not run are not charged, the silence is after 3 ms of running time."""
    r = rig()
    r.run(0, 20)
    for _ in range(21, 30):
        r.watt()
    st = r.run(30, 35, tps=False)
    assert st[:2] == [SensorStatus.OK] * 2, st  # 30, 31: 1 and 2 ms of running silence
    assert st[2] == SensorStatus.TIMEOUT  # 32 ms: 12 ms after the last frame, 3 ms running
    assert r.thr.monitor.first_fault_ns == 32 * MS


def test_live_a_silence_of_every_frame_is_a_host_gap_up_to_host_gap_ms(rig):
    """The sending process stalled for 20 ms while the ECU ran on time, just after a frame of
    its own other than the TPS: then no TPS, no wattmeter. Excused on a live bus (host_gap_ms =
    50): the estimate is broadcast, no TPS DTC; the first tick back may see only some of the
    sender's frames (the TPS in the next one)."""
    r = rig(host_gap_ms=50)
    r.run(0, 19)
    assert r.run(20, 20, tps=False) == [SensorStatus.OK]  # e.g. an engine event, then stalled
    assert set(r.run(21, 39, tps=False, watt=False)) == {SensorStatus.OK}
    r.watt()
    assert r.tick(40) == SensorStatus.OK
    assert set(r.run(41, 60)) == {SensorStatus.OK}
    mon = r.thr.monitor
    assert mon.status_history == [] and mon.dtc_item.confirmations == 0 and mon.host_gaps == 1
    assert set(r.sources[22:41]) == {SOURCE_ESTIMATE} and r.sources[41:] == [SOURCE_SENSOR] * 20


def test_live_a_silence_of_every_frame_longer_than_host_gap_ms_is_a_timeout(rig):
    r = rig(host_gap_ms=50)
    r.run(0, 19)
    st = r.run(20, 80, tps=False, watt=False)
    first = st.index(SensorStatus.TIMEOUT)
    assert 20 + first == 19 + 50  # charged from the last frame, at host_gap_ms
    assert r.thr.monitor.dtc == DtcState.CONFIRMED


def test_simulated_clock_a_silence_of_every_frame_is_a_timeout_as_before(rig):
    """host_gap_ms = 0 (simulated clock, scenarios, replay): nothing is excused but the ECU's
    own stalls, and the simulated ECU never stalls."""
    r = rig()
    r.run(0, 19)
    st = r.run(20, 25, tps=False, watt=False)
    assert st.index(SensorStatus.TIMEOUT) == 2 and r.thr.monitor.host_gaps == 0


def test_a_timeout_is_put_on_the_sender_host_when_it_reported_skipped_sends_meanwhile(rig):
    """Issue 29 item 2: the sender (a loaded live plant) skipped the TPS frames of 20..29 ms and
    says so in its next PLANT_Host; the timeout is kept with that cause (summary and closing
    line), not left as a sensor fault."""
    r = rig()
    r.host_report(0)
    r.run(0, 19)
    st = r.run(20, 29, tps=False)  # its wattmeter frames went on (e.g. sent late), not the TPS
    assert SensorStatus.TIMEOUT in st
    r.host_report(10, 3)
    r.run(30, 60)
    causes = r.thr.monitor.timeout_causes()
    assert len(causes) == 1 and causes[0]["cause"] == "sender-host"
    assert causes[0]["sender_skipped"] == 10 and causes[0]["sender_late"] == 3 and causes[0]["t_s"] == pytest.approx(0.022)
    assert causes[0]["silent_ms"] == pytest.approx(3.0)


def test_a_timeout_the_host_does_not_explain_is_the_sensors(rig):
    """Same silence, but the sender's reports say it skipped nothing (its count before the
    timeout does not count either): the sensor or its wiring."""
    r = rig()
    r.host_report(4)  # skipped earlier, before the TPS went silent
    r.run(0, 19)
    r.run(20, 29, tps=False)
    r.host_report(4)
    r.run(30, 60)
    (cause,) = r.thr.monitor.timeout_causes()
    assert cause["cause"] == "sensor" and cause["sender_skipped"] == 0


def test_a_timeout_across_an_ecu_stall_is_put_on_this_ecus_host(rig):
    r = rig()
    r.run(0, 20)
    for _ in range(21, 30):
        r.watt()
    r.run(30, 35, tps=False)
    (cause,) = r.thr.monitor.timeout_causes()
    assert cause["cause"] == "ecu-host" and cause["ecu_not_running_ms"] == pytest.approx(9.0)  # ticks 21..29


def test_the_ecu_closing_lines_say_who_dropped_the_frames():
    from vecu.cli.ecu import _timeout_lines

    lines = _timeout_lines({
        "tps": [{"t_s": 1.5, "silent_ms": 3.0, "ecu_not_running_ms": 0.0, "sender_skipped": 12,
                 "sender_late": 0, "cause": "sender-host"}],
        "wheel": [{"t_s": 0.5, "silent_ms": 6.0, "ecu_not_running_ms": 0.0, "sender_skipped": 0,
                   "sender_late": 0, "cause": "sensor"}]})
    assert lines[0].startswith("  timeout wheel at 0.500 s") and "the sensor or its wiring" in lines[0]
    assert "the host, not the sensor: the sender skipped 12 and delayed 0 sends" in lines[1]
