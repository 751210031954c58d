"""What every vehicle speed / acceleration estimator offers (Hernandez 2005; the 500 Hz Kalman
filter lives in speed.kf)."""

from __future__ import annotations

from typing import Protocol, runtime_checkable


@runtime_checkable
class SpeedEstimator(Protocol):
    """A filter fusing the wheel-speed sensor and the accelerometer (the paper's eq. 25 observer;
    SpeedKalmanFilter at 2 ms): step(wheel_speed, accel) (m/s, m/s^2; None = missing); never NaN.
    standstill / abs_mode: held at rest / following the upper wheel envelope under ABS slip."""

    @property
    def steps(self) -> int: ...

    @property
    def resets(self) -> int: ...

    def step(self, wheel_speed: float | None, accel: float | None) -> None: ...

    def reset(self) -> None: ...

    @property
    def speed_mps(self) -> float: ...

    @property
    def accel_mps2(self) -> float: ...

    @property
    def offset_mps2(self) -> float: ...

    @property
    def speed_std_mps(self) -> float: ...

    @property
    def accel_std_mps2(self) -> float: ...

    @property
    def standstill(self) -> bool: ...

    @property
    def abs_mode(self) -> bool: ...
