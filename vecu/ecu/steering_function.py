"""ECU steering function: steering-wheel angle and side-slip from yaw rate and lateral
acceleration (Khalid), SWA sensor diagnosis and substitution, live fixed-lag smoothing.

Every 10 ms: step the UKF (inside the fixed-lag unscented RTS smoother) with the latest
CHS_Lateral sample, diagnose the SWA sensor against the UKF, send ECU_SteeringEstimate with the
sensor angle while it is healthy and the estimate otherwise, and ECU_SteeringSmoothed with the
smoothed estimate of STS_LagMs ago (flagged invalid until the lag has filled), and
ECU_SteeringSigma with the UKF's reported sigmas (reported_cov: the stiffness error considered). STE_Validity / STS_Validity (vecu.ecu.validity; UDS DID
0x040F) qualify the estimates: init until the first CHS_Lateral frame has been filtered (STS: until
the lag has filled), degraded while the car is slower than V_X_MIN (3 m/s): yaw rate and a_y say
nothing of the steering angle at standstill, so the broadcast sigma then adds the prior's
(sqrt(sigma_UKF^2 + sigma_prior^2), about 80 deg). The SWA monitor gates on the
UKF's reported sigma.
"""

from __future__ import annotations

import math
from collections import deque
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
from vecu.ecu.sensor_monitor import (
    SOURCE_SENSOR,
    SensorMonitor,
    SensorMonitorConfig,
    SensorStatus,
)
from vecu.ecu.sensor_monitor import SensorStatus as S
from vecu.ecu.validity import DEGRADED, INIT, VALID
from vecu.estimators.steering.filters import SteeringUKF
from vecu.estimators.steering.model import V_X_MIN, SteeringModel
from vecu.estimators.steering.smoothers import FixedLagSmoother
from vecu.units import DEG_PER_RAD, MPS_PER_KMH

SWA_LIMIT_DEG = 780.0  # lock to lock of a passenger car, about 2.2 turns each way


# failure type bytes (SAE J2012-DA): 0x21/0x22 signal amplitude < min / > max, 0x64 signal
# plausibility failure, 0x83 value of signal protection calculation incorrect (CRC / alive
# counter), 0x87 missing message
DTCS: tuple[DtcSpec, ...] = (
    DtcSpec(0x446087, "swa", (S.TIMEOUT,), "steering angle sensor: missing message"),
    DtcSpec(0x446083, "swa", (S.E2E_ERROR,), "steering angle sensor: signal protection (E2E)"),
    DtcSpec(0x446021, "swa", (S.RANGE_LOW,), "steering angle sensor: signal below minimum"),
    DtcSpec(0x446022, "swa", (S.RANGE_HIGH,), "steering angle sensor: signal above maximum"),
    DtcSpec(0x446064, "swa", (S.IMPLAUSIBLE, S.STUCK),
            "steering angle sensor: implausible against the estimate, or stuck"),
)

@dataclass(frozen=True)
class SteeringFunctionConfig:
    # the smoother keeps lag_s / 10 ms steps; STS_LagMs carries at most 4095 ms
    lag_s: float = field(default=0.25, metadata={"bounds": (0.01, 4.0)})
    # 10 ms frames; the sensor has 0.1 deg noise on a 0.05 deg LSB, so two equal consecutive
    # readings happen ~14 % of the time: 10 in a row ~ 2e-8 per frame.
    monitor: SensorMonitorConfig = field(default_factory=lambda: SensorMonitorConfig(
        cycle_ms=10.0, stuck_samples=10, plaus_sigma=5.0, plaus_margin=4.0, heal_ms=500.0))
    model: SteeringModel = field(default_factory=SteeringModel)  # vehicle + UKF tuning


class SteeringFunction:
    name = "steering"
    period_ns = 10 * NS_PER_MS

    def __init__(self, codec: DbcCodec,
                 config: SteeringFunctionConfig = SteeringFunctionConfig()) -> None:
        self.smoother = FixedLagSmoother(lag_s=config.lag_s, filt=SteeringUKF(config.model))
        self.ukf = self.smoother.filter
        self._est = codec["ECU_SteeringEstimate"]
        e2e = self._est.e2e
        assert e2e is not None, "the DBC's safety frame has no E2E layout"
        self._modulo = e2e.protection.counter_modulo  # P11: 0..14
        self._smoothed = codec["ECU_SteeringSmoothed"]
        self._est_frame = self._est.framer((
            "STE_CRC", "STE_AliveCounter", "STE_Source", "STE_Validity", "STE_SwAngle",
            "STE_SwAngleEst", "STE_SideSlip", "STE_SwaStatus"))
        self._smoothed_frame = self._smoothed.framer(
            ("STS_SwAngle", "STS_SideSlip", "STS_LagMs", "STS_Valid", "STS_Validity"))
        self._sigma_frame = codec["ECU_SteeringSigma"].framer(
            ("STE_SwAngleEstStd", "STE_SideSlipStd"))
        cycle = codec["SWA_Sensor"].cycle_time_ms or config.monitor.cycle_ms
        self.monitor = SensorMonitor(replace(config.monitor, cycle_ms=cycle), -SWA_LIMIT_DEG,
                                     SWA_LIMIT_DEG, float)
        self.estimates_sent = 0
        self._tx_counter = 0
        self._vx: float | None = None
        self._r: float | None = None
        self._ay: float | None = None
        # last outputs (deg), read by probes
        self.angle = 0.0
        self.source = SOURCE_SENSOR
        self.status = SensorStatus.OK
        self.lagged: tuple[int, float, float] | None = None  # (lag in ms, SWA, side-slip)
        self.validity = INIT
        self.smoothed_validity = INIT
        self.swa_std = 0.0  # the broadcast STE_SwAngleEstStd (deg)
        self._filtered = False  # a CHS_Lateral frame has been filtered
        self._speed = 0.0  # the last CHS_Lateral speed (m/s, not clipped)
        # per step: the car below V_X_MIN, as far back as the smoother's lag
        self._slow: deque[bool] = deque(maxlen=self.smoother.lag + 1)

    @property
    def timeouts(self) -> int:
        return self.monitor.timeouts

    def monitors(self) -> dict[str, SensorMonitor]:
        return {"swa": self.monitor}

    def subscriptions(self) -> list[Subscription]:
        return [Subscription("CHS_Lateral", self._on_lateral),
                Subscription("SWA_Sensor", self._on_swa, self.monitor.on_e2e_error)]

    def _on_lateral(self, values: dict[str, float], t_ns: int) -> None:
        self._vx = values["LAT_VehSpeed"] * MPS_PER_KMH
        self._r = values["LAT_YawRate"] / DEG_PER_RAD
        self._ay = values["LAT_LatAccel"]

    def _on_swa(self, values: dict[str, float], t_ns: int) -> None:
        self.monitor.on_frame(t_ns, values["SWA_Angle"])

    def run(self, t_ns: int, send: Send) -> None:
        vx = self._vx
        if vx is not None:
            self._filtered = True
            if math.isfinite(vx):
                self._speed = abs(vx)
        lagged = self.smoother.step(vx, self._r, self._ay)
        self._vx = self._r = self._ay = None
        ukf = self.ukf
        est, std, beta = ukf.swa_rad * DEG_PER_RAD, ukf.swa_std_rad * DEG_PER_RAD, ukf.side_slip_rad * DEG_PER_RAD
        angle, source, status = self.monitor.select(t_ns, est, std)
        self.angle, self.source, self.status = angle, source, status
        slow = self._speed < V_X_MIN
        self._slow.append(slow)
        if not self._filtered:
            validity = INIT
        elif slow:  # not observable: the prior's sigma too
            validity = DEGRADED
            std = math.hypot(std, ukf.swa_prior_std_rad * DEG_PER_RAD)
        else:
            validity = VALID
        self.validity, self.swa_std = validity, std
        ts = t_ns / NS_PER_S
        send(*self._sigma_frame(ts, std, ukf.side_slip_std_rad * DEG_PER_RAD))
        self.estimates_sent += send(*self._est_frame(
            ts, 0, self._tx_counter, source, validity, angle, est, beta, int(status)))
        self._tx_counter = (self._tx_counter + 1) % self._modulo
        if lagged is not None:
            lag_ms = round(lagged.lag_steps * self.period_ns / NS_PER_MS)
            self.lagged = (lag_ms, lagged.swa_rad * DEG_PER_RAD, lagged.side_slip_rad * DEG_PER_RAD)
        lag = self.lagged
        if lag:
            self.smoothed_validity = DEGRADED if self._slow[0] else VALID
            send(*self._smoothed_frame(ts, lag[1], lag[2], lag[0], 1, self.smoothed_validity))
        else:
            send(*self._smoothed_frame(ts, 0.0, 0.0, 0, 0, INIT))

    def status_signals(self) -> dict[str, int]:
        return {}

    def dids(self) -> list[Did]:
        """UDS: SWA broadcast and estimate, side-slip, SWA input and status."""
        ukf, smon = self.ukf, self.monitor
        return [
            Did(0x0400, "steering-wheel angle (broadcast)", "h", 0.05, "deg",
                lambda: self.angle),
            Did(0x0401, "steering-wheel angle estimate", "h", 0.05, "deg",
                lambda: ukf.swa_rad * DEG_PER_RAD),
            Did(0x0402, "side-slip angle estimate", "h", 0.01, "deg",
                lambda: ukf.side_slip_rad * DEG_PER_RAD),
            Did(0x0403, "steering-wheel angle sensor (last valid)", "h", 0.05, "deg",
                lambda: smon.value, io=("SWA_Sensor", "SWA_Angle")),
            Did(0x0404, "steering-wheel angle sensor status", "B", 1, "", status_reader(smon)),
            Did(0x0405, "steering-wheel angle estimate std", "H", 0.01, "deg",
                lambda: self.swa_std),
            Did(0x0406, "side-slip angle estimate std", "H", 0.001, "deg",
                lambda: ukf.side_slip_std_rad * DEG_PER_RAD),
            validity_did(0x040F, "steering estimate validity", lambda: self.validity),
        ]

    def dtcs(self) -> tuple[DtcSpec, ...]:
        """UDS: the SWA sensor's DTCs."""
        return DTCS

    def calibrations(self) -> Calibrations:
        """Taken mid-run (XCP, timed sets): the SWA monitor's settings."""
        return {"steering.monitor": self.monitor.recalibrate}

    def variables(self) -> list[Variable]:
        """XCP measurements: the SWA broadcast and its source."""
        return [
            Variable("steering.angle_deg", "deg", FLOAT, lambda: self.angle, -1000, 1000,
                     "steering-wheel angle broadcast (sensor or estimate)"),
            Variable("steering.source", "1", UBYTE, lambda: self.source, 0, 1,
                     "0 sensor, 1 estimate"),
        ]
