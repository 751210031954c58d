"""What every intake-manifold estimator offers (Dutka 2006; the EKF and the SDKF live in
manifold.filters)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np

from vecu.models.manifold_params import EngineInput, ManifoldParams


@runtime_checkable
class ManifoldEstimator(Protocol):
    """An event-rate filter on the augmented model of eq. 10, x = (u_prev, alpha, alpha_prev,
    P_im, T_im, T_im.meas), y = (TA, P_im, T_im.out) (ManifoldEKF, ManifoldSDKF).

    step(y, u) at engine event n: update with y_n (None: predict only; a NaN or implausible
    channel is rejected and counted, the others used), then predict x_n+1|n with the event's
    input u_n (eqs. 12-14 for the SDKF). Returns the posterior x_n|n (a copy); afterwards
    `last_prediction` is (u_n, f(x_n|n, u_n)), or None when the step reset the filter. The
    outputs never become NaN: a diverged filter resets to its prior, counted in `resets`.
    """

    @property
    def name(self) -> str: ...

    @property
    def params(self) -> ManifoldParams: ...

    @property
    def events(self) -> int: ...

    @property
    def resets(self) -> int: ...

    @property
    def last_prediction(self) -> tuple[EngineInput, np.ndarray] | None: ...

    def step(self, y: Sequence[Any] | None, u: EngineInput) -> np.ndarray: ...

    def reset(self) -> None: ...

    @property
    def p_im(self) -> float: ...

    @property
    def t_im(self) -> float: ...

    @property
    def alpha(self) -> float: ...
