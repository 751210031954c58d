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
