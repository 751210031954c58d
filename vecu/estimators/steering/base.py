"""What every steering-wheel angle / side-slip estimator offers (Khalid et al.; filters and
smoothers live in sibling modules), and the outputs they share."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from vecu.estimators.steering.model import SteeringModel


@dataclass(frozen=True, eq=False)
class FilterRun:
    """A recorded forward pass, arrays over steps k = 0..N-1 (steering.filters' docstring).
    x_pred[0], P_pred[0], C[0] link the prior to step 0; after a divergence reset C[k] = 0."""

    x: np.ndarray  # (N, 4) filtered
    P: np.ndarray  # (N, 4, 4)
    x_pred: np.ndarray  # (N, 4)
    P_pred: np.ndarray  # (N, 4, 4)
    C: np.ndarray  # (N, 4, 4)
    v_x: np.ndarray  # (N,) speed used by the predict into step k


@dataclass(frozen=True, eq=False)
class LaggedEstimate:
    """Fixed-lag smoothed state of step `step` (time t_s), produced `lag_steps` steps later."""

    step: int
    t_s: float
    lag_steps: int
    x: np.ndarray  # [v_y, r, delta, delta_dot]
    swa_rad: float
    side_slip_rad: float


@runtime_checkable
class SteeringEstimator(Protocol):
    """A filter (SteeringUKF, SteeringEKF) or a live smoother around one (FixedLagSmoother)
    tracking x = [v_y, r, delta, delta_dot] at 100 Hz (the paper's eqs. 1-3, 17-26).
    step(v_x, yaw_rate, a_y) (m/s, rad/s, m/s^2; None = missing) returns a fixed-lag smoother's
    lagged estimate, None for a filter; the outputs are the current filtered estimate, never NaN.
    """

    @property
    def model(self) -> SteeringModel: ...

    @property
    def steps(self) -> int: ...

    @property
    def resets(self) -> int: ...

    def step(self, v_x: float | None, yaw_rate: float | None, a_y: float | None
             ) -> LaggedEstimate | None: ...

    def reset(self) -> None: ...

    @property
    def swa_rad(self) -> float: ...

    @property
    def swa_std_rad(self) -> float: ...

    @property
    def side_slip_rad(self) -> float: ...
