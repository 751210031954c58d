"""ECU speed function: vehicle speed and acceleration at 500 Hz (Hernandez 2005), wheel-speed
diagnosis.

Every 2 ms: diagnose the wheel-speed reading of the latest ESC_Motion frame (receive deadline from
the DBC cycle time, range, plausibility against the filter's speed), feed the Kalman filter the
wheel speed only while the sensor is healthy and the accelerometer always (no new frame: None,
predict only), and send ECU_SpeedEstimate (km/h, m/s^2 at the boundary). While the wheel sensor is
faulty the filter coasts on the accelerometer and SPD_Mode reads 3 (coast), SPD_Validity
degraded; until the first wheel-speed frame has initialised the filter SPD_Validity reads init
(vecu.ecu.validity), the UDS DID 0x030F too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.codec import DbcCodec
from vecu.ecu.diagnostics import (
    FLOAT,
    UBYTE,
    Calibrations,
    Did,
    DtcSpec,
    Variable,
    status_reader,
    validity_did,
)
from vecu.ecu.node import Send, Subscription
from vecu.ecu.sensor_monitor import SensorMonitor, SensorMonitorConfig, SensorStatus
from vecu.ecu.sensor_monitor import SensorStatus as S
from vecu.ecu.validity import DEGRADED, INIT, VALID
from vecu.estimators.speed.kf import SpeedFilterConfig, SpeedKalmanFilter
from vecu.units import MPS_PER_KMH

MODE_NORMAL, MODE_STANDSTILL, MODE_ABS, MODE_COAST = 0, 1, 2, 3
WHEEL_MAX_KMH = 280.0  # above: a short to supply / garbage (the car cannot go faster)


_OK, _TIMEOUT = SensorStatus.OK, SensorStatus.TIMEOUT  # bound once (per-tick code)


# failure type bytes (SAE J2012-DA): 0x21/0x22 signal amplitude < min / > max, 0x64 signal
# plausibility failure, 0x83 value of signal protection calculation incorrect (CRC / alive
# counter), 0x87 missing message
DTCS: tuple[DtcSpec, ...] = (
    DtcSpec(0x403587, "wheel", (S.TIMEOUT,), "wheel speed sensor: missing message (ESC_Motion)"),
    DtcSpec(0x403521, "wheel", (S.RANGE_LOW,), "wheel speed sensor: signal below minimum"),
    DtcSpec(0x403522, "wheel", (S.RANGE_HIGH,), "wheel speed sensor: signal above maximum"),
    DtcSpec(0x403564, "wheel", (S.IMPLAUSIBLE, S.STUCK),
            "wheel speed sensor: implausible against the speed filter"),
)

@dataclass(frozen=True)
class SpeedFunctionConfig:
    # Wheel speed reads exactly 0 below ~5 km/h (no pulses) and at rest, so the stuck check is off
    # (stuck_samples=0); a dead sensor at speed is caught by plausibility: |wheel - v_hat| beyond
    # 5 sigma + 10 km/h (ABS slip reaches 20 % of 84 km/h; below ~10 km/h a dead sensor looks like
    # a normal dropout and cannot be told apart).
    wheel_monitor: SensorMonitorConfig = field(default_factory=lambda: SensorMonitorConfig(
        cycle_ms=2.0, stuck_samples=0, plaus_sigma=5.0, plaus_margin=10.0, plaus_debounce=5))
    filter: SpeedFilterConfig = field(default_factory=SpeedFilterConfig)  # the 500 Hz KF


class SpeedFunction:
    name = "speed"
    period_ns = 2 * NS_PER_MS

    def __init__(self, codec: DbcCodec, kf: SpeedKalmanFilter | None = None,
                 config: SpeedFunctionConfig = SpeedFunctionConfig()) -> None:
        self.kf = kf if kf is not None else SpeedKalmanFilter(config.filter)
        self._out = codec["ECU_SpeedEstimate"]
        self._out_frame = self._out.framer(("SPD_VehSpeed", "SPD_VehAccel", "SPD_VehSpeedStd",
                                            "SPD_AccelOffset", "SPD_Mode", "SPD_Validity",
                                            "SPD_VehAccelStd"))
        cycle = codec["ESC_Motion"].cycle_time_ms or config.wheel_monitor.cycle_ms
        self.monitor = SensorMonitor(replace(config.wheel_monitor, cycle_ms=cycle), 0.0,
                                     WHEEL_MAX_KMH, float)
        self.estimates_sent = 0
        self.coast_steps = 0  # filter steps without the wheel speed (sensor faulty)
        self._wheel: float | None = None
        self._accel: float | None = None
        self.mode = MODE_NORMAL
        self.validity = INIT
        # the filter's reported (var v, cov, var a) in one call, when it has one (SpeedKalmanFilter;
        # the std properties compute it each): the frame's two sigmas from one evaluation
        self._va_cov = getattr(self.kf, "reported_va_cov", None)
        self._has_init = hasattr(self.kf, "initialised")

    # ECU_RxTimeouts keeps counting the TPS and SWA deadlines only (as before this monitor
    # existed); wheel-speed timeouts are in ECU_Diag (DIAG_WheelStatus/Dtc) and the run summary.
    timeouts = 0

    def monitors(self) -> dict[str, SensorMonitor]:
        return {"wheel": self.monitor}

    def subscriptions(self) -> list[Subscription]:
        return [Subscription("ESC_Motion", self._on_motion)]

    def _on_motion(self, values: dict[str, float], t_ns: int) -> None:
        wheel_kmh = values["ESC_WheelSpeed"]
        self.monitor.on_frame(t_ns, wheel_kmh)
        self._wheel = wheel_kmh * MPS_PER_KMH
        self._accel = values["ESC_LongAccel"]

    def run(self, t_ns: int, send: Send) -> None:
        kf = self.kf
        # diagnose against the filter's speed before this reading is used (innovation gate)
        mon = self.monitor
        was_ok = mon.status == _OK
        # until the filter has taken its first wheel reading its speed means nothing: no gate
        initialised = kf.initialised if self._has_init else True
        std = kf.speed_std_mps / MPS_PER_KMH if initialised else math.inf
        status = mon.evaluate(t_ns, kf.speed_mps / MPS_PER_KMH, std)
        if was_ok and status == _TIMEOUT:
            mon.timeouts += 1
        wheel = self._wheel
        if status != _OK:
            wheel = None
            self.coast_steps += 1
        kf.step(wheel, self._accel)
        self._wheel = self._accel = None
        if status != _OK:
            mode = MODE_COAST
        else:
            mode = MODE_STANDSTILL if kf.standstill else (MODE_ABS if kf.abs_mode else MODE_NORMAL)
        self.mode = mode
        self.validity = validity = (INIT if not (kf.initialised if self._has_init else True)
                                    else VALID if status == _OK else DEGRADED)
        cov = self._va_cov
        if cov is not None:
            var_v, _, var_a = cov()
            v_std, a_std = math.sqrt(var_v), math.sqrt(var_a)
        else:
            v_std, a_std = kf.speed_std_mps, kf.accel_std_mps2
        self.estimates_sent += send(*self._out_frame(
            t_ns / NS_PER_S, kf.speed_mps / MPS_PER_KMH, kf.accel_mps2, v_std / MPS_PER_KMH,
            kf.offset_mps2, mode, validity, a_std))

    def status_signals(self) -> dict[str, int]:
        return {}

    def dids(self) -> list[Did]:
        """UDS: speed, acceleration, wheel-speed input and status, filter mode."""
        kf, wmon = self.kf, self.monitor
        return [
            Did(0x0300, "vehicle speed", "H", 0.01, "km/h", lambda: kf.speed_mps / MPS_PER_KMH),
            Did(0x0301, "vehicle acceleration", "h", 0.001, "m/s^2", lambda: kf.accel_mps2),
            Did(0x0302, "wheel speed (last valid)", "H", 0.01, "km/h", lambda: wmon.value,
                io=("ESC_Motion", "ESC_WheelSpeed")),
            Did(0x0303, "wheel-speed sensor status", "B", 1, "", status_reader(wmon)),
            Did(0x0304, "speed filter mode (0 normal, 1 standstill, 2 ABS, 3 coast)", "B", 1,
                "", lambda: float(self.mode)),
            Did(0x0305, "vehicle speed std", "H", 0.01, "km/h",
                lambda: kf.speed_std_mps / MPS_PER_KMH),
            validity_did(0x030F, "speed estimate validity", lambda: self.validity),
        ]

    def dtcs(self) -> tuple[DtcSpec, ...]:
        """UDS: the WHEEL sensor's DTCs."""
        return DTCS

    def calibrations(self) -> Calibrations:
        """Taken mid-run (XCP, timed sets): the WHEEL monitor's settings."""
        return {"speed.wheel_monitor": self.monitor.recalibrate}

    def variables(self) -> list[Variable]:
        """XCP measurements: the filter's speed, sigma, acceleration, offset and mode."""
        kf = self.kf
        return [
            Variable("speed.speed_mps", "m/s", FLOAT, lambda: kf.speed_mps, -100, 100,
                     "vehicle speed estimate"),
            Variable("speed.speed_std_mps", "m/s", FLOAT, lambda: kf.speed_std_mps, 0, 100,
                     "vehicle speed standard deviation"),
            Variable("speed.accel_mps2", "m/s^2", FLOAT, lambda: kf.accel_mps2, -50, 50,
                     "longitudinal acceleration estimate"),
            Variable("speed.offset_mps2", "m/s^2", FLOAT, lambda: kf.offset_mps2, -50, 50,
                     "accelerometer offset state"),
            Variable("speed.mode", "1", UBYTE, lambda: self.mode, 0, 3,
                     "0 normal, 1 standstill, 2 ABS, 3 coast"),
            Variable("speed.validity", "1", UBYTE, lambda: self.validity, 0, 3,
                     "0 init, 1 valid, 2 degraded, 3 invalid"),
        ]
