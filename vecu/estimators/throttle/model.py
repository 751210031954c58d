"""Filter-side throttle model (Vargas et al. 2015, eqs. 3-4) and the numpy UKF built on it.

f(x, u): eq. (3) (vecu.models.throttle.eq3_step), theta clipped to [0, 90] deg as in the plant;
h(x) = i^2 (eq. 4); Q = diag((alpha F_ii)^2), R = 1, x0 = 0, P0 = I (Section III-C). The
calibration is a ThrottleModel (default Table I).
"""

from __future__ import annotations

import numpy as np

from vecu.estimators.common.covariance import DivergenceBounds
from vecu.estimators.common.sigma_sets import SigmaSet, paper_set
from vecu.estimators.common.ukf import UnscentedFilter
from vecu.models.throttle import (
    F_DIAG,
    H_WATTMETER,
    PAPER_THROTTLE,
    ThrottleModel,
    clip_theta,
    eq3_step,
)

N_STATE = 3
X0: tuple[float, float, float] = (0.0, 0.0, 0.0)
# Divergence bounds for the throttle filters: |theta| <= 90 by construction, |i| and |rho| stay
# well below 1e3 in simulation; a trace of 1e6 (1000 deg std) is far beyond any honest estimate.
THROTTLE_BOUNDS = DivergenceBounds(max_trace=1e6, max_abs_state=1e6)


def f(x: np.ndarray, u: float, model: ThrottleModel = PAPER_THROTTLE) -> np.ndarray:
    """x_{k+1} = eq3_step(x_k, u_k) with theta clipped to [0, 90] (eq. 3 without w)."""
    b1, b2 = model.mode_bounds_deg
    th, rho, i = eq3_step(model.rows, b1, b2, float(x[0]), float(x[1]), float(x[2]), u)
    return np.array([clip_theta(th), rho, i])


def h(x: np.ndarray) -> np.ndarray:
    """Wattmeter mean, eq. (4): y = i^2."""
    return np.array([x[2] * x[2]])


def process_noise_diag(noise_scale: float = 1.0,
                       f_diag: tuple[float, float, float] = F_DIAG) -> tuple[float, float, float]:
    """Diagonal of FF^T with F scaled by alpha (plant's noise_scale)."""
    a = float(noise_scale)
    return ((a * f_diag[0]) ** 2, (a * f_diag[1]) ** 2, (a * f_diag[2]) ** 2)


def process_noise_cov(noise_scale: float = 1.0,
                      f_diag: tuple[float, float, float] = F_DIAG) -> np.ndarray:
    """Q = FF^T, F = alpha diag(sqrt 0.35, 0, sqrt 0.18) (Table I's F by default)."""
    return np.diag(process_noise_diag(noise_scale, f_diag))


def measurement_noise_var(h_wattmeter: float = H_WATTMETER) -> float:
    """R = HH^T (1: standard Gaussian wattmeter noise)."""
    return h_wattmeter * h_wattmeter


class NumpyThrottleUKF:
    """ThrottleEstimator over the generic numpy UnscentedFilter (the reference / baseline)."""

    def __init__(self, sigma_set: SigmaSet | str, noise_scale: float = 1.0,
                 model: ThrottleModel = PAPER_THROTTLE) -> None:
        s = paper_set(sigma_set) if isinstance(sigma_set, str) else sigma_set
        self.name = f"{s.name}-numpy"
        self.noise_scale = float(noise_scale)
        self.model = model
        fx = f if model == PAPER_THROTTLE else (lambda x, u: f(x, u, model))
        self.ukf = UnscentedFilter(
            fx, h, process_noise_cov(noise_scale, model.f_diag),
            np.array([[measurement_noise_var(model.h_wattmeter)]]), s,
            np.array(X0), np.eye(N_STATE), THROTTLE_BOUNDS,
        )

    @property
    def resets(self) -> int:
        return self.ukf.resets

    def step(self, u_prev: float, y: float | None) -> None:
        self.ukf.step(u_prev, y)

    @property
    def theta_deg(self) -> float:
        return float(self.ukf.x[0])

    @property
    def theta_std_deg(self) -> float:
        return float(np.sqrt(max(self.ukf.P[0, 0], 0.0)))

    @property
    def state(self) -> tuple[float, float, float]:
        x = self.ukf.x
        return float(x[0]), float(x[1]), float(x[2])

    @property
    def covariance(self) -> np.ndarray:
        return self.ukf.P.copy()

    def set_state(self, x: tuple[float, float, float], P: np.ndarray) -> None:
        """Overwrite the estimate (tests, warm starts)."""
        self.ukf.x = np.array(x, dtype=float)
        self.ukf.P = np.array(P, dtype=float)

    def reset(self) -> None:
        self.ukf.reset()
