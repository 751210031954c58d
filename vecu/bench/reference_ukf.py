"""The paper's UKF written generically in numpy (Vargas et al. 2015, Section II-A, Step 3): the
same-run speed baseline of `vecu bench --only ukf` and the oracle the compiled throttle UKF
(vecu.estimators.throttle.ukf_fast) is checked against in tests/estimators/common/test_ukf.py.
Not an estimator: nothing in the ECU or the registry uses it.

Step 2: chi_j = x + S Z_j, S = chol(P), Z a SigmaSet; Step 3: predict the points through f,
update with h on the *propagated* points (no redraw), one set of weights for mean and
covariance. Guards (common.covariance): P symmetrised, factored with a fallback, reset to
(x0, P0) on divergence (`resets`); a non-finite y is missing.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from vecu.estimators.common.covariance import (
    DivergenceBounds,
    cholesky_lower,
    diverged,
    symmetrise,
)
from vecu.estimators.common.sigma_sets import SigmaSet, paper_set
from vecu.estimators.throttle.model import (
    THROTTLE_BOUNDS,
    X0,
    measurement_noise_var,
    process_noise_diag,
)
from vecu.models.throttle import F_DIAG, PAPER_THROTTLE, ThrottleModel, clip_theta, eq3_step

TransitionFn = Callable[[np.ndarray, float], np.ndarray]
MeasurementFn = Callable[[np.ndarray], np.ndarray]


class UnscentedFilter:
    """UKF with additive noise; predict() and update() kept separate (Stone Soup style)."""

    def __init__(
        self,
        f: TransitionFn,
        h: MeasurementFn,
        Q: np.ndarray,
        R: np.ndarray,
        sigma_set: SigmaSet,
        x0: np.ndarray,
        P0: np.ndarray,
        bounds: DivergenceBounds = DivergenceBounds(),
    ) -> None:
        n = sigma_set.n
        if np.shape(x0) != (n,) or np.shape(P0) != (n, n) or np.shape(Q) != (n, n):
            raise ValueError("x0, P0, Q must match the sigma set dimension")
        self.f = f
        self.h = h
        self.Q = np.array(Q, dtype=float)
        self.R = np.atleast_2d(np.array(R, dtype=float))
        self.sigma_set = sigma_set
        self.x0 = np.array(x0, dtype=float)
        self.P0 = np.array(P0, dtype=float)
        self.bounds = bounds
        self.resets = 0
        self.x = self.x0.copy()
        self.P = self.P0.copy()
        self._chi: np.ndarray | None = None  # propagated sigma points of the last predict

    # -- Step 2 -------------------------------------------------------------------------------
    def sigma_points(self, x: np.ndarray, P: np.ndarray) -> np.ndarray:
        """chi = x + S Z (n x (N+1)), S = chol(P) with fallback."""
        return x[:, None] + cholesky_lower(P) @ self.sigma_set.Z

    def _restart(self) -> None:
        self.x = self.x0.copy()
        self.P = self.P0.copy()
        # Prior points (not propagated) so that an update right after a reset is well defined.
        self._chi = self.sigma_points(self.x, self.P)

    def reset(self) -> None:
        """Back to the prior (x0, P0) without counting a divergence."""
        self._restart()
        self._chi = None

    def _diverge_reset(self) -> None:
        self.resets += 1
        self._restart()

    # -- Step 3, first half ---------------------------------------------------------------------
    def predict(self, u: float) -> None:
        """Propagate the points of (x, P) through f with input u; x, P become the prediction."""
        chi = self.sigma_points(self.x, self.P)
        chi = np.column_stack([self.f(chi[:, j], u) for j in range(chi.shape[1])])
        w = self.sigma_set.w
        x = chi @ w
        d = chi - x[:, None]
        P = (d * w) @ d.T + self.Q
        self._chi = chi
        self.x, self.P = x, P
        if diverged(x, P, self.bounds):
            self._diverge_reset()

    # -- Step 3, second half --------------------------------------------------------------------
    def update(self, y: np.ndarray | float) -> bool:
        """Correct with y using gamma = h(chi_{k|k-1}); returns False if y was not used."""
        y = np.atleast_1d(np.asarray(y, dtype=float))
        if not np.all(np.isfinite(y)):
            return False
        chi = self._chi if self._chi is not None else self.sigma_points(self.x, self.P)
        w = self.sigma_set.w
        gamma = np.column_stack([np.atleast_1d(self.h(chi[:, j])) for j in range(chi.shape[1])])
        y_pred = gamma @ w
        dx = chi - self.x[:, None]
        dy = gamma - y_pred[:, None]
        Pxy = (dx * w) @ dy.T
        Pyy = (dy * w) @ dy.T + self.R
        G = np.linalg.solve(Pyy.T, Pxy.T).T  # Pxy Pyy^-1 (Pyy symmetric)
        x = self.x + G @ (y - y_pred)
        P = symmetrise(self.P - G @ Pyy @ G.T)
        self._chi = None
        self.x, self.P = x, P
        if diverged(x, P, self.bounds):
            self._diverge_reset()
            self._chi = None
        return True

    def step(self, u: float, y: np.ndarray | float | None) -> None:
        """One Step-2/3 iteration: predict with u, then update with y (None: predict only)."""
        self.predict(u)
        if y is not None:
            self.update(y)
        self._chi = None


# --- the throttle on it (eqs. 3-4, Section III-C) ----------------------------------------------


def f(x: np.ndarray, u: float, model: ThrottleModel = PAPER_THROTTLE) -> np.ndarray:
    """x_{k+1} = eq3_step(x_k, u_k) with theta clipped to [0, 90] (eq. 3 without w)."""
    b1, b2 = model.mode_bounds_deg
    th, rho, i = eq3_step(model.rows, b1, b2, float(x[0]), float(x[1]), float(x[2]), u)
    return np.array([clip_theta(th), rho, i])


def h(x: np.ndarray) -> np.ndarray:
    """Wattmeter mean, eq. (4): y = i^2."""
    return np.array([x[2] * x[2]])


def process_noise_cov(noise_scale: float = 1.0,
                      f_diag: tuple[float, float, float] = F_DIAG) -> np.ndarray:
    """Q = FF^T, F = alpha diag(sqrt 0.35, 0, sqrt 0.18) (Table I's F by default)."""
    return np.diag(process_noise_diag(noise_scale, f_diag))


class NumpyThrottleUKF:
    """The throttle UKF over UnscentedFilter: x0 = 0, P0 = I, Q = diag((alpha F_ii)^2), R = HH^T."""

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
            np.array(X0), np.eye(len(X0)), THROTTLE_BOUNDS,
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
