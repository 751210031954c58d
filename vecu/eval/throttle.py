"""Offline accuracy of throttle estimators against the simulated *true* angle.

The plant (vecu.plant.throttle.simulate) gives u_k, the true theta_k and y_k measured on x_k.
Each estimator is fed est.step(u_{k-1}, y_k) (k = 0: step(0.0, y_0)) and theta_hat_k is compared
with theta_k. Statistics skip the first `burn_in` steps (default 1000 = 1 s, the prior x0 = 0,
P0 = I having been forgotten by then). Note: the paper's Table II compares with the model's
"statistical mean" instead; we do not (docs/models.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from vecu.clock import perf_s
from vecu.estimators.registry import make_throttle_estimator
from vecu.estimators.throttle.base import ThrottleEstimator
from vecu.plant.throttle import ThrottleTrace, simulate

DEFAULT_BURN_IN = 1000


@dataclass(frozen=True)
class ThrottleEvalResult:
    """Error statistics of one estimator over steps burn_in..steps-1 (degrees)."""

    filter: str
    mean_deg: float  # mean of theta_hat - theta_true
    std_deg: float  # standard deviation of the error
    rms_deg: float
    mean_sigma_deg: float  # mean of the filter's own sqrt(P_theta)
    us_per_step: float  # wall time per step() incl. the harness reading theta and sigma
    resets: int  # divergence resets over the whole run


@dataclass(frozen=True)
class ThrottleEvalReport:
    """A whole evaluation: settings, the truth's own spread, one result per filter."""

    steps: int
    burn_in: int
    noise_scale: float
    seed: int
    filter_noise_scale: float
    theta_true_std_deg: float  # spread of theta itself: the error of a constant estimate
    results: tuple[ThrottleEvalResult, ...]


def run_estimator(
    est: ThrottleEstimator, trace: ThrottleTrace
) -> tuple[np.ndarray, np.ndarray, float]:
    """Feed the trace; return theta_hat_k, the filter's sigma_k and the seconds spent looping."""
    u = trace.u.tolist()
    y = trace.y.tolist()
    n = len(y)
    th = [0.0] * n
    sd = [0.0] * n
    step = est.step
    up = 0.0
    t0 = perf_s()
    for k in range(n):
        step(up, y[k])
        th[k] = est.theta_deg
        sd[k] = est.theta_std_deg
        up = u[k]
    elapsed = perf_s() - t0
    return np.asarray(th), np.asarray(sd), elapsed


def error_stats(
    name: str, theta_hat: np.ndarray, sigma: np.ndarray, theta_true: np.ndarray,
    burn_in: int, elapsed_s: float, resets: int,
) -> ThrottleEvalResult:
    """Statistics of theta_hat - theta_true after burn_in."""
    e = theta_hat[burn_in:] - theta_true[burn_in:]
    n = len(theta_true)
    return ThrottleEvalResult(
        filter=name,
        mean_deg=float(e.mean()),
        std_deg=float(e.std()),
        rms_deg=float(math.sqrt(float(np.mean(e * e)))),
        mean_sigma_deg=float(sigma[burn_in:].mean()),
        us_per_step=1e6 * elapsed_s / n,
        resets=int(resets),
    )


def evaluate_throttle(
    filters: Sequence[str] = ("ahsm", "arm", "agm"),
    steps: int = 200_000,
    noise_scale: float = 1.0,
    seed: int = 1,
    burn_in: int = DEFAULT_BURN_IN,
    filter_noise_scale: float | None = None,
    trace: ThrottleTrace | None = None,
) -> ThrottleEvalReport:
    """Simulate `steps` ms at plant noise alpha = noise_scale and score each named filter.

    filter_noise_scale: the alpha the filters assume (default: the plant's, i.e. a matched model).
    trace: reuse an existing simulation (its length overrides steps).
    """
    if steps <= burn_in and trace is None:
        raise ValueError(f"steps ({steps}) must exceed the burn-in ({burn_in})")
    fa = noise_scale if filter_noise_scale is None else filter_noise_scale
    tr = trace if trace is not None else simulate(steps, seed=seed, noise_scale=noise_scale)
    estimators = [make_throttle_estimator(name, fa) for name in filters]  # fail before running
    results = []
    for name, est in zip(filters, estimators):
        th, sd, elapsed = run_estimator(est, tr)
        results.append(error_stats(name, th, sd, tr.theta, burn_in, elapsed, est.resets))
    return ThrottleEvalReport(
        steps=len(tr.y), burn_in=burn_in, noise_scale=noise_scale, seed=seed,
        filter_noise_scale=fa, theta_true_std_deg=float(tr.theta[burn_in:].std()),
        results=tuple(results),
    )
