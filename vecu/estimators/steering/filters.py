"""Steering-wheel angle / side-slip filters (Khalid et al.) on steering.model: UKF and EKF.

One 100 Hz step: time update with the measured v_x (eqs. 17-18 / 26), the linear gyro update,
then the a_y update (eqs. 19-25: unscented in the UKF, linearised in the EKF). The kernels are in
steering.model, .unscented and .rts; the classes check inputs, gate, count, project and reset
(docs/models.md, "Steering › Filters — decisions"). record=True feeds a steering.history.Ring
for steering.smoothers.
"""

from __future__ import annotations

import math

import numpy as np

from vecu.estimators.common.covariance import diverged_floats, symmetrise
from vecu.estimators.common.sigma_sets import SigmaSet, ahsm
from vecu.estimators.common.small_linalg import chol4_or_fallback
from vecu.estimators.steering import model as sm
from vecu.estimators.steering import rts
from vecu.estimators.steering import unscented as uk
from vecu.estimators.steering.base import FilterRun
from vecu.estimators.steering.history import (
    COL_C,
    COL_PP,
    COL_VX,
    COL_XP,
    IDX16,
    N_COLS,
    TRIU,
    Ring,
)
from vecu.estimators.steering.model import SteeringModel
from vecu.kernels import constants

P10 = tuple[float, float, float, float, float, float, float, float, float, float]
V_X_DEFAULT = 20.0  # used for v_x until the first good reading


def default_sigma_set() -> SigmaSet:
    """AHSM generalised to n = 4 with lambda = 0 (the cubature rule), module docstring."""
    return ahsm(sm.N_STATE, lam=0.0)


def p10_from_matrix(P: np.ndarray) -> P10:
    """The 10-entry upper triangle p00 p01 p02 p03 p11 p12 p13 p22 p23 p33 of P."""
    return tuple(P[TRIU].tolist())  # type: ignore[return-value]  # 10 entries


def matrix_from_p10(p: P10 | list[float]) -> np.ndarray:
    return np.asarray(p, dtype=np.float64)[IDX16].reshape(4, 4)


class _SteeringFilter:
    """Shared input handling, counters, outputs, divergence reset and recording: a
    steering.base.SteeringEstimator. Subclasses supply the predict and the a_y update."""

    def __init__(self, model: SteeringModel, record: bool, history_maxlen: int | None) -> None:
        self.model = model
        self._cst = sm.constants(model)
        self._kcst = constants(self._cst)  # as the kernels take it (vecu.kernels.constants)
        self._gate2 = model.gate_sigma ** 2
        self._x0 = tuple(float(v) for v in model.x0())
        self._p0 = p10_from_matrix(model.P0())
        self._reset_row = np.array([*self._x0, *self._p0, *([0.0] * 16)])
        self.record = record
        self._ring: Ring | None = Ring(history_maxlen) if record else None
        if record:
            rts.prepare()
        self._scratch = np.zeros((1, N_COLS))  # the kernels' history row when not recording
        self._smooth_lag: int | None = None  # set by a FixedLagSmoother (keep_history)
        self._lagged = (0.0, 0.0, 0.0, 0.0)  # with a smoother: its output of the last step
        self.steps = self.resets = 0
        self.missing_r = self.missing_ay = self.missing_vx = 0
        self.rejected_r = self.rejected_ay = self.rejected_vx = 0
        self.gated_r = self.gated_ay = 0
        self.clipped = 0  # state projections onto the physical limits
        self._gch_r = [0, 0, 0]
        self._gch_ay = [0, 0, 0]
        self.v_x = V_X_DEFAULT
        self.reset()

    def reset(self) -> None:
        """Back to the prior (not counted as a divergence)."""
        self._x: tuple[float, ...] = self._x0
        self._p: P10 = self._p0

    # -- outputs --------------------------------------------------------------------------------
    @property
    def x(self) -> np.ndarray:
        return np.array(self._x)

    @property
    def P(self) -> np.ndarray:
        return matrix_from_p10(self._p)

    @property
    def swa_rad(self) -> float:
        """Steering-wheel angle estimate i_s * delta."""
        return sm.swa(self._x, self._cst)

    def reported_cov(self) -> np.ndarray:
        """P as reported (SteeringModel.report_var_scale, stiffness_rel_sigma): the stiffness
        error considered on (v_y, delta), then scaled."""
        m = self.model
        g = np.zeros(4)
        g[2], g[0] = sm.stiffness_sensitivity(self._x[1], self.v_x, m.params)
        return m.report_var_scale * (self.P + m.stiffness_rel_sigma ** 2 * np.outer(g, g))

    @property
    def swa_std_rad(self) -> float:
        """Reported std of the steering-wheel angle (reported_cov)."""
        m = self.model
        gd = sm.stiffness_sensitivity(self._x[1], self.v_x, m.params)[0]
        var = m.report_var_scale * (max(self._p[7], 0.0) + (m.stiffness_rel_sigma * gd) ** 2)
        return self._cst[sm.IS] * math.sqrt(var)

    @property
    def side_slip_std_rad(self) -> float:
        """Reported std of the side slip, sigma_vy / v_x (reported_cov)."""
        m = self.model
        gv = sm.stiffness_sensitivity(self._x[1], self.v_x, m.params)[1]
        var = m.report_var_scale * (max(self._p[0], 0.0) + (m.stiffness_rel_sigma * gv) ** 2)
        return math.sqrt(var) / max(self.v_x, sm.V_X_MIN)

    @property
    def side_slip_rad(self) -> float:
        return sm.side_slip(self._x, self.v_x)

    @property
    def swa_prior_std_rad(self) -> float:
        """The prior's steering-wheel-angle standard deviation (i_s times p0_std of delta): what
        is known of the angle where yaw rate and a_y say nothing of it (at standstill)."""
        return self._cst[sm.IS] * self.model.p0_std[2]

    @property
    def rejected(self) -> int:
        return self.rejected_r + self.rejected_ay + self.rejected_vx

    def keep_history(self, maxlen: int | None, smooth_lag: int | None = None) -> None:
        """Start recording afresh, keeping the last `maxlen` steps (None: all); smooth_lag: a
        fixed-lag smoother's lag (maxlen = smooth_lag + 1): each step then also records the
        previous step's gain and runs the backward pass (rts.record)."""
        self.record = True
        self._ring = Ring(maxlen)
        self._smooth_lag = smooth_lag
        rts.prepare()

    def history(self) -> FilterRun:
        """The recorded forward pass (record=True; the last history_maxlen steps if bounded)."""
        if self._ring is None:
            raise RuntimeError("filter was built with record=False")
        if not self._ring.count:
            raise RuntimeError("no steps recorded")
        return FilterRun(*self._ring.arrays())

    # -- input checks ---------------------------------------------------------------------------
    def _speed(self, v_x: float | None) -> float:
        if v_x is None:
            self.missing_vx += 1
        elif not -self.model.max_v_x <= v_x <= self.model.max_v_x:  # NaN fails too
            self.rejected_vx += 1
        else:
            self.v_x = max(abs(v_x), sm.V_X_MIN)  # the car does not reverse at speed
        return self.v_x

    def _gate(self, ch: list[int], e: float, s: float) -> bool:
        """Innovation gate on channel state ch = [accepted, gated run, re-acquire left].

        Not armed for the first gate_after_updates accepted readings (the prior knows nothing);
        after max_gated_in_row gated readings in a row the next as many are accepted ungated
        (the estimate, not the sensor, is then the likelier culprit)."""
        m = self.model
        if ch[2] > 0:
            ch[2] -= 1
        elif ch[0] >= m.gate_after_updates and e * e > self._gate2 * s:
            ch[1] += 1
            if ch[1] >= m.max_gated_in_row:
                ch[1] = 0
                ch[2] = m.max_gated_in_row
            return False
        else:
            ch[1] = 0
        ch[0] += 1
        return True

    def _gate_r(self, e: float, s: float) -> bool:
        if self._gate(self._gch_r, e, s):
            return True
        self.gated_r += 1
        return False

    def _gate_ay(self, e: float, s: float) -> bool:
        if self._gate(self._gch_ay, e, s):
            return True
        self.gated_ay += 1
        return False

    def _project(self, x: tuple[float, ...], vx: float) -> tuple[float, ...]:
        """Clip v_y, r and delta to the model's physical limits (counted in `clipped`)."""
        m = self.model
        vy, r, d, dd = x
        lim = m.max_slip_ratio * vx
        if -lim <= vy <= lim and -m.max_abs_r <= r <= m.max_abs_r \
                and -m.max_abs_delta <= d <= m.max_abs_delta:
            return x
        self.clipped += 1
        return (min(max(vy, -lim), lim), min(max(r, -m.max_abs_r), m.max_abs_r),
                min(max(d, -m.max_abs_delta), m.max_abs_delta), dd)

    # -- one step -------------------------------------------------------------------------------
    def _predict(self, vx: float, hist: np.ndarray, slot: int
                 ) -> tuple[tuple[float, ...], P10]:
        """x_pred, P_pred; when recording also written with C into hist[slot]."""
        raise NotImplementedError

    def _update_ay(self, x: tuple[float, ...], p: P10, y: float, vx: float
                   ) -> tuple[tuple[float, ...], P10]:
        raise NotImplementedError

    def _update_r(self, x: tuple[float, ...], p: P10, y: float) -> tuple[tuple[float, ...], P10]:
        """Linear update with H = [0, 1, 0, 0] (exact): P_xy = P[:, 1], s = P_11 + sigma_r^2."""
        s = p[4] + self._cst[sm.R_R]
        e = y - x[1]
        if not self._gate_r(e, s):
            return x, p
        return uk.scalar_update(x, p, e, s, p[1], p[4], p[5], p[6])

    def step(self, v_x: float | None, yaw_rate: float | None, a_y: float | None) -> None:
        """Predict 10 ms with v_x, then update with the gyro and the accelerometer readings."""
        self.steps += 1
        m = self.model
        vx = float(self._speed(v_x))
        ring = self._ring
        if ring is not None:
            slot = ring.slot()  # first: it may grow the ring
            hist = ring.hist
        else:
            slot, hist = 0, self._scratch
        x, p = self._predict(vx, hist, slot)
        if yaw_rate is None:
            self.missing_r += 1
        elif not -m.max_abs_r <= yaw_rate <= m.max_abs_r:
            self.rejected_r += 1
        else:
            x, p = self._update_r(x, p, yaw_rate)
        if a_y is None:
            self.missing_ay += 1
        elif not -m.max_abs_ay <= a_y <= m.max_abs_ay:
            self.rejected_ay += 1
        else:
            x, p = self._update_ay(x, p, a_y, vx)
        if (diverged_floats(x, p[0] + p[4] + p[7] + p[9], sum(p) - p[0] - p[4] - p[7] - p[9],
                            m.bounds)
                or p[0] <= 0.0 or p[4] <= 0.0 or p[7] <= 0.0 or p[9] <= 0.0):
            self.resets += 1
            x, p = self._x0, self._p0
            if ring is not None:  # the prediction recorded is the prior's, C = 0
                hist[slot, COL_XP:COL_VX] = self._reset_row
        else:
            x = self._project(x, vx)
        self._x, self._p = x, p
        if ring is not None:
            self._lagged = self._record(ring, slot, x, p, vx)

    def _record(self, ring: Ring, slot: int, x: tuple[float, ...], p: P10, vx: float
                ) -> tuple[float, float, float, float]:
        """Close row `slot` (rts.record) and advance the ring; with a fixed-lag smoother also
        the previous row's gain and, once steps > lag, the smoothed mean of step k - lag."""
        prev, n_back = -1, 0
        cap = ring.hist.shape[0]
        lag = self._smooth_lag
        if lag is not None:
            if ring.count and cap > 1:
                prev = ring.newest()
            if self.steps - 1 >= lag:
                n_back = min(ring.count + 1, cap)
        out = rts.record(ring.hist, slot, prev, x, p, vx, n_back, rts.NO_OUT)
        ring.advance()
        return out


class SteeringUKF(_SteeringFilter):
    """Unscented filter (module docstring); its equations: steering.unscented. ~20-50 us per
    step as plain Python, a third of that compiled (bit-identical results)."""

    def __init__(self, model: SteeringModel = SteeringModel(), sigma_set: SigmaSet | None = None,
                 record: bool = False, history_maxlen: int | None = None) -> None:
        s = sigma_set if sigma_set is not None else default_sigma_set()
        if s.n != sm.N_STATE:
            raise ValueError(f"sigma set must have n = {sm.N_STATE}")
        self.sigma_set = s
        super().__init__(model, record, history_maxlen)
        self._pts = constants(uk.pattern(s))
        uk.prepare()

    def _predict(self, vx: float, hist: np.ndarray, slot: int
                 ) -> tuple[tuple[float, ...], P10]:
        cst, pts = self._kcst, self._pts
        rec = self._ring is not None
        ok, x, p = uk.predict(self._x, self._p, vx, cst, pts, hist, slot, rec)
        if not ok:  # not PD for the unrolled Cholesky: the fallback factor
            ok, x, p = uk.predict_with_factor(chol4_or_fallback(self._p), self._x, vx, cst, pts,
                                              hist, slot, rec)
        return x, p

    def _update_ay(self, x: tuple[float, ...], p: P10, y: float, vx: float
                   ) -> tuple[tuple[float, ...], P10]:
        """Unscented scalar update with points redrawn from (x, P)."""
        cst, pts = self._kcst, self._pts
        ok, ym, s, c0, c1, c2, c3 = uk.ay_moments(x, p, vx, cst, pts)
        if not ok:
            ok, ym, s, c0, c1, c2, c3 = uk.ay_moments_with_factor(chol4_or_fallback(p), x, vx,
                                                                  cst, pts)
        e = y - ym
        if not self._gate_ay(e, s):
            return x, p
        return uk.scalar_update(x, p, e, s, c0, c1, c2, c3)


class SteeringEKF(_SteeringFilter):
    """Extended Kalman filter on the same model (exact Jacobians of the Heun step and of h)."""

    def __init__(self, model: SteeringModel = SteeringModel(), record: bool = False,
                 history_maxlen: int | None = None) -> None:
        self._Q = sm.process_noise(model)
        super().__init__(model, record, history_maxlen)

    def _predict(self, vx: float, hist: np.ndarray, slot: int
                 ) -> tuple[tuple[float, ...], P10]:
        x, k = self._x, self._cst
        F = sm.jacobian_f(x, vx, k)  # type: ignore[arg-type]  # the state is a 4-tuple
        P = matrix_from_p10(self._p)
        PFt = P @ F.T
        pp = p10_from_matrix(symmetrise(F @ PFt + self._Q))
        xp = sm.transition(x[0], x[1], x[2], x[3], vx, k)
        if self._ring is not None:  # C = P F^T: the extended RTS smoother's
            hist[slot, COL_XP:COL_PP] = xp
            hist[slot, COL_PP:COL_C] = pp
            hist[slot, COL_C:COL_VX] = PFt.ravel()
        return xp, pp

    def _update_ay(self, x: tuple[float, ...], p: P10, y: float, vx: float
                   ) -> tuple[tuple[float, ...], P10]:
        k = self._cst
        Hr = sm.jacobian_h(x, vx, k)[1]  # type: ignore[arg-type]  # the state is a 4-tuple
        c = matrix_from_p10(p) @ Hr  # P H^T
        s = float(Hr @ c) + k[sm.R_AY]
        e = y - sm.accelerations(x[0], x[1], x[2], vx, k)[0]
        if not self._gate_ay(e, s):
            return x, p
        return uk.scalar_update(x, p, e, s, float(c[0]), float(c[1]), float(c[2]), float(c[3]))
