"""The model-only baseline of the throttle estimators ('open-loop' in estimators.registry)."""

from __future__ import annotations

from vecu.estimators.throttle.ukf_fast import FastThrottleUKF
from vecu.models.throttle import PAPER_THROTTLE, ThrottleModel


class OpenLoopThrottle:
    """Baseline: the AHSM filter's prediction only, y ignored (what the model alone knows).

    Its error is what an estimator must beat for the wattmeter to be worth anything.
    """

    def __init__(self, noise_scale: float = 1.0, model: ThrottleModel = PAPER_THROTTLE) -> None:
        self._ukf = FastThrottleUKF("ahsm", noise_scale, model=model)
        self.name = "open-loop"

    @property
    def resets(self) -> int:
        return self._ukf.resets

    def step(self, u_prev: float, y: float | None) -> None:
        self._ukf.step(u_prev, None)

    @property
    def theta_deg(self) -> float:
        return self._ukf.theta_deg

    @property
    def theta_std_deg(self) -> float:
        return self._ukf.theta_std_deg

    def reset(self) -> None:
        self._ukf.reset()
