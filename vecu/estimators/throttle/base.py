"""What the ECU needs from a throttle-angle estimator (models and filters live in sibling modules)."""

from __future__ import annotations

from typing import Protocol, runtime_checkable


@runtime_checkable
class ThrottleEstimator(Protocol):
    """A filter tracking the throttle angle from commanded voltage and wattmeter power.

    step(u_prev, y): predict over one 1 ms step with the input applied during it (u_{k-1}), then
    update with the wattmeter reading y_k; y=None (missing / rejected frame) means predict only.
    Implementations never produce NaN: they guard their covariance and reset on divergence,
    counting resets in `resets`.
    """

    name: str
    resets: int

    def step(self, u_prev: float, y: float | None) -> None: ...

    @property
    def theta_deg(self) -> float: ...

    @property
    def theta_std_deg(self) -> float: ...

    def reset(self) -> None: ...
