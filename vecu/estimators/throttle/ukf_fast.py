"""The paper's UKF (Step 3, any Step 2/2a/2b sigma set) for the throttle (n = 3) in plain floats:
unrolled Cholesky (chol3_or_fallback), eq. (3) by vecu.models.throttle.eq3_step, the Step-3 sums
in one pass; within 1e-9 relative of the generic numpy Step 3 (vecu.bench.reference_ukf).
"""

from __future__ import annotations

import math
import weakref
from typing import Any

import numpy as np

from vecu.estimators.common.covariance import DivergenceBounds, diverged_floats
from vecu.estimators.common.sigma_sets import SigmaSet, paper_set
from vecu.estimators.common.small_linalg import chol3_or_fallback
from vecu.estimators.throttle.model import (
    THROTTLE_BOUNDS,
    X0,
    measurement_noise_var,
    process_noise_diag,
)
from vecu.kernels import kernel
from vecu.models.throttle import PAPER_THROTTLE, ThrottleModel, clip_theta, eq3_step


class FastThrottleUKF:
    """ThrottleEstimator: the paper's UKF for the throttle, n = 3, scalar y, plain floats."""

    def __init__(
        self, sigma_set: SigmaSet | str, noise_scale: float = 1.0,
        bounds: DivergenceBounds = THROTTLE_BOUNDS, model: ThrottleModel = PAPER_THROTTLE,
    ) -> None:
        s = paper_set(sigma_set) if isinstance(sigma_set, str) else sigma_set
        if s.n != 3:
            raise ValueError("FastThrottleUKF needs a 3-state sigma set")
        self.name = s.name
        self.sigma_set = s
        self.noise_scale = float(noise_scale)
        self.bounds = bounds
        self._pattern = tuple(
            (float(s.Z[0, j]), float(s.Z[1, j]), float(s.Z[2, j]), float(s.w[j]))
            for j in range(s.points)
        )
        self.model = model
        self._rows = model.rows
        self._pattern_arr = np.array(self._pattern, dtype=np.float64)  # predict_moments'
        self._rows_arr = np.array(self._rows, dtype=np.float64)
        self._pattern_arr.flags.writeable = self._rows_arr.flags.writeable = False
        self._b1, self._b2 = (float(b) for b in model.mode_bounds_deg)
        self._q = process_noise_diag(noise_scale, model.f_diag)
        self._r = measurement_noise_var(model.h_wattmeter)
        self.resets = 0
        self.reset()

    def reset(self) -> None:
        """Back to x0 = 0, P0 = I (not counted as a divergence)."""
        self.x: tuple[float, float, float] = X0
        self.p: tuple[float, ...] = (1.0, 0.0, 0.0, 1.0, 0.0, 1.0)  # p00 p01 p02 p11 p12 p22

    @property
    def theta_deg(self) -> float:
        return self.x[0]

    @property
    def theta_std_deg(self) -> float:
        return math.sqrt(self.p[0]) if self.p[0] > 0.0 else 0.0

    @property
    def state(self) -> tuple[float, float, float]:
        return self.x

    @property
    def covariance(self) -> np.ndarray:
        p00, p01, p02, p11, p12, p22 = self.p
        return np.array([[p00, p01, p02], [p01, p11, p12], [p02, p12, p22]])

    def set_state(self, x: tuple[float, float, float], P: np.ndarray) -> None:
        """Overwrite the estimate (tests, warm starts); P is read as a symmetric 3x3 matrix."""
        self.x = (float(x[0]), float(x[1]), float(x[2]))
        Pa = np.asarray(P, dtype=float)
        self.p = (float(Pa[0, 0]), float(Pa[0, 1]), float(Pa[0, 2]),
                  float(Pa[1, 1]), float(Pa[1, 2]), float(Pa[2, 2]))

    def _diverged(self) -> bool:
        p00, p01, p02, p11, p12, p22 = self.p
        return diverged_floats(self.x, p00 + p11 + p22, p01 + p02 + p12, self.bounds)

    def _prior_moments(self) -> tuple[float, float, float, float, float]:
        """Reset to (x0, P0) and return y_pred, Pxy, Pyy of its (unpropagated) sigma points."""
        self.reset()
        l00, l10, l11, l20, l21, l22 = chol3_or_fallback(self.p)
        x2 = self.x[2]
        pts = []
        for z0, z1, z2, w in self._pattern:
            c = x2 + ((l20 * z0 + l21 * z1) + l22 * z2)
            pts.append((l00 * z0, l10 * z0 + l11 * z1, c - x2, c * c, w))
        yp = sum(g * w for _, _, _, g, w in pts)
        c0 = c1 = c2 = pyy = 0.0
        for d0, d1, d2, g, w in pts:
            ey = (g - yp) * w
            c0 += d0 * ey
            c1 += d1 * ey
            c2 += d2 * ey
            pyy += (g - yp) * ey
        return yp, c0, c1, c2, pyy

    def step(self, u_prev: float, y: float | None) -> None:
        """Step 2 (draw) + Step 3 (predict with u_prev; update with y unless None / non-finite)."""
        low = chol3_or_fallback(self.p)
        out = predict_moments(low, self.x, self._pattern_arr, self._rows_arr, self._b1, self._b2,
                              float(u_prev), self._q)
        x0, x1, x2, p00, p01, p02, p11, p12, p22, yp, c0, c1, c2, pyy = out
        self.x = (x0, x1, x2)
        self.p = (p00, p01, p02, p11, p12, p22)
        if self._diverged():
            self.resets += 1
            yp, c0, c1, c2, pyy = self._prior_moments()
        if y is None or not (-math.inf < y < math.inf):
            return
        self._update(float(y), yp, c0, c1, c2, pyy)

    def _update(self, y: float, yp: float, c0: float, c1: float, c2: float, pyy: float) -> None:
        """Step 3, update with Pxy = (c0, c1, c2) and Pyy (before adding HH^T): scalar gain."""
        pyy += self._r
        g0 = c0 / pyy
        g1 = c1 / pyy
        g2 = c2 / pyy
        v = y - yp
        x0, x1, x2 = self.x
        self.x = (x0 + g0 * v, x1 + g1 * v, x2 + g2 * v)
        h0 = g0 * pyy
        h1 = g1 * pyy
        h2 = g2 * pyy
        p00, p01, p02, p11, p12, p22 = self.p
        self.p = (p00 - h0 * g0, p01 - h0 * g1, p02 - h0 * g2,
                  p11 - h1 * g1, p12 - h1 * g2, p22 - h2 * g2)
        if self._diverged():
            self.resets += 1
            self.reset()


_lists: dict[int, Any] = {}  # id of a read-only array -> its tolist() (dropped with it)


def _as_list(a: np.ndarray) -> Any:
    if a.flags.writeable:
        return a.tolist()
    hit = _lists.get(id(a))
    if hit is None:
        hit = _lists[id(a)] = a.tolist()
        weakref.finalize(a, _lists.pop, id(a), None)
    return hit


def _moments_on_lists(low: Any, x: Any, pattern: Any, rows: Any, b1: float, b2: float, u: float,
                      q: Any) -> tuple[float, ...]:
    """predict_moments' python form: the same function on Python lists (in plain Python,
    numpy's element access and float64 scalars would cost the step about twice its time)."""
    return _predict_moments(low, x, _as_list(pattern), _as_list(rows), b1, b2, u, q)


def _predict_moments(low: Any, x: Any, pattern: Any, rows: Any, b1: float, b2: float, u: float,
                     q: Any) -> tuple[float, ...]:
    """Step 3's prediction: the sigma points x + L z of `pattern` (rows z0, z1, z2, w), each
    through eq. (3) (eq3_step, theta clipped), their mean, covariance + Q, y_pred = E[i^2], Pxy
    and Pyy (without HH^T), accumulated in one pass about the first propagated point. Returns
    (x0, x1, x2, p00, p01, p02, p11, p12, p22, y_pred, pxy0, pxy1, pxy2, pyy)."""
    l00, l10, l11, l20, l21, l22 = low
    x0, x1, x2 = x
    first = True
    r0 = r1 = r2 = ry = 0.0
    s0 = s1 = s2 = sy = 0.0
    p00 = p01 = p02 = p11 = p12 = p22 = c0 = c1 = c2 = pyy = 0.0
    for pt in pattern:
        z0, z1, z2, w = pt[0], pt[1], pt[2], pt[3]
        t = x0 + l00 * z0
        r = x1 + (l10 * z0 + l11 * z1)
        c = x2 + ((l20 * z0 + l21 * z1) + l22 * z2)
        tn, rn, cn = eq3_step(rows, b1, b2, t, r, c, u)
        tn = clip_theta(tn)
        if first:
            # Moments are accumulated about the first propagated point (shifted one-pass).
            r0, r1, r2, ry = tn, rn, cn, cn * cn
            first = False
            continue
        d0 = tn - r0
        d1 = rn - r1
        d2 = cn - r2
        dy = cn * cn - ry
        e0 = d0 * w
        e1 = d1 * w
        e2 = d2 * w
        ey = dy * w
        s0 += e0
        s1 += e1
        s2 += e2
        sy += ey
        p00 += e0 * d0
        p01 += e0 * d1
        p02 += e0 * d2
        p11 += e1 * d1
        p12 += e1 * d2
        p22 += e2 * d2
        c0 += d0 * ey
        c1 += d1 * ey
        c2 += d2 * ey
        pyy += dy * ey
    q0, q1, q2 = q
    return (r0 + s0, r1 + s1, r2 + s2,
            p00 - s0 * s0 + q0, p01 - s0 * s1, p02 - s0 * s2,
            p11 - s1 * s1 + q1, p12 - s1 * s2, p22 - s2 * s2 + q2,
            ry + sy, c0 - s0 * sy, c1 - s1 * sy, c2 - s2 * sy, pyy - sy * sy)


predict_moments = kernel(_predict_moments, python=_moments_on_lists)
