"""Sensor diagnosis: timeout, range, E2E, stuck, plausibility against an estimator; DTCs.

One monitor per safety-relevant sensor (TPS, steering-wheel angle, wheel speed). Each check is
debounced; the first to confirm sets the status (codes = THR_TpsStatus / STE_SwaStatus /
DIAG_*Status in the DBC) and the ECU substitutes the estimate. The status heals after `heal_ms` of
clean samples. The DTC follows its own lifecycle (Dtc): none -> pending (a check failing, not yet
debounced) -> confirmed (debounced) -> healed (`dtc_heal_ms` clean after the status healed) ->
confirmed again if the fault comes back. docs/scenarios.md describes it.
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass, field

from vecu.clock import NS_PER_MS
from vecu.models.sensors import TpsCalibration

SOURCE_SENSOR, SOURCE_ESTIMATE = 0, 1  # THR_Source / STE_Source in the DBC


class SensorStatus(enum.IntEnum):
    OK = 0
    TIMEOUT = 1
    RANGE_LOW = 2
    RANGE_HIGH = 3
    E2E_ERROR = 4
    IMPLAUSIBLE = 5
    STUCK = 6


class DtcState(enum.IntEnum):
    """Values of ECU_TpsDtc / DIAG_*Dtc in the DBC."""

    NONE = 0
    PENDING = 1
    CONFIRMED = 2
    HEALED = 3


class Dtc:
    """DTC lifecycle of one monitored item; report() once per evaluation.

    failed: a debounced fault is present; suspicious: a check fails but is not yet debounced;
    healthy: the item's status is ok again (healing clock runs only then). Transitions are kept in
    `history` as (t_ns, state); `on_change` (if set) is called on every transition.
    """

    def __init__(self, heal_ms: float) -> None:
        self.state = DtcState.NONE
        self.confirmations = 0
        self.history: list[tuple[int, DtcState]] = []
        self.on_change: Callable[[], None] | None = None
        self._heal_ns = int(heal_ms * NS_PER_MS)
        self._healthy_since: int | None = None
        self._was_confirmed = False

    def report(self, t_ns: int, failed: bool, suspicious: bool, healthy: bool) -> DtcState:
        state = self.state
        if failed:
            new = DtcState.CONFIRMED
            self._healthy_since = None
        elif state == DtcState.CONFIRMED:
            new = state
            if healthy:
                if self._healthy_since is None:
                    self._healthy_since = t_ns
                elif t_ns - self._healthy_since >= self._heal_ns:
                    new = DtcState.HEALED
            else:
                self._healthy_since = None
        elif suspicious:
            new = DtcState.PENDING
        else:
            new = DtcState.HEALED if self._was_confirmed else DtcState.NONE
        if new != state:
            if new == DtcState.CONFIRMED:
                self.confirmations += 1
                self._was_confirmed = True
            self.state = new
            self.history.append((t_ns, new))
            if self.on_change is not None:
                self.on_change()
        return new


@dataclass(frozen=True)
class SensorMonitorConfig:
    # from the DBC (GenMsgCycleTime of the sensor's frame): set by the function, not a parameter
    cycle_ms: float = field(default=1.0, metadata={"param": False})
    timeout_cycles: int = 3        # frames stop: confirmed after 3 missed periods
    range_debounce: int = 2        # consecutive out-of-range samples
    e2e_debounce: int = 2          # consecutive CRC/counter errors
    stuck_samples: int = 8         # identical raw readings in a row (needs sensor noise)
    plaus_sigma: float = 5.0       # gate in estimator sigmas ...
    plaus_margin: float = 4.0      # ... plus a fixed margin (physical units, deg here)
    plaus_debounce: int = 5        # up/down counter threshold
    heal_ms: float = 500.0         # clean time before the sensor is trusted again
    dtc_heal_ms: float = 5000.0    # healthy time after that before the DTC reads 'healed'
    enabled: bool = True           # False: no checks at all (a broken ECU, for scenario tests)


class SensorMonitor:
    """Feed on_frame()/on_e2e_error() as frames arrive, then evaluate() once per function run.

    raw_low/raw_high bound the valid raw signal (range checks run on the raw value, e.g. volts);
    to_physical maps a raw value to the quantity compared with the estimator (deg).
    """

    def __init__(self, config: SensorMonitorConfig, raw_low: float, raw_high: float,
                 to_physical: Callable[[float], float]) -> None:
        self.cfg = config
        self._low, self._high = raw_low, raw_high
        self._to_physical = to_physical
        self.status = SensorStatus.OK
        self.timeouts = 0  # confirmed timeouts (select())
        self.dtc_item = Dtc(config.dtc_heal_ms)
        self.status_history: list[tuple[int, SensorStatus]] = []  # (t_ns, status) transitions
        self.first_fault_ns: int | None = None
        self.first_fault_status: SensorStatus | None = None
        self.value: float | None = None     # last valid sensor value (physical)
        self._raw: float | None = None
        self._fresh = False
        self._last_rx_ns: int | None = None
        self._range_low = self._range_high = 0
        self._e2e_bad = 0
        self._same = 0
        self._plaus = 0
        self._clean_since_ns: int | None = None
        self._timeout_ns = int(config.timeout_cycles * config.cycle_ms * NS_PER_MS)

    @classmethod
    def for_tps(cls, config: SensorMonitorConfig, cal: TpsCalibration) -> SensorMonitor:
        """Range checks on the voltage (open / short circuit), plausibility on the angle."""
        return cls(config, cal.fault_low_v, cal.fault_high_v, cal.angle)

    def on_frame(self, t_ns: int, raw: float) -> None:
        """A frame that passed DLC/E2E/value checks."""
        self._same = self._same + 1 if raw == self._raw else 0
        self._raw = raw
        self._last_rx_ns = t_ns
        self._e2e_bad = 0
        self._fresh = True
        self._range_low = self._range_low + 1 if raw < self._low else 0
        self._range_high = self._range_high + 1 if raw > self._high else 0
        self.value = self._to_physical(raw)

    def on_e2e_error(self) -> None:
        self._e2e_bad += 1

    def evaluate(self, t_ns: int, est: float, est_std: float) -> SensorStatus:
        cfg = self.cfg
        finding = SensorStatus.OK
        last_rx = 0 if self._last_rx_ns is None else self._last_rx_ns  # run start counts as rx
        if not cfg.enabled:
            pass
        elif t_ns - last_rx >= self._timeout_ns:
            finding = SensorStatus.TIMEOUT
        else:
            if self._e2e_bad >= cfg.e2e_debounce:
                finding = SensorStatus.E2E_ERROR
            elif self._range_low >= cfg.range_debounce:
                finding = SensorStatus.RANGE_LOW
            elif self._range_high >= cfg.range_debounce:
                finding = SensorStatus.RANGE_HIGH
            elif cfg.stuck_samples and self._same + 1 >= cfg.stuck_samples:
                finding = SensorStatus.STUCK
            elif self._fresh and self.value is not None:
                gate = cfg.plaus_sigma * est_std + cfg.plaus_margin
                if abs(self.value - est) > gate:
                    if self._plaus < cfg.plaus_debounce:  # saturating up/down counter
                        self._plaus += 1
                elif self._plaus > 0:
                    self._plaus -= 1
                if self._plaus >= cfg.plaus_debounce:
                    finding = SensorStatus.IMPLAUSIBLE
        self._fresh = False
        return self._update(t_ns, finding)

    def _update(self, t_ns: int, finding: SensorStatus) -> SensorStatus:
        status = self.status
        if finding != SensorStatus.OK:
            if status == SensorStatus.OK:
                status = self.status = finding
                self.status_history.append((t_ns, finding))
                if self.first_fault_ns is None:
                    self.first_fault_ns = t_ns
                    self.first_fault_status = finding
            self._clean_since_ns = None
        elif status != SensorStatus.OK:
            if self._clean_since_ns is None:
                self._clean_since_ns = t_ns
            elif t_ns - self._clean_since_ns >= self.cfg.heal_ms * NS_PER_MS:
                status = self.status = SensorStatus.OK
                self.status_history.append((t_ns, status))
                self._plaus = 0
        suspicious = (self._plaus or self._e2e_bad or self._range_low or self._range_high
                      or (self.cfg.stuck_samples and self._same >= self.cfg.stuck_samples // 2))
        self.dtc_item.report(t_ns, finding != SensorStatus.OK, bool(suspicious),
                             status == SensorStatus.OK)
        return status

    @property
    def dtc(self) -> DtcState:
        return self.dtc_item.state

    def report(self) -> dict:
        """Diagnosis record for the run summary (times in s)."""
        dtc = self.dtc_item
        return {"status": self.status.name.lower(), "dtc": dtc.state.name.lower(),
                "confirmations": dtc.confirmations, "timeouts": self.timeouts,
                "first_fault_s": None if self.first_fault_ns is None else self.first_fault_ns / 1e9,
                "first_fault_status": (self.first_fault_status.name.lower()
                                       if self.first_fault_status else None),
                "status_history": [(t / 1e9, st.name.lower()) for t, st in self.status_history],
                "dtc_history": [(t / 1e9, st.name.lower()) for t, st in dtc.history]}

    def select(self, t_ns: int, est: float, est_std: float) -> tuple[float, int, SensorStatus]:
        """Diagnose (evaluate) and pick what to broadcast: (value, source, status), the sensor's
        last valid value while it is healthy (SOURCE_SENSOR), else the estimate (SOURCE_ESTIMATE).
        A newly confirmed timeout is counted in `timeouts`."""
        was_ok = self.status == SensorStatus.OK
        status = self.evaluate(t_ns, est, est_std)
        if was_ok and status == SensorStatus.TIMEOUT:
            self.timeouts += 1
        if status == SensorStatus.OK and self.value is not None:
            return self.value, SOURCE_SENSOR, status
        return est, SOURCE_ESTIMATE, status

    @property
    def healthy(self) -> bool:
        return self.status == SensorStatus.OK

