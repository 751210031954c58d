"""Throttle position sensor diagnosis: timeout, electrical range, E2E, stuck, plausibility.

Each check is debounced; the first to confirm sets the status (codes = THR_TpsStatus in the DBC)
and the ECU switches to the estimator. The status heals after `heal_ms` of clean samples.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from vecu.calibration import TpsCalibration
from vecu.clock import NS_PER_MS


class TpsStatus(enum.IntEnum):
    OK = 0
    TIMEOUT = 1
    RANGE_LOW = 2
    RANGE_HIGH = 3
    E2E_ERROR = 4
    IMPLAUSIBLE = 5
    STUCK = 6


class DtcState(enum.IntEnum):
    NONE = 0
    PENDING = 1
    CONFIRMED = 2


@dataclass(frozen=True)
class TpsMonitorConfig:
    cycle_ms: float = 1.0          # from the DBC (GenMsgCycleTime of TPS_Sensor)
    timeout_cycles: int = 3        # frames stop: confirmed after 3 missed periods
    range_debounce: int = 2        # consecutive out-of-range samples
    e2e_debounce: int = 2          # consecutive CRC/counter errors
    stuck_samples: int = 8         # identical raw readings in a row (needs sensor noise)
    plaus_sigma: float = 5.0       # gate in estimator sigmas ...
    plaus_margin_deg: float = 4.0  # ... plus a fixed margin
    plaus_debounce: int = 5        # up/down counter threshold
    heal_ms: float = 500.0         # clean time before the sensor is trusted again


class TpsMonitor:
    """Feed on_frame()/on_e2e_error() as frames arrive, then evaluate() once per ECU tick."""

    def __init__(self, config: TpsMonitorConfig, calibration: TpsCalibration) -> None:
        self.cfg = config
        self.cal = calibration
        self.status = TpsStatus.OK
        self.dtc = DtcState.NONE
        self.first_fault_ns: int | None = None
        self.first_fault_status: TpsStatus | None = None
        self.angle: float | None = None     # last valid sensor angle (deg)
        self._voltage: float | None = None
        self._fresh = False
        self._last_rx_ns: int | None = None
        self._range_low = self._range_high = 0
        self._e2e_bad = 0
        self._same = 0
        self._plaus = 0
        self._clean_since_ns: int | None = None
        self._timeout_ns = int(config.timeout_cycles * config.cycle_ms * NS_PER_MS)

    def on_frame(self, t_ns: int, voltage: float) -> None:
        """A frame that passed DLC/E2E/value checks."""
        self._same = self._same + 1 if voltage == self._voltage else 0
        self._voltage = voltage
        self._last_rx_ns = t_ns
        self._e2e_bad = 0
        self._fresh = True
        cal = self.cal
        self._range_low = self._range_low + 1 if voltage < cal.fault_low_v else 0
        self._range_high = self._range_high + 1 if voltage > cal.fault_high_v else 0
        self.angle = cal.angle(voltage)

    def on_e2e_error(self) -> None:
        self._e2e_bad += 1

    def evaluate(self, t_ns: int, est_deg: float, est_std_deg: float) -> TpsStatus:
        cfg = self.cfg
        finding = TpsStatus.OK
        last_rx = 0 if self._last_rx_ns is None else self._last_rx_ns  # run start counts as rx
        if t_ns - last_rx >= self._timeout_ns:
            finding = TpsStatus.TIMEOUT
        else:
            if self._e2e_bad >= cfg.e2e_debounce:
                finding = TpsStatus.E2E_ERROR
            elif self._range_low >= cfg.range_debounce:
                finding = TpsStatus.RANGE_LOW
            elif self._range_high >= cfg.range_debounce:
                finding = TpsStatus.RANGE_HIGH
            elif self._same + 1 >= cfg.stuck_samples:
                finding = TpsStatus.STUCK
            elif self._fresh and self.angle is not None:
                gate = cfg.plaus_sigma * est_std_deg + cfg.plaus_margin_deg
                if abs(self.angle - est_deg) > gate:
                    if self._plaus < cfg.plaus_debounce:  # saturating up/down counter
                        self._plaus += 1
                elif self._plaus > 0:
                    self._plaus -= 1
                if self._plaus >= cfg.plaus_debounce:
                    finding = TpsStatus.IMPLAUSIBLE
        self._fresh = False
        return self._update(t_ns, finding)

    def _update(self, t_ns: int, finding: TpsStatus) -> TpsStatus:
        if finding != TpsStatus.OK:
            if self.status == TpsStatus.OK:
                self.status = finding
                if self.first_fault_ns is None:
                    self.first_fault_ns = t_ns
                    self.first_fault_status = finding
            self.dtc = DtcState.CONFIRMED
            self._clean_since_ns = None
        elif self.status != TpsStatus.OK:
            if self._clean_since_ns is None:
                self._clean_since_ns = t_ns
            elif t_ns - self._clean_since_ns >= self.cfg.heal_ms * NS_PER_MS:
                self.status = TpsStatus.OK
                self._plaus = 0
        if self.dtc != DtcState.CONFIRMED:  # confirmed is stored for the rest of the run
            suspicious = (self._plaus or self._e2e_bad or self._range_low or self._range_high
                          or self._same >= self.cfg.stuck_samples // 2)
            self.dtc = DtcState.PENDING if suspicious else DtcState.NONE
        return self.status

    @property
    def healthy(self) -> bool:
        return self.status == TpsStatus.OK

