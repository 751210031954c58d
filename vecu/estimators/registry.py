"""Estimators by name, one table entry per family (ESTIMATORS: names and a make(name, ...)):
what `vecu run` / `vecu eval` and the parameter tree (ecu.throttle.estimator,
ecu.manifold.filter) accept. The throttle family's filters are listed here; the other
families' makers import their modules on first use: reading the names imports nothing heavy
(the command line's choices come from here)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from vecu.errors import BadArgumentError, UnavailableError

if TYPE_CHECKING:
    from vecu.estimators.throttle.base import ThrottleEstimator
    from vecu.models.throttle import ThrottleModel

_PAPER = ("ahsm", "arm", "agm")
# The paper filters (plain floats), the model-only baseline and the production estimator.
THROTTLE_ESTIMATORS: tuple[str, ...] = (*_PAPER, "open-loop", "production")


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
    from vecu.models.throttle import PAPER_THROTTLE

    if name in _PAPER:
        from vecu.estimators.throttle.ukf_fast import FastThrottleUKF

        return FastThrottleUKF(name, noise_scale, model=model or PAPER_THROTTLE)
    if name == "open-loop":
        from vecu.estimators.throttle.open_loop import OpenLoopThrottle

        return OpenLoopThrottle(noise_scale, model or PAPER_THROTTLE)
    if name == "production":
        try:
            from vecu.estimators.throttle.pf.filter import make_production_estimator
        except ImportError as exc:
            raise EstimatorUnavailableError(
                "throttle estimator 'production' is unavailable: cannot import "
                f"make_production_estimator from vecu.estimators.throttle.pf.filter ({exc})"
            ) from exc
        if model is None:
            return make_production_estimator(noise_scale)
        return make_production_estimator(noise_scale, model=model)
    raise BadArgumentError(
        f"unknown throttle estimator {name!r}; choose from {', '.join(THROTTLE_ESTIMATORS)}"
    )


# ecu.manifold.filter: Dutka 2006's EKF and SDKF, the adaptive EKF
MANIFOLD_FILTERS: tuple[str, ...] = ("sdkf", "ekf", "adaptive")


def make_manifold_filter(name: str, config: Any = None, x0: Any = None) -> Any:
    """A manifold filter by name (estimators.manifold.factory.make_filter, which also takes the
    Riccati variants 'sdkf_doubling', 'sdkf_scipy')."""
    from vecu.estimators.manifold.factory import make_filter
    from vecu.estimators.manifold.filters import ManifoldFilterConfig

    return make_filter(name, config if config is not None else ManifoldFilterConfig(), x0)


def make_speed_estimator(name: str = "kf", config: Any = None) -> Any:
    """'kf': Hernandez 2005's 500 Hz Kalman filter."""
    from vecu.estimators.speed.kf import SpeedFilterConfig, SpeedKalmanFilter

    if name != "kf":
        raise BadArgumentError(f"unknown speed estimator {name!r}; choose from kf")
    return SpeedKalmanFilter(config if config is not None else SpeedFilterConfig())


def make_steering_estimator(name: str = "ukf-smoother", model: Any = None,
                            lag_s: float = 0.25) -> Any:
    """'ukf': Khalid's UKF; 'ukf-smoother': the UKF inside the fixed-lag unscented RTS
    smoother (what the ECU runs)."""
    from vecu.estimators.steering.filters import SteeringUKF
    from vecu.estimators.steering.model import SteeringModel
    from vecu.estimators.steering.smoothers import FixedLagSmoother

    ukf = SteeringUKF(model if model is not None else SteeringModel())
    if name == "ukf":
        return ukf
    if name == "ukf-smoother":
        return FixedLagSmoother(lag_s=lag_s, filt=ukf)
    raise BadArgumentError(f"unknown steering estimator {name!r}; choose from ukf, ukf-smoother")


@dataclass(frozen=True)
class EstimatorFamily:
    """One family's estimators: the names it accepts and make(name, ...) -> a fresh one."""

    names: tuple[str, ...]
    make: Callable[..., Any]


ESTIMATORS: dict[str, EstimatorFamily] = {
    "throttle": EstimatorFamily(THROTTLE_ESTIMATORS, make_throttle_estimator),
    "speed": EstimatorFamily(("kf",), make_speed_estimator),
    "steering": EstimatorFamily(("ukf", "ukf-smoother"), make_steering_estimator),
    "manifold": EstimatorFamily(MANIFOLD_FILTERS, make_manifold_filter),
}
