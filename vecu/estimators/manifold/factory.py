"""make_filter: a manifold filter by name (the paper's EKF and SDKF variants, the adaptive EKF)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from vecu.estimators.manifold.adaptive import ManifoldAdaptive
from vecu.estimators.manifold.filters import (
    RICCATI_MODES,
    ManifoldEKF,
    ManifoldFilterConfig,
    ManifoldSDKF,
    _ManifoldKF,
)


def make_filter(name: str, config: ManifoldFilterConfig = ManifoldFilterConfig(),
                x0: np.ndarray | None = None) -> _ManifoldKF:
    """'ekf', 'sdkf' (iterate), 'sdkf_doubling', 'sdkf_scipy', 'adaptive'."""
    if name == "adaptive":
        return ManifoldAdaptive(config, x0)
    if name == "ekf":
        return ManifoldEKF(config, x0)
    if name == "sdkf":
        return ManifoldSDKF(replace(config, riccati="iterate"), x0)
    if name.startswith("sdkf_") and name[5:] in RICCATI_MODES:
        return ManifoldSDKF(replace(config, riccati=name[5:]), x0)
    raise ValueError(f"unknown manifold filter {name!r}")
