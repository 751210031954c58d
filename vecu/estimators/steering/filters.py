"""Steering-wheel angle / side-slip filters on vecu.estimators.steering.model: UKF and EKF.

Both run the same step at 100 Hz: predict with the measured v_x (the paper's Step "time
update", eqs. 17-18 / 26), then a linear Kalman update with the gyro r (H = [0, 1, 0, 0]: exact, no
sigma points needed), then the a_y update (eqs. 19-25: unscented in the UKF, linearised in the
EKF). Processing the two independent readings one after the other is exact for the linear one
and lets either be missing on its own.

UKF (`SteeringUKF`): plain floats, n = 4, P kept as its 10 distinct entries, unrolled Cholesky
(common.small_linalg.chol4; fallback: covariance.cholesky_lower). Sigma set: any
vecu.estimators.common.sigma_sets.SigmaSet with n = 4; default `ahsm(4, lam=0)`, the symmetric
AHSM set generalised to n with lambda = 0, i.e. the third-degree spherical-radial cubature rule:
2n points x +- sqrt(n) S e_i, weights 1/(2n), all positive (so P stays PSD) and the zero-weight
centre point skipped (docs/models.md: why not the paper-throttle lam = 12 or a
negative-centre-weight scaled set). Unlike vecu.estimators.common.ukf
(Vargas Step 3), the points are redrawn from (x_pred, P_pred) for the update: here Q (the steering
random walk) reaches a_y within one step and must be in Pxy.

Inputs of `step(v_x, yaw_rate, a_y)`: None = missing (predict only / that update skipped,
counted); non-finite or outside the plausible range = rejected (counted); innovations beyond
gate_sigma are gated (counted; armed after gate_after_updates accepted readings; after
max_gated_in_row in a row as many are accepted ungated); v_x: a bad reading keeps the
last good one, below V_X_MIN it is clipped. Divergence (covariance.diverged_floats or a
non-positive variance) resets to the prior and counts. Nothing the inputs contain makes the
outputs NaN.

With record=True each step appends (x_k|k, P_k|k, x_k|k-1, P_k|k-1, C_k = cov(x_k-1|k-1, x_k|k-1))
to deques bounded by history_maxlen (None: unbounded) for the smoothers (steering_smoothers.py):
the backward pass then reuses the forward pass's own v_x and sigma points (nothing is
re-propagated, so the time-varying input cannot be mismatched).

Backends (vecu.kernels, VECU_KERNELS): under "numba" the UKF's predict and a_y moments (and the
recording, with a smoother its gain and backward pass) run in vecu.estimators.steering.kernels,
3 compiled calls per step, bit-identical to the plain-float code here (the reference, used
under "python"); the history then lives in a numpy ring (converted if the backend changes).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from vecu.estimators.common.covariance import diverged_floats, symmetrise
from vecu.estimators.common.sigma_sets import SigmaSet, ahsm
from vecu.estimators.common.small_linalg import chol4_or_fallback
from vecu.estimators.steering import kernels as sk
from vecu.estimators.steering import model as sm
from vecu.estimators.steering.base import FilterRun
from vecu.estimators.steering.model import SteeringModel
from vecu.kernels import backend

P10 = tuple[float, float, float, float, float, float, float, float, float, float]
# index of (i, j) in the 10-entry upper triangle p00 p01 p02 p03 p11 p12 p13 p22 p23 p33
_IDX = ((0, 1, 2, 3), (1, 4, 5, 6), (2, 5, 7, 8), (3, 6, 8, 9))
V_X_DEFAULT = 20.0  # used for v_x until the first good reading


def default_sigma_set() -> SigmaSet:
    """AHSM generalised to n = 4 with lambda = 0 (the cubature rule), module docstring."""
    return ahsm(sm.N_STATE, lam=0.0)


def p10_from_matrix(P: np.ndarray) -> P10:
    return tuple(float(P[i, j]) for i in range(4) for j in range(i, 4))  # type: ignore[return-value]  # 10 entries (upper triangle of 4x4)


def matrix_from_p10(p: P10 | list[float]) -> np.ndarray:
    P = np.empty((4, 4))
    for i in range(4):
        for j in range(4):
            P[i, j] = p[_IDX[i][j]]
    return P


class _SteeringFilter:
    """Shared input handling, counters, outputs, divergence reset and recording: a
    steering.base.SteeringEstimator.

    Subclasses with compiled kernels (`_kernels_ok`) run their numeric core in
    vecu.estimators.steering.kernels under the numba backend and then record into a
    steering_kernels.Ring instead of the deques; the storage follows the backend at every step
    (converted when it changes), so `history()` and the smoothers see the same run either way.
    """

    _kernels_ok = False

    def __init__(self, model: SteeringModel, record: bool, history_maxlen: int | None) -> None:
        self.model = model
        self.k = sm.consts(model)
        self._q = p10_from_matrix(sm.process_noise(model))
        self._r_r = model.sigma_r ** 2
        self._r_ay = model.sigma_ay ** 2
        self._gate2 = model.gate_sigma ** 2
        self._x0 = tuple(float(v) for v in model.x0())
        self._p0 = p10_from_matrix(model.P0())
        self.record = record
        self._hist: tuple[deque, ...] = tuple(deque(maxlen=history_maxlen) for _ in range(6))
        self._maxlen = history_maxlen
        self._smooth_lag: int | None = None  # set by a FixedLagSmoother (keep_history)
        self._gains: deque | None = None  # its G_k (Python storage; in the ring under numba)
        self._nb = False  # ring storage and kernels in use
        self._ring: sk.Ring | None = None
        self._lagged = (0.0, 0.0, 0.0, 0.0)  # numba: the smoother's output of the last step
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
        self._set(self._x0, self._p0)

    # -- state access (subclasses store x and P as they like) -----------------------------------
    def _set(self, x: tuple[float, ...], p: P10) -> None:
        self._x = x
        self._p = p

    def _get(self) -> tuple[tuple[float, ...], P10]:
        return self._x, self._p

    # -- outputs --------------------------------------------------------------------------------
    @property
    def x(self) -> np.ndarray:
        return np.array(self._get()[0])

    @property
    def P(self) -> np.ndarray:
        return matrix_from_p10(self._get()[1])

    @property
    def swa_rad(self) -> float:
        """Steering-wheel angle estimate i_s * delta."""
        return self.k.i_s * self._get()[0][2]

    @property
    def swa_std_rad(self) -> float:
        return self.k.i_s * math.sqrt(max(self._get()[1][7], 0.0))

    @property
    def side_slip_rad(self) -> float:
        return math.atan2(self._get()[0][0], self.v_x)

    @property
    def rejected(self) -> int:
        return self.rejected_r + self.rejected_ay + self.rejected_vx

    def keep_history(self, maxlen: int | None, smooth_lag: int | None = None) -> None:
        """Start recording afresh, keeping the last `maxlen` steps (None: all); smooth_lag: also
        keep the fixed-lag smoother's gains (maxlen = smooth_lag + 1)."""
        self.record = True
        self._hist = tuple(deque(maxlen=maxlen) for _ in range(6))
        self._maxlen = maxlen
        self._smooth_lag = smooth_lag
        self._gains = None if smooth_lag is None else deque(maxlen=smooth_lag)
        self._ring = None
        self._nb = False

    def history(self) -> FilterRun:
        """The recorded forward pass (record=True; the last history_maxlen steps if bounded)."""
        if not self.record:
            raise RuntimeError("filter was built with record=False")
        if self._nb:
            if not self._ring.count:  # type: ignore[union-attr]  # nb: a ring
                raise RuntimeError("no steps recorded")
            return FilterRun(*self._ring.arrays())  # type: ignore[union-attr]  # nb: a ring
        xs, ps, xp, pp, cs, vs = self._hist
        if not xs:
            raise RuntimeError("no steps recorded")
        return FilterRun(x=np.array(xs), P=np.array([matrix_from_p10(p) for p in ps]),
                         x_pred=np.array(xp), P_pred=np.array([matrix_from_p10(p) for p in pp]),
                         C=np.array(cs).reshape(-1, 4, 4), v_x=np.array(vs))

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
    def _predict(self, vx: float) -> tuple[tuple[float, ...], P10, list[float] | None]:
        raise NotImplementedError

    def _update_ay(self, x: tuple[float, ...], p: P10, y: float, vx: float
                   ) -> tuple[tuple[float, ...], P10]:
        raise NotImplementedError

    def _update_r(self, x: tuple[float, ...], p: P10, y: float) -> tuple[tuple[float, ...], P10]:
        """Linear update with H = [0, 1, 0, 0] (exact)."""
        p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = p
        s = p11 + self._r_r
        e = y - x[1]
        if not self._gate_r(e, s):
            return x, p
        k0, k1, k2, k3 = p01 / s, p11 / s, p12 / s, p13 / s
        x = (x[0] + k0 * e, x[1] + k1 * e, x[2] + k2 * e, x[3] + k3 * e)
        # P - K s K^T with K s = P[:, 1]
        p = (p00 - k0 * p01, p01 - k0 * p11, p02 - k0 * p12, p03 - k0 * p13,
             p11 - k1 * p11, p12 - k1 * p12, p13 - k1 * p13,
             p22 - k2 * p12, p23 - k2 * p13, p33 - k3 * p13)
        return x, p

    def step(self, v_x: float | None, yaw_rate: float | None, a_y: float | None) -> None:
        """Predict 10 ms with v_x, then update with the gyro and the accelerometer readings."""
        nb = self._kernels_ok and backend() == "numba"
        if nb is not self._nb:
            self._use_ring(nb)
        self.steps += 1
        m = self.model
        vx = self._speed(v_x)
        if nb:
            vx = float(vx)
            slot = self._ring.slot() if self.record else 0  # type: ignore[union-attr]  # nb: a ring
            x, p, cross = self._predict_compiled(vx, slot)
        else:
            x, p, cross = self._predict(vx)
        xp, pp = x, p
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
        elif nb:
            x, p = self._update_ay_compiled(x, p, a_y, vx)
        else:
            x, p = self._update_ay(x, p, a_y, vx)
        if (diverged_floats(x, p[0] + p[4] + p[7] + p[9], sum(p) - p[0] - p[4] - p[7] - p[9],
                            m.bounds)
                or p[0] <= 0.0 or p[4] <= 0.0 or p[7] <= 0.0 or p[9] <= 0.0):
            self.resets += 1
            x, p = self._x0, self._p0
            xp, pp, cross = x, p, [0.0] * 16
            if nb and self.record:
                self._ring.hist[slot, sk.COL_XP:sk.COL_VX] = self._reset_row  # type: ignore[attr-defined, union-attr]  # nb: a ring
        else:
            x = self._project(x, vx)
        self._set(x, p)
        if nb:
            if self.record:
                self._push(slot, x, p, vx)
        elif self.record:
            h = self._hist
            h[0].append(x)
            h[1].append(p)
            h[2].append(xp)
            h[3].append(pp)
            h[4].append(cross)
            h[5].append(vx)

    # -- numba backend: ring storage (the kernel calls: SteeringUKF._*_compiled) ---------------
    def _use_ring(self, nb: bool) -> None:
        """Move the recorded history between the deques and the ring (backend changed)."""
        if nb:
            sk.prepare_numba()
            if self.record:
                self._ring = sk.Ring(self._maxlen, sk.rows_from_deques(self._hist, self._gains))
                self._hist = tuple(deque(maxlen=self._maxlen) for _ in range(6))
        elif self._ring is not None:
            self._hist, self._gains = sk.deques_from_rows(self._ring.ordered(), self._maxlen,
                                                          self._smooth_lag)
            self._ring = None
        self._nb = nb

    def _push(self, slot: int, x: tuple[float, ...], p: P10, vx: float) -> None:
        self._lagged = self._ring.record(slot, x, p, vx, self._smooth_lag,  # type: ignore[union-attr]  # nb: a ring
                                         self.steps - 1)

    def _hist_len(self) -> int:
        return self._ring.count if self._nb else len(self._hist[0])  # type: ignore[union-attr]  # nb: a ring

    def _window_vx(self) -> list[float]:
        """v_x of the recorded steps, oldest first."""
        return self._ring.vx() if self._nb else list(self._hist[5])  # type: ignore[union-attr]  # nb: a ring

    def _oldest_vx(self) -> float:
        return self._ring.oldest_vx() if self._nb else float(self._hist[5][0])  # type: ignore[union-attr]  # nb: a ring



class SteeringUKF(_SteeringFilter):
    """Unscented filter, plain floats (module docstring). ~20-30 us per step; under the numba
    backend its numeric core runs in steering_kernels (bit-identical results)."""

    _kernels_ok = True

    def __init__(self, model: SteeringModel = SteeringModel(), sigma_set: SigmaSet | None = None,
                 record: bool = False, history_maxlen: int | None = None) -> None:
        s = sigma_set if sigma_set is not None else default_sigma_set()
        if s.n != sm.N_STATE:
            raise ValueError(f"sigma set must have n = {sm.N_STATE}")
        self.sigma_set = s
        # Pattern columns and weights, zero-weight columns dropped (cubature centre point).
        cols = [(tuple(float(v) for v in s.Z[:, j]), float(s.w[j])) for j in range(s.points)]
        self._pts = tuple((z, w) for z, w in cols if w != 0.0)
        super().__init__(model, record, history_maxlen)
        self._cst = sk.constants(self.k, self._q, self._r_ay)
        self._ptab = sk.point_table(self._pts)
        self._scratch = np.zeros((1, sk.N_COLS))  # the kernels' history row when not recording
        self._reset_row = np.array([*self._x0, *self._p0, *([0.0] * 16)])

    def _sigma(self, x: tuple[float, ...], p: P10) -> list[tuple[tuple[float, ...], float,
                                                                  tuple[float, ...]]]:
        """[(chi_j, w_j, S z_j)] with S = chol(P)."""
        l00, l10, l11, l20, l21, l22, l30, l31, l32, l33 = chol4_or_fallback(p)
        x0, x1, x2, x3 = x
        out = []
        for (z0, z1, z2, z3), w in self._pts:
            d0 = l00 * z0
            d1 = l10 * z0 + l11 * z1
            d2 = l20 * z0 + l21 * z1 + l22 * z2
            d3 = l30 * z0 + l31 * z1 + l32 * z2 + l33 * z3
            out.append(((x0 + d0, x1 + d1, x2 + d2, x3 + d3), w, (d0, d1, d2, d3)))
        return out

    def _predict(self, vx: float) -> tuple[tuple[float, ...], P10, list[float] | None]:
        k = self.k
        f = sm.f
        pts = self._sigma(self._x, self._p)
        props = [f(c, vx, k) for c, _, _ in pts]
        m0 = m1 = m2 = m3 = 0.0
        for (c0, c1, c2, c3), (_, w, _) in zip(props, pts):
            m0 += w * c0
            m1 += w * c1
            m2 += w * c2
            m3 += w * c3
        q = self._q
        p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = q
        rec = self.record
        cr = [0.0] * 16
        for (c0, c1, c2, c3), (_, w, dz) in zip(props, pts):
            e0, e1, e2, e3 = c0 - m0, c1 - m1, c2 - m2, c3 - m3
            a0, a1, a2, a3 = w * e0, w * e1, w * e2, w * e3
            p00 += a0 * e0
            p01 += a0 * e1
            p02 += a0 * e2
            p03 += a0 * e3
            p11 += a1 * e1
            p12 += a1 * e2
            p13 += a1 * e3
            p22 += a2 * e2
            p23 += a2 * e3
            p33 += a3 * e3
            if rec:  # C = sum w (chi - x)(chi' - x_pred)^T
                for i in range(4):
                    di = dz[i]
                    cr[4 * i] += di * a0
                    cr[4 * i + 1] += di * a1
                    cr[4 * i + 2] += di * a2
                    cr[4 * i + 3] += di * a3
        return ((m0, m1, m2, m3), (p00, p01, p02, p03, p11, p12, p13, p22, p23, p33),
                cr if rec else None)

    def _update_ay(self, x: tuple[float, ...], p: P10, y: float, vx: float
                   ) -> tuple[tuple[float, ...], P10]:
        """Unscented scalar update with points redrawn from (x, P)."""
        k = self.k
        hay = sm.h_ay
        pts = self._sigma(x, p)
        gam = [hay(c, vx, k) for c, _, _ in pts]
        ym = 0.0
        for g, (_, w, _) in zip(gam, pts):
            ym += w * g
        s = self._r_ay
        c0 = c1 = c2 = c3 = 0.0
        for g, (_, w, dz) in zip(gam, pts):
            a = w * (g - ym)
            s += a * (g - ym)
            c0 += a * dz[0]
            c1 += a * dz[1]
            c2 += a * dz[2]
            c3 += a * dz[3]
        return self._apply_ay(x, p, y, ym, s, c0, c1, c2, c3)

    def _apply_ay(self, x: tuple[float, ...], p: P10, y: float, ym: float, s: float, c0: float,
                  c1: float, c2: float, c3: float) -> tuple[tuple[float, ...], P10]:
        """Gate and apply the a_y update from its moments (predicted y, variance, P h^T)."""
        e = y - ym
        if not self._gate_ay(e, s):
            return x, p
        k0, k1, k2, k3 = c0 / s, c1 / s, c2 / s, c3 / s
        x = (x[0] + k0 * e, x[1] + k1 * e, x[2] + k2 * e, x[3] + k3 * e)
        p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = p
        p = (p00 - k0 * c0, p01 - k0 * c1, p02 - k0 * c2, p03 - k0 * c3,
             p11 - k1 * c1, p12 - k1 * c2, p13 - k1 * c3,
             p22 - k2 * c2, p23 - k2 * c3, p33 - k3 * c3)
        return x, p

    def _predict_compiled(self, vx: float, slot: int) -> tuple[tuple[float, ...], P10, None]:
        rec = self.record
        hist = self._ring.hist if rec else self._scratch  # type: ignore[union-attr]  # rec: a ring
        ok, x, p = sk.predict.compiled(self._x, self._p, vx, self._cst, self._ptab, hist, slot,
                                       rec)
        if not ok:  # not PD for the unrolled Cholesky: the fallback factor from Python
            ok, x, p = sk.predict_chol.compiled(chol4_or_fallback(self._p), self._x, vx,
                                                self._cst, self._ptab, hist, slot, rec)
        return x, p, None

    def _update_ay_compiled(self, x: tuple[float, ...], p: P10, y: float, vx: float
                            ) -> tuple[tuple[float, ...], P10]:
        ok, ym, s, c0, c1, c2, c3 = sk.ay_moments.compiled(x, p, vx, self._cst, self._ptab)
        if not ok:
            ok, ym, s, c0, c1, c2, c3 = sk.ay_moments_chol.compiled(
                chol4_or_fallback(p), x, vx, self._cst, self._ptab)
        return self._apply_ay(x, p, y, ym, s, c0, c1, c2, c3)


class SteeringEKF(_SteeringFilter):
    """Extended Kalman filter on the same model (exact Jacobians of the Heun step and of h)."""

    def __init__(self, model: SteeringModel = SteeringModel(), record: bool = False,
                 history_maxlen: int | None = None) -> None:
        self._Q = sm.process_noise(model)
        super().__init__(model, record, history_maxlen)

    def _predict(self, vx: float) -> tuple[tuple[float, ...], P10, list[float] | None]:
        x = self._x
        F = sm.jacobian_f(x, vx, self.k)  # type: ignore[arg-type]  # the state is a 4-tuple
        P = matrix_from_p10(self._p)
        PFt = P @ F.T
        Pp = symmetrise(F @ PFt + self._Q)
        xp = sm.f(x, vx, self.k)  # type: ignore[arg-type]  # the state is a 4-tuple
        return xp, p10_from_matrix(Pp), (PFt.ravel().tolist() if self.record else None)

    def _update_ay(self, x: tuple[float, ...], p: P10, y: float, vx: float
                   ) -> tuple[tuple[float, ...], P10]:
        Hr = sm.jacobian_h(x, vx, self.k)[1]  # type: ignore[arg-type]  # the state is a 4-tuple
        P = matrix_from_p10(p)
        c = P @ Hr  # P H^T
        s = float(Hr @ c) + self._r_ay
        e = y - sm.h_ay(x, vx, self.k)  # type: ignore[arg-type]  # the state is a 4-tuple
        if not self._gate_ay(e, s):
            return x, p
        K = c / s
        xn = tuple(float(v) for v in np.asarray(x) + K * e)
        Pn = symmetrise(P - np.outer(K, c))
        return xn, p10_from_matrix(Pn)
