"""Throttle estimators by name (what `vecu run` / `vecu eval` accept)."""

from __future__ import annotations

from vecu.errors import BadArgumentError, UnavailableError
from vecu.estimators.throttle.base import ThrottleEstimator
from vecu.models.throttle import PAPER_THROTTLE, ThrottleModel

_PAPER = ("ahsm", "arm", "agm")
# Fast (plain-float) paper filters, their numpy reference versions, the model-only baseline and
# the production estimator.
THROTTLE_ESTIMATORS: tuple[str, ...] = (
    *_PAPER, *(f"{s}-numpy" for s in _PAPER), "open-loop", "production",
)


class OpenLoopThrottle:
    """Baseline: the AHSM filter's prediction only, y ignored (what the model alone knows).

    Its error is what an estimator must beat for the wattmeter to be worth anything.
    """

    def __init__(self, noise_scale: float = 1.0, model: ThrottleModel = PAPER_THROTTLE) -> None:
        from vecu.estimators.throttle.ukf_fast import FastThrottleUKF

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


class EstimatorUnavailableError(UnavailableError, ValueError):
    """A known estimator name whose implementation could not be imported (a user error, exit 2,
    and a ValueError like an unknown name)."""


def make_throttle_estimator(name: str, noise_scale: float = 1.0,
                            model: ThrottleModel | None = None) -> ThrottleEstimator:
    """Build a fresh estimator. noise_scale is the alpha the filter assumes for F (Q = (alpha F)^2),
    model its calibration (eq. 3 modes, switching angles, F, H; None: Table I).

    Raises BadArgumentError (a ValueError) for an unknown name, EstimatorUnavailableError if
    "production" cannot be imported (the other names never depend on it).
    """
    if name in _PAPER:
        from vecu.estimators.throttle.ukf_fast import FastThrottleUKF

        return FastThrottleUKF(name, noise_scale, model=model or PAPER_THROTTLE)
    if name.endswith("-numpy") and name[: -len("-numpy")] in _PAPER:
        from vecu.estimators.throttle.model import NumpyThrottleUKF

        return NumpyThrottleUKF(name[: -len("-numpy")], noise_scale, model or PAPER_THROTTLE)
    if name == "open-loop":
        return OpenLoopThrottle(noise_scale, model or PAPER_THROTTLE)
    if name == "production":
        try:
            from vecu.estimators.throttle.production import make_production_estimator
        except ImportError as exc:
            raise EstimatorUnavailableError(
                "throttle estimator 'production' is unavailable: cannot import "
                f"make_production_estimator from vecu.estimators.throttle.production ({exc})"
            ) from exc
        if model is None:
            return make_production_estimator(noise_scale)
        return make_production_estimator(noise_scale, model=model)
    raise BadArgumentError(
        f"unknown throttle estimator {name!r}; choose from {', '.join(THROTTLE_ESTIMATORS)}"
    )
