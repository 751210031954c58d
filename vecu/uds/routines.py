"""The ECU's routines (RoutineControl 0x31, ISO 14229-1 §14.2): sensor self-tests."""

from __future__ import annotations

from vecu.clock import NS_PER_MS
from vecu.ecu.sensor_monitor import SensorMonitor, SensorStatus

SELF_TEST_MS = 200.0
ROUTINES = {0x0201: "tps", 0x0203: "wheel", 0x0204: "swa"}  # sensor self-tests
RUNNING, PASSED, FAILED, STOPPED = 1, 2, 3, 4


class SelfTest:
    """Routine: watch one sensor monitor for SELF_TEST_MS; passed when frames came, the status
    stayed ok and never changed."""

    def __init__(self, monitor: SensorMonitor) -> None:
        self.mon = monitor
        self.state = 0  # never started
        self._t0 = 0
        self._changes0 = 0
        self._rx0: int | None = None
        self.changes = 0

    def start(self, t_ns: int) -> None:
        self.state, self._t0 = RUNNING, t_ns
        self._changes0, self._rx0 = len(self.mon.status_history), self.mon.last_rx_ns
        self.changes = 0

    def poll(self, t_ns: int) -> None:
        if self.state == RUNNING and t_ns - self._t0 >= SELF_TEST_MS * NS_PER_MS:
            mon = self.mon
            self.changes = len(mon.status_history) - self._changes0
            ok = mon.status == SensorStatus.OK and not self.changes and mon.last_rx_ns != self._rx0
            self.state = PASSED if ok else FAILED

    def record(self) -> bytes:
        return bytes([self.state, int(self.mon.status), min(self.changes, 255)])
