"""Unscented RTS smoothers for the steering filters (Khalid et al. eqs. 27-28, the recursion in
steering.rts): `rts_smooth(run)` offline, `FixedLagSmoother` live (docs/models.md, "Steering ›
Smoothers")."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vecu.estimators.steering import rts
from vecu.estimators.steering.base import FilterRun, LaggedEstimate
from vecu.estimators.steering.filters import SteeringUKF, _SteeringFilter
from vecu.estimators.steering.history import COL_G, rows_from_run
from vecu.estimators.steering.model import SteeringModel, side_slip, swa


@dataclass(frozen=True, eq=False)
class SmoothedRun:
    """x_k|T (N, 4) and, if computed, P_k|T (N, 4, 4)."""

    x: np.ndarray
    P: np.ndarray | None


def rts_smooth(run: FilterRun, covariance: bool = True) -> SmoothedRun:
    """Full (offline) unscented RTS smoother over a recorded forward pass: gains and means by
    rts.smooth_run, then P_k|T = P_k|k + G_k (P_k+1|T - P_k+1|k) G_k^T."""
    rows = rows_from_run(run)
    n = rows.shape[0]
    xs = np.empty((n, 4))
    rts.smooth_run(rows, n, xs)
    if not covariance:
        return SmoothedRun(xs, None)
    G = rows[:, COL_G:].reshape(n, 4, 4)
    Ps = np.empty_like(run.P)
    Ps[-1] = run.P[-1]
    for k in range(n - 2, -1, -1):
        Pk = run.P[k] + G[k] @ (Ps[k + 1] - run.P_pred[k + 1]) @ G[k].T
        Ps[k] = 0.5 * (Pk + Pk.T)
    return SmoothedRun(xs, Ps)


class FixedLagSmoother:
    """Live fixed-lag unscented RTS smoother around a steering filter: step(...) returns the
    estimate of `lag` steps ago, the outputs stay the filter's current ones. Means only: `lag`
    4x4 mat-vec products per step."""

    def __init__(self, lag_s: float = 0.25, filt: _SteeringFilter | None = None) -> None:
        f = filt if filt is not None else SteeringUKF()
        dt = f.model.dt_s
        self.lag = round(lag_s / dt)
        if self.lag < 0:
            raise ValueError("lag must be >= 0")
        if f.steps:
            raise ValueError("the filter must be fresh (no steps taken)")
        # the window the backward pass needs, with G_k of the buffered steps but the newest
        f.keep_history(self.lag + 1, smooth_lag=self.lag)
        self.filter = f
        self._dt = dt

    def step(self, v_x: float | None, yaw_rate: float | None, a_y: float | None
             ) -> LaggedEstimate | None:
        """One filter step, then the smoothed estimate of step k - lag (None while k < lag)."""
        f = self.filter
        f.step(v_x, yaw_rate, a_y)
        k = f.steps - 1  # the gain and the backward pass ran in the filter's step (rts.record)
        return None if k < self.lag else self._estimate(k - self.lag, f._lagged)

    def reset(self) -> None:
        """Start afresh, as a new smoother around a fresh filter: the filter back to its prior,
        its step count and the buffered window cleared (its other counters kept)."""
        f = self.filter
        f.reset()
        f.steps = 0
        f.keep_history(self.lag + 1, smooth_lag=self.lag)

    # -- the filter's current estimate and counters (SteeringEstimator) ------------------------
    @property
    def model(self) -> SteeringModel:
        return self.filter.model

    @property
    def steps(self) -> int:
        return self.filter.steps

    @property
    def resets(self) -> int:
        return self.filter.resets

    @property
    def swa_rad(self) -> float:
        return self.filter.swa_rad

    @property
    def swa_std_rad(self) -> float:
        return self.filter.swa_std_rad

    @property
    def side_slip_rad(self) -> float:
        return self.filter.side_slip_rad

    def _estimate(self, step: int, xt: tuple[float, ...]) -> LaggedEstimate:
        x = np.array(xt, dtype=float)
        ring = self.filter._ring
        vx = ring.oldest_vx() if ring is not None and ring.count else self.filter.v_x
        cst = self.filter._cst
        return LaggedEstimate(step=step, t_s=step * self._dt, lag_steps=self.lag, x=x,
                              swa_rad=swa(x, cst), side_slip_rad=side_slip(x, vx))

    def flush(self) -> list[LaggedEstimate]:
        """Smoothed estimates of the steps not yet returned (end of a run), oldest first."""
        f = self.filter
        ring = f._ring
        n_buf = ring.count if ring is not None else 0
        if ring is None or n_buf == 0:
            return []
        first = f.steps - n_buf
        out = np.empty((n_buf, 4))
        rts.smooth_window(ring.hist, ring.newest(), n_buf, out)
        ms = out.tolist()
        vxs = ring.vx()
        skip = 1 if f.steps - 1 >= self.lag else 0  # the oldest one was already returned
        return [LaggedEstimate(step=first + j, t_s=(first + j) * self._dt, lag_steps=self.lag,
                               x=np.array(ms[j]), swa_rad=swa(ms[j], f._cst),
                               side_slip_rad=side_slip(ms[j], vxs[j]))
                for j in range(skip, n_buf)]
