"""The production throttle estimator's particle step in numpy: the python backend's reference.

ThrottleParticleFilter (vecu.estimators.throttle.production) under VECU_KERNELS=python steps
its particles with these methods: eq. (3) per mode class (Vargas et al. 2015, Table I, as
class matrices, pf_parts), the theta noise and the clip to the stops, then the prior current
(no y) or the linearised optimal proposal with its predictive-likelihood weights (eq. 4),
the careful variant, and the redo of a surprising step. Under numba the same step is
pf_kernels.pf_step inside the compiled tick (vecu.estimators.throttle.tick): same draws,
same decisions, results equal to rounding (tests/estimators/throttle/test_pf_kernels.py).
"""

from __future__ import annotations

import bisect

import numpy as np

from vecu.estimators.throttle.pf_kernels import AS_OUTLIER
from vecu.estimators.throttle.pf_parts import HIGH_CLASS, U_COL, Bank
from vecu.models.throttle import THETA_MAX_DEG, THETA_MIN_DEG

_min = np.minimum.reduce  # (the np.min / .min() forms add a Python-level wrapper)
_max = np.maximum.reduce


class NumpyParticleStep:
    """Mixin of ThrottleParticleFilter: its numpy particle step (the attributes below are the
    filter's)."""

    _cb: tuple[float, float, float]
    _cls_b: tuple[float, ...]
    _mats: np.ndarray
    _mviews: list[np.ndarray]
    _bvec: np.ndarray
    _bcol: np.ndarray
    _zth: np.ndarray
    _zi: np.ndarray
    _zq: np.ndarray
    _yc: np.ndarray
    _y_shift: float
    _s_i: float
    _lo: float
    _hi: float
    _gated: int
    rejected: int
    careful_updates: int

    def _summarise(self, f) -> float:  # the filter's
        raise NotImplementedError

    def _propagate(self, b: Bank, f, g, u: float, y: float | None, o1: int, o2: int,
                   careful: bool) -> float:
        """Predict f into g, then the prior current (y None) or the update with y; returns
        the new weight sum (_summarise). The numpy path (the reference); under numba the
        whole tick is pf_tick (pf_kernels.pf_step with the same draws and decisions)."""
        self._predict(b, f, g, u, o1)
        if y is None:
            self._prior_current(b, f, g, o2)
        else:
            self._update(b, f, g, y, o2, careful)
        return self._summarise(g)

    def _predict(self, b: Bank, f, g, u: float, o1: int) -> None:
        """Eq. (3) for every particle into frame g, theta noise added and clipped to [0, 90]."""
        np.sign(f.rh, out=f.sg)
        cb = self._cb
        c = bisect.bisect_left(cb, self._lo)
        if c == HIGH_CLASS or c == bisect.bisect_left(cb, self._hi):
            self._mats[3 * c + 2, U_COL] = self._cls_b[c] * u
            np.dot(self._mviews[c], f.top5, out=g.top3)
        else:  # particles straddle a mode switch: all four classes, then pick per particle
            np.multiply(self._bvec, u, out=self._bcol)
            np.dot(self._mats, f.top5, out=b.Y)
            if b.class_offset is not None:  # whole-degree bounds: class by ceil(theta)
                np.ceil(f.th, out=b.cls, casting="unsafe")  # exact class lookup by ceil(theta)
                b.class_offset.take(b.cls, out=b.cls, mode="clip")  # class * 3n
            else:  # other bounds: the number of bounds below theta, x 3n
                b.cls[:] = np.searchsorted(b.bounds, f.th, side="left") * (3 * b.n)
            np.add(b.base, b.cls, out=b.idx)
            b.Yflat.take(b.idx, out=g.top3, mode="clip")
        th = g.th
        np.add(th, self._zth[o1:o1 + b.n], out=th)
        np.minimum(th, b.ninety, out=th)
        lo = float(_min(th))
        if lo < THETA_MIN_DEG:
            np.maximum(th, b.zero, out=th)
            lo = THETA_MIN_DEG
        self._lo = lo
        self._hi = float(_max(th)) if lo <= self._cb[-1] else THETA_MAX_DEG

    def _prior_current(self, b: Bank, f, g, o2: int) -> None:
        """No measurement: i from its prior N(m, s^2), weights unchanged."""
        np.add(g.ci, self._zi[o2:o2 + b.n], out=g.ci)
        np.copyto(g.w, f.w)

    def _update(self, b: Bank, f, g, y: float, o2: int, careful: bool) -> None:
        """Linearised optimal proposal for i and predictive-likelihood weights (eq. 4).

        Prior i ~ N(m, s^2); y ~ N(m^2 + s^2, S), S = 1 + 4 m^2 s^2 (eq. 4 linearised at m);
        proposal i = m (1 + 2 s^2 r / S) + s z / sqrt(S), r = y - m^2 - s^2; new weight
        w N(y; m^2 + s^2, S). careful (y far from every particle): the linearisation overshoots
        (sqrt(m^2 + r) < m + r / 2m), so the relative correction is clamped to [-1/2, 1] and the
        likelihoods are scaled to a maximum of 1 in the log domain (no underflow).
        """
        m, t1, t2, t3 = g.ci, b.t1, b.t2, b.t3
        np.multiply(m, m, out=t1)
        np.add(t1, b.inv_c2, out=t1)  # h^2 = 1/(2s)^2 + m^2 = S / (2s)^2
        np.sqrt(t1, out=t2)
        np.divide(b.kappa, t2, out=t2)  # q = sqrt(0.5 / S)
        np.divide(b.neg_k2, t1, out=t3)  # -0.5 / S
        self._yc[()] = y + self._y_shift
        np.subtract(self._yc, t1, out=t1)  # r
        np.multiply(t1, t3, out=t3)  # -0.5 r / S
        np.multiply(t1, t3, out=t1)  # -0.5 r^2 / S
        if careful:
            s2 = self._s_i * self._s_i
            np.clip(t3, -0.25 / s2, 0.125 / s2, out=t3)  # 2 s^2 r / S in [-1/2, 1]
            t1 += np.log(t2)
            t1 -= t1.max()
            np.exp(t1, out=t1)
        else:
            np.exp(t1, out=t1)
            np.multiply(t2, t1, out=t1)  # sqrt(.5/S) exp(-r^2/2S): likelihood up to a constant
        np.multiply(f.w, t1, out=g.w)
        np.multiply(t3, m, out=t3)
        np.multiply(t3, b.neg_four_s2, out=t3)  # 2 s^2 r m / S
        np.add(t3, m, out=t3)
        np.multiply(t2, self._zq[o2:o2 + b.n], out=t2)  # s z / sqrt(S)
        np.add(t3, t2, out=m)

    def _replay(self, b: Bank, f, g, u: float, y: float, o1: int, o2: int,
                kind: int) -> float:
        """Redo the step from frame f (same random draws) as redo_kind said: y an isolated
        outlier -> predict only; otherwise the careful update. Returns the new weight sum."""
        if kind == AS_OUTLIER:
            self._gated += 1
            self.rejected += 1
            return self._propagate(b, f, g, u, None, o1, o2, False)
        self._gated = 0
        self.careful_updates += 1
        return self._propagate(b, f, g, u, y, o1, o2, True)
