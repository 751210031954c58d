"""What every intake-manifold estimator offers (Dutka 2006; the EKF and the SDKF live in
manifold.filters)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np

from vecu.models.manifold_params import EngineInput, ManifoldParams


@runtime_checkable
class ManifoldEstimator(Protocol):
    """An event-rate filter on the augmented model of eq. 10 (manifold.filters): step(y_n, u_n)
    -> x_n|n, `last_prediction` (u_n, f(x_n|n, u_n)) or None after a reset; never NaN."""

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
