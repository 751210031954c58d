"""ECU speed function: vehicle speed and acceleration at 500 Hz (Hernandez 2005).

Every 2 ms: feed the latest ESC_Motion sample (wheel speed, accelerometer; None when no new
frame arrived) to the Kalman filter and send ECU_SpeedEstimate (km/h, m/s^2 at the boundary).
"""

from __future__ import annotations

from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.codec import DbcCodec
from vecu.ecu.node import Send, Subscription
from vecu.estimators.speed_kf import SpeedKalmanFilter
from vecu.plant.longitudinal import KMH

MODE_NORMAL, MODE_STANDSTILL, MODE_ABS = 0, 1, 2


class SpeedFunction:
    name = "speed"
    period_ns = 2 * NS_PER_MS

    def __init__(self, codec: DbcCodec, kf: SpeedKalmanFilter | None = None) -> None:
        self.kf = kf if kf is not None else SpeedKalmanFilter()
        self._out = codec["ECU_SpeedEstimate"]
        self.timeouts = 0
        self.estimates_sent = 0
        self._wheel: float | None = None
        self._accel: float | None = None

    def subscriptions(self) -> list[Subscription]:
        return [Subscription("ESC_Motion", self._on_motion)]

    def _on_motion(self, values: dict[str, float], t_ns: int) -> None:
        self._wheel = values["ESC_WheelSpeed"] * KMH
        self._accel = values["ESC_LongAccel"]

    def run(self, t_ns: int, send: Send) -> None:
        kf = self.kf
        kf.step(self._wheel, self._accel)
        self._wheel = self._accel = None
        mode = MODE_STANDSTILL if kf.standstill else (MODE_ABS if kf.abs_mode else MODE_NORMAL)
        self.estimates_sent += send(self._out.frame({
            "SPD_VehSpeed": kf.speed_mps / KMH, "SPD_VehAccel": kf.accel_mps2,
            "SPD_VehSpeedStd": kf.speed_std_mps / KMH, "SPD_AccelOffset": kf.offset_mps2,
            "SPD_Mode": mode,
        }, t_ns / NS_PER_S))

    def status_signals(self) -> dict[str, int]:
        return {}
