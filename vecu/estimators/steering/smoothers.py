"""Unscented Rauch-Tung-Striebel smoothers for the steering filters (Khalid et al., eqs. 27-28).

The paper's backward recursion (27)-(28) is garbled (it linearises f and mixes filter gains into
the smoothed covariance); we use the standard unscented RTS smoother (Saerkkae 2008), which is
what its text describes ("the smoothed property of the latent variable ... p(x(t) | y_0^T)"):
  G_k   = C_k+1 P_k+1|k^-1,       C_k+1 = sum_j w_j (chi_j - x_k|k)(f(chi_j, v_x) - x_k+1|k)^T
  x_k|T = x_k|k + G_k (x_k+1|T - x_k+1|k)
  P_k|T = P_k|k + G_k (P_k+1|T - P_k+1|k) G_k^T
C_k+1, x_k+1|k and P_k+1|k are the forward pass's own (steering.base.FilterRun), so the
backward pass never re-propagates and always uses the v_x of that step. Fed an EKF run
(C = P F^T) the same code is the extended RTS smoother.

- `rts_smooth(run)`: offline, over a stored filter run.
- `FixedLagSmoother`: live; wraps a filter, and after step k returns the smoothed estimate of
  step k - lag (a `LaggedEstimate`, flagged with its own step index and time: it is *lagged*), or
  None during the first `lag` steps. Its output at step k equals rts_smooth on the run 0..k at
  index k - lag (tested); `flush()` smooths the buffered tail at the end of a run. Under the
  numba backend (around a SteeringUKF) the gain and the backward pass run in the filter's last
  kernel of the step (steering_kernels.push), bit-identical to the Python code here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vecu.estimators.steering.base import FilterRun, LaggedEstimate
from vecu.estimators.steering.filters import SteeringUKF, _SteeringFilter, matrix_from_p10
from vecu.estimators.steering.model import SteeringModel


@dataclass(frozen=True, eq=False)
class SmoothedRun:
    """x_k|T (N, 4) and, if computed, P_k|T (N, 4, 4)."""

    x: np.ndarray
    P: np.ndarray | None


def smoother_gains(run: FilterRun) -> np.ndarray:
    """G_k = C_k+1 P_k+1|k^-1 for k = 0..N-2, shape (N-1, 4, 4) (batched solve, P symmetric)."""
    Pp = run.P_pred[1:]
    Ct = np.transpose(run.C[1:], (0, 2, 1))
    try:
        Gt = np.linalg.solve(Pp, Ct)
    except np.linalg.LinAlgError:
        Gt = np.linalg.pinv(Pp) @ Ct
    return np.transpose(Gt, (0, 2, 1))


def rts_smooth(run: FilterRun, covariance: bool = True) -> SmoothedRun:
    """Full (offline) unscented RTS smoother over a recorded forward pass."""
    n = run.x.shape[0]
    G = smoother_gains(run)
    xs = np.empty_like(run.x)
    xs[-1] = run.x[-1]
    xf, xp = run.x, run.x_pred
    for k in range(n - 2, -1, -1):
        xs[k] = xf[k] + G[k] @ (xs[k + 1] - xp[k + 1])
    if not covariance:
        return SmoothedRun(xs, None)
    Ps = np.empty_like(run.P)
    Ps[-1] = run.P[-1]
    for k in range(n - 2, -1, -1):
        Pk = run.P[k] + G[k] @ (Ps[k + 1] - run.P_pred[k + 1]) @ G[k].T
        Ps[k] = 0.5 * (Pk + Pk.T)
    return SmoothedRun(xs, Ps)


class FixedLagSmoother:
    """Live fixed-lag unscented RTS smoother around a steering filter (module docstring); a
    steering.base.SteeringEstimator.

    step(v_x, yaw_rate, a_y) runs the filter and returns the estimate of `lag` steps ago; the
    filter's current estimate stays available as `.filter` and through the outputs (swa_rad,
    side_slip_rad, ...: the filtered, not the lagged values). Cost: `lag` 4x4 mat-vec products
    per step (means only; the lagged covariance is not computed).
    """

    def __init__(self, lag_s: float = 0.25, filt: _SteeringFilter | None = None) -> None:
        f = filt if filt is not None else SteeringUKF()
        dt = f.model.dt_s
        self.lag = round(lag_s / dt)
        if self.lag < 0:
            raise ValueError("lag must be >= 0")
        if f.steps:
            raise ValueError("the filter must be fresh (no steps taken)")
        # the window the backward pass needs, and G_k (row-major 16-tuples) for the buffered
        # steps but the newest (f._gains)
        f.keep_history(self.lag + 1, smooth_lag=self.lag)
        self.filter = f
        self._dt = dt

    def step(self, v_x: float | None, yaw_rate: float | None, a_y: float | None
             ) -> LaggedEstimate | None:
        """One filter step, then the smoothed estimate of step k - lag (None while k < lag)."""
        f = self.filter
        f.step(v_x, yaw_rate, a_y)
        k = f.steps - 1
        if f._nb:  # numba: gain and backward pass done in the filter's step (kernel)
            return None if k < self.lag else self._estimate(k - self.lag, f._lagged)
        h = f._hist
        if len(h[0]) >= 2:  # gain of the previous step from this step's prediction
            Pp = matrix_from_p10(h[3][-1])
            C = np.asarray(h[4][-1], dtype=float).reshape(4, 4)
            f._gains.append(tuple(np.linalg.solve(Pp, C.T).T.ravel().tolist()))  # type: ignore[union-attr]  # no nb: deques
        if k < self.lag:
            return None
        return self._estimate(k - self.lag, self._backward()[0])

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

    def _backward(self) -> list[tuple[float, float, float, float]]:
        """Smoothed means of the buffered window, oldest first (plain floats: ~2 us a step)."""
        h = self.filter._hist
        xs, xp, G = h[0], h[2], self.filter._gains  # len(G) == len(xs) - 1: G[j] is xs[j]'s
        n = len(xs)
        m0, m1, m2, m3 = xs[-1]
        out = [(m0, m1, m2, m3)]
        for j in range(n - 2, -1, -1):
            p = xp[j + 1]
            e0, e1, e2, e3 = m0 - p[0], m1 - p[1], m2 - p[2], m3 - p[3]
            g = G[j]
            x = xs[j]
            m0 = x[0] + g[0] * e0 + g[1] * e1 + g[2] * e2 + g[3] * e3
            m1 = x[1] + g[4] * e0 + g[5] * e1 + g[6] * e2 + g[7] * e3
            m2 = x[2] + g[8] * e0 + g[9] * e1 + g[10] * e2 + g[11] * e3
            m3 = x[3] + g[12] * e0 + g[13] * e1 + g[14] * e2 + g[15] * e3
            out.append((m0, m1, m2, m3))
        out.reverse()
        return out

    def _estimate(self, step: int, xt: tuple[float, ...]) -> LaggedEstimate:
        x = np.array(xt)
        vx = self.filter._oldest_vx() if self.filter._hist_len() else self.filter.v_x
        i_s = self.filter.k.i_s
        return LaggedEstimate(step=step, t_s=step * self._dt, lag_steps=self.lag, x=x,
                              swa_rad=i_s * float(x[2]),
                              side_slip_rad=math.atan2(float(x[0]), vx))

    def flush(self) -> list[LaggedEstimate]:
        """Smoothed estimates of the steps not yet returned (end of a run), oldest first."""
        f = self.filter
        n_buf = f._hist_len()
        if n_buf == 0:
            return []
        first = f.steps - n_buf
        ms = f._ring.means() if f._nb else self._backward()  # type: ignore[union-attr]  # nb: a ring
        vxs = f._window_vx()
        i_s = f.k.i_s
        skip = 1 if f.steps - 1 >= self.lag else 0  # the oldest one was already returned
        return [LaggedEstimate(step=first + j, t_s=(first + j) * self._dt, lag_steps=self.lag,
                               x=np.array(ms[j]), swa_rad=i_s * float(ms[j][2]),
                               side_slip_rad=math.atan2(float(ms[j][0]), vxs[j]))
                for j in range(skip, n_buf)]

