"""The particle step: eq. (3) prediction, then the prior current or the linearised optimal
proposal with its predictive-likelihood weights (eq. 4), and the moments.

`pf_step` is loops (compiled); its numpy form `numpy_step` runs under the python backend
(vecu.kernels), agreeing to rounding (tests/estimators/throttle/test_update.py). Frame rows:
theta, rho, i, 1, sgn rho, theta^2, weight (pf.state.Frame); s: the state record.
"""

# The explicit `a if a < b else b` selects keep numpy's NaN semantics (np.minimum / np.clip
# propagate NaN; Python's min / max depend on the argument order):
# ruff: noqa: FURB136

from __future__ import annotations

import bisect
import math
import weakref
from typing import Any

import numpy as np

from vecu.estimators.throttle.pf.model import HIGH_CLASS, U_COL
from vecu.kernels import kernel
from vecu.kernels.exp import exp_poly
from vecu.models.throttle import THETA_MIN_DEG

# pf_step modes
PRIOR = 0  # no measurement: i from its prior, weights unchanged
UPDATE = 1  # linearised optimal proposal, predictive-likelihood weights
CAREFUL = 2  # the same with the clamped correction and log-domain weights

_min = np.minimum.reduce  # (the np.min / .min() forms add a Python-level wrapper)
_max = np.maximum.reduce


def set_step_constants(s: Any, s_i: float, class_b: tuple[float, ...], r_watt: float,
                       bounds: tuple[float, float, float]) -> None:
    """Fill the state's step constants (s_i: the current's step noise std, r_watt: HH^T):
    S = (2 s)^2 h^2 with h^2 = R / (2s)^2 + m^2, q = kappa / h = sqrt(0.5 / S), -0.5 / S =
    neg_k2 / h^2, r = y - s^2 - m^2 = y + y_shift - h^2."""
    inv_c = 1.0 / (2.0 * s_i)
    kappa = np.sqrt(0.5) * inv_c
    s2 = s_i * s_i
    s.y_shift = r_watt / (4.0 * s_i * s_i) - s_i * s_i
    s.inv_c2 = r_watt * (inv_c * inv_c)
    s.kappa, s.neg_k2, s.neg_four_s2 = kappa, -kappa * kappa, -4.0 * s_i * s_i
    s.clip_lo, s.clip_hi = -0.25 / s2, 0.125 / s2  # 2 s^2 r / S in [-1/2, 1]
    s.class_b[:], s.bounds[:] = class_b, bounds


@kernel(error_model="numpy")
def eq3_row(out, th0, rh0, ci0, mats, s, u, r, c0, c1, c2, c3, z, theta_row):
    """Row r (0 theta, 1 rho, 2 i) of eq. (3) for every particle into out, each with class c_s
    for s = the number of class bounds below its theta (NaN: 0), picked by selects (vectorises);
    theta_row: + the noise z, clipped to [0, 90]."""
    n = th0.shape[0]
    bnd, cb = s.bounds, s.class_b
    k0, k1, k2 = bnd[0], bnd[1], bnd[2]
    ra, rb, rc, rd = 3 * c0 + r, 3 * c1 + r, 3 * c2 + r, 3 * c3 + r
    a0, a1, a2, a3, a4 = mats[ra, 0], mats[ra, 1], mats[ra, 2], mats[ra, 3], mats[ra, 4]
    b0, b1, b2, b3, b4 = mats[rb, 0], mats[rb, 1], mats[rb, 2], mats[rb, 3], mats[rb, 4]
    d0, d1, d2, d3, d4 = mats[rc, 0], mats[rc, 1], mats[rc, 2], mats[rc, 3], mats[rc, 4]
    e0, e1, e2, e3, e4 = mats[rd, 0], mats[rd, 1], mats[rd, 2], mats[rd, 3], mats[rd, 4]
    if r == 2:
        a3, b3, d3, e3 = cb[c0] * u, cb[c1] * u, cb[c2] * u, cb[c3] * u
    for j in range(n):
        t0 = th0[j]
        x1 = rh0[j]
        g1, g2, g3 = t0 > k0, t0 > k1, t0 > k2
        sg = 1.0 if x1 > 0.0 else (-1.0 if x1 < 0.0 else 0.0)
        m0 = e0 if g3 else (d0 if g2 else (b0 if g1 else a0))
        m1 = e1 if g3 else (d1 if g2 else (b1 if g1 else a1))
        m2 = e2 if g3 else (d2 if g2 else (b2 if g1 else a2))
        m3 = e3 if g3 else (d3 if g2 else (b3 if g1 else a3))
        m4 = e4 if g3 else (d4 if g2 else (b4 if g1 else a4))
        t = m0 * t0 + m1 * x1 + m2 * ci0[j] + m3 + m4 * sg
        if theta_row:
            t = t + z[j]
            t = 90.0 if t > 90.0 else t
            t = 0.0 if t < 0.0 else t
        out[j] = t


class StepWork:
    """numpy_step's buffers for one bank FB (kept by the filter, found by FB): row views, the
    constants pre-broadcast (numpy is ~40 % slower with a float operand), the class tables."""

    def __init__(self, FB: np.ndarray, mats: np.ndarray, s: Any) -> None:
        n = FB.shape[2]
        self.views = [(FB[c], FB[c, 0], FB[c, 1], FB[c, 4], FB[c, :5], FB[c, 6], FB[1 - c],
                       FB[1 - c, 0], FB[1 - c, 2], FB[1 - c, 6], FB[1 - c, :3])
                      for c in (0, 1)]
        self.tmp = FB[2, 0], FB[2, 1], FB[2, 2]
        self.mats = mats
        self.Y = np.empty((12, n))  # all four classes' predictions (mixed-class steps)
        self.Yflat = self.Y.reshape(-1)
        self.base = np.arange(3 * n).reshape(3, n)  # flat index of class 0's rows
        self.cls = np.empty(n, dtype=np.intp)
        self.idx = np.empty((3, n), dtype=np.intp)
        self.cb = tuple(float(b) for b in s.bounds)
        self.bounds = np.array(self.cb)
        # class * 3n by ceil(theta) in 0..90: ceil <= 1 -> 0, 2..8 -> 1, 9..16 -> 2, >= 17 -> 3
        # (exact for whole-degree bounds; others: class_offset None, classes by searchsorted)
        whole = all(b.is_integer() for b in self.cb)
        self.class_offset = (np.searchsorted(self.bounds, np.arange(91.0)) * (3 * n)
                             if whole else None)
        self.class_b = tuple(float(b) for b in s.class_b)
        self.bvec = np.array(self.class_b)
        self.bcol = mats[2::3, U_COL]
        self.mviews = [mats[3 * c:3 * c + 3] for c in range(4)]
        self.inv_c2 = np.full(n, s.inv_c2)
        self.kappa = np.full(n, s.kappa)
        self.neg_k2 = np.full(n, s.neg_k2)
        self.neg_four_s2 = np.full(n, s.neg_four_s2)
        self.clip = float(s.clip_lo), float(s.clip_hi)
        self.ninety = np.full(n, 90.0)
        self.zero = np.zeros(n)
        self.yc = np.zeros(())  # 0-d array: y + y_shift of the current step
        _work[id(FB)] = weakref.ref(self)
        weakref.finalize(self, _work.pop, id(FB), None)


_work: dict[int, Any] = {}  # id(FB) -> weak reference to its StepWork


def frame_moments(F: np.ndarray) -> tuple[float, float, float, float]:
    """(sum w, sum w theta, sum w theta^2, sum w^2) of a frame (fills its theta^2 row)."""
    np.multiply(F[0], F[0], out=F[5])
    mom = F.dot(F[6])  # sums of w * [theta, rho, i, 1, sgn rho, theta^2, w]
    return float(mom[3]), float(mom[0]), float(mom[5]), float(mom[6])


def numpy_step(FB, cur, mats, s, ztab, u, lo_prev, hi_prev, o1, o2, mode, yc, extremes):
    """pf_step's numpy form (the python backend's): the same step on the same arguments; the
    max theta only while lo is at or below b2 or with extremes, the min i only with extremes
    (else 90 / NaN: the tick reads them only then)."""
    wk = _work[id(FB)]()
    src, th0, rh0, sg0, top5, w0, dst, th, ci, w, top3 = wk.views[cur]
    n = th0.shape[0]
    # eq. (3): one class, one matrix product; particles straddling a mode switch: all four
    # classes, then each particle's row picked by its class
    np.sign(rh0, out=sg0)
    c = bisect.bisect_left(wk.cb, lo_prev)
    if c == HIGH_CLASS or c == bisect.bisect_left(wk.cb, hi_prev):
        mats[3 * c + 2, U_COL] = wk.class_b[c] * u
        np.dot(wk.mviews[c], top5, out=top3)
    else:
        np.multiply(wk.bvec, u, out=wk.bcol)
        np.dot(mats, top5, out=wk.Y)
        if wk.class_offset is not None:  # whole-degree bounds: class by ceil(theta)
            np.ceil(th0, out=wk.cls, casting="unsafe")
            wk.class_offset.take(wk.cls, out=wk.cls, mode="clip")  # class * 3n
        else:  # other bounds: the number of bounds below theta, x 3n
            wk.cls[:] = np.searchsorted(wk.bounds, th0, side="left") * (3 * n)
        np.add(wk.base, wk.cls, out=wk.idx)
        wk.Yflat.take(wk.idx, out=top3, mode="clip")
    np.add(th, ztab[0, o1:o1 + n], out=th)
    np.minimum(th, wk.ninety, out=th)
    lo = float(_min(th))
    if lo < THETA_MIN_DEG:
        np.maximum(th, wk.zero, out=th)
        lo = THETA_MIN_DEG
    if mode == PRIOR:  # i from its prior N(m, s^2), weights unchanged
        np.add(ci, ztab[1, o2:o2 + n], out=ci)
        np.copyto(w, w0)
    else:
        _proposal(wk, w0, ci, w, ztab[2, o2:o2 + n], yc, mode == CAREFUL)
    sw, s_th, s_th2, s_w2 = frame_moments(dst)
    hi = float(_max(th)) if extremes or lo <= wk.cb[2] else 90.0
    return sw, s_th, s_th2, s_w2, lo, hi, float(_min(ci)) if extremes else math.nan


def _proposal(wk: StepWork, w0, m, w, zq, yc, careful: bool) -> None:
    """Linearised optimal proposal for i and predictive-likelihood weights (eq. 4): prior
    i ~ N(m, s^2), y ~ N(m^2 + s^2, S), S = 1 + 4 m^2 s^2; i = m (1 + 2 s^2 r / S) + s z / sqrt(S),
    r = y - m^2 - s^2; weight w N(y; m^2 + s^2, S). careful (y far from every particle): the
    correction clamped to [-1/2, 1], likelihoods scaled to a maximum of 1 (log domain)."""
    t1, t2, t3 = wk.tmp
    np.multiply(m, m, out=t1)
    np.add(t1, wk.inv_c2, out=t1)  # h^2 = 1/(2s)^2 + m^2 = S / (2s)^2
    np.sqrt(t1, out=t2)
    np.divide(wk.kappa, t2, out=t2)  # q = sqrt(0.5 / S)
    np.divide(wk.neg_k2, t1, out=t3)  # -0.5 / S
    wk.yc[()] = yc
    np.subtract(wk.yc, t1, out=t1)  # r
    np.multiply(t1, t3, out=t3)  # -0.5 r / S
    np.multiply(t1, t3, out=t1)  # -0.5 r^2 / S
    if careful:
        np.clip(t3, wk.clip[0], wk.clip[1], out=t3)
        t1 += np.log(t2)
        t1 -= t1.max()
        np.exp(t1, out=t1)
    else:
        np.exp(t1, out=t1)
        np.multiply(t2, t1, out=t1)  # sqrt(.5/S) exp(-r^2/2S): likelihood up to a constant
    np.multiply(w0, t1, out=w)
    np.multiply(t3, m, out=t3)
    np.multiply(t3, wk.neg_four_s2, out=t3)  # 2 s^2 r m / S
    np.add(t3, m, out=t3)
    np.multiply(t2, zq, out=t2)  # s z / sqrt(S)
    np.add(t3, t2, out=m)


@kernel(error_model="numpy", python=numpy_step)  # x / 0 -> inf / NaN as numpy
def pf_step(FB, cur, mats, s, ztab, u, lo_prev, hi_prev, o1, o2, mode, yc, extremes):
    """One particle step of bank FB from frame FB[cur] into FB[1 - cur] (FB[2]: scratch); mats
    the 12x5 class matrices, ztab the normal table's rows, lo_prev / hi_prev the set's extent,
    yc = y + y_shift. (sum w, sum w theta, sum w theta^2, sum w^2, min theta, max theta, min i),
    NaN-propagating; the extremes only as the tick reads them (numpy_step's)."""
    src, dst, tmp = FB[cur], FB[1 - cur], FB[2]
    n = src.shape[1]
    th0, rh0, ci0, w0 = src[0], src[1], src[2], src[6]
    th, rh, ci, w = dst[0], dst[1], dst[2], dst[6]
    zth, zi, zq = ztab[0, o1:o1 + n], ztab[1, o2:o2 + n], ztab[2, o2:o2 + n]
    t1, q, t3 = tmp[0], tmp[1], tmp[2]
    bnd, cb = s.bounds, s.class_b
    # bisect.bisect_left((1, b1, b2), x): the number of bounds below x (0 for NaN)
    k0, k1, k2 = bnd[0], bnd[1], bnd[2]
    c_lo = (1 if lo_prev > k0 else 0) + (1 if lo_prev > k1 else 0) + (1 if lo_prev > k2 else 0)
    c_hi = (1 if hi_prev > k0 else 0) + (1 if hi_prev > k1 else 0) + (1 if hi_prev > k2 else 0)
    # eq. (3): th = mats row 3c . [theta, rho, i, 1, sgn rho] (+ noise, clipped), likewise rho
    # and the predicted current m (into row ci; its constant column is b_c u). Every particle's
    # class lies between those of lo_prev and hi_prev (NaN theta: the lowest): one class, one
    # plain pass per row; several, one pass per row with the class picked per particle
    # (eq3_row, the same arithmetic). One output row per loop: few enough arrays for LLVM's
    # alias checks, so every loop vectorises.
    c_end = 3 if (c_lo == 3 or c_hi < c_lo) else c_hi  # c_hi < c_lo: hi_prev NaN
    if c_end > c_lo:  # slot s = the bounds below theta -> class clamp(s, c_lo, c_end)
        s1 = c_lo if c_lo > 1 else (1 if c_end > 1 else c_end)
        s2 = c_lo if c_lo > 2 else (2 if c_end > 2 else c_end)
        eq3_row(th, th0, rh0, ci0, mats, s, u, 0, c_lo, s1, s2, c_end, zth, True)
        eq3_row(rh, th0, rh0, ci0, mats, s, u, 1, c_lo, s1, s2, c_end, zth, False)
        eq3_row(ci, th0, rh0, ci0, mats, s, u, 2, c_lo, s1, s2, c_end, zth, False)
    else:
        r = 3 * c_lo
        a0, a1, a2, a3, a4 = mats[r, 0], mats[r, 1], mats[r, 2], mats[r, 3], mats[r, 4]
        b0, b1, b2, b3, b4 = (mats[r + 1, 0], mats[r + 1, 1], mats[r + 1, 2], mats[r + 1, 3],
                              mats[r + 1, 4])
        d0, d1, d2, d3, d4 = (mats[r + 2, 0], mats[r + 2, 1], mats[r + 2, 2], cb[c_lo] * u,
                              mats[r + 2, 4])
        for j in range(n):
            x1 = rh0[j]
            sg = 1.0 if x1 > 0.0 else (-1.0 if x1 < 0.0 else 0.0)  # NaN rho: all rows NaN anyway
            t = a0 * th0[j] + a1 * x1 + a2 * ci0[j] + a3 + a4 * sg
            t = t + zth[j]
            t = 90.0 if t > 90.0 else t
            th[j] = 0.0 if t < 0.0 else t  # numpy clips all at 0 if the minimum is below: same
        for j in range(n):
            x1 = rh0[j]
            sg = 1.0 if x1 > 0.0 else (-1.0 if x1 < 0.0 else 0.0)
            rh[j] = b0 * th0[j] + b1 * x1 + b2 * ci0[j] + b3 + b4 * sg
        for j in range(n):
            x1 = rh0[j]
            sg = 1.0 if x1 > 0.0 else (-1.0 if x1 < 0.0 else 0.0)
            ci[j] = d0 * th0[j] + d1 * x1 + d2 * ci0[j] + d3 + d4 * sg
    inv_c2, kappa, neg_k2, neg_four_s2 = s.inv_c2, s.kappa, s.neg_k2, s.neg_four_s2
    if mode == PRIOR:  # prior current, weights unchanged
        for j in range(n):
            ci[j] = ci[j] + zi[j]
            w[j] = w0[j]
    elif mode == UPDATE:  # the linearised optimal proposal (_proposal, fused into one loop)
        for j in range(n):
            m = ci[j]
            h2 = m * m
            h2 = h2 + inv_c2  # S / (2s)^2
            inv = 1.0 / h2  # one division (numpy: two; the same to rounding)
            qj = kappa * math.sqrt(inv)  # sqrt(0.5 / S)
            tj = neg_k2 * inv  # -0.5 / S
            rr = yc - h2  # r
            tj = rr * tj
            w[j] = w0[j] * (qj * exp_poly(rr * tj))  # likelihood up to a constant
            tj = tj * m
            tj = tj * neg_four_s2
            tj = tj + m
            ci[j] = tj + qj * zq[j]
    else:  # careful: the correction clamped, likelihoods scaled to a maximum of 1 (log domain)
        clip_lo, clip_hi = s.clip_lo, s.clip_hi
        for j in range(n):
            m = ci[j]
            h2 = m * m + inv_c2
            inv = 1.0 / h2
            q[j] = kappa * math.sqrt(inv)
            rr = yc - h2
            tj = rr * (neg_k2 * inv)
            t1[j] = rr * tj + math.log(q[j])
            t3[j] = clip_lo if tj < clip_lo else (clip_hi if tj > clip_hi else tj)
        mx = t1[0]
        for j in range(1, n):
            v = t1[j]
            if not math.isnan(mx) and (v > mx or math.isnan(v)):
                mx = v
        for j in range(n):
            w[j] = w0[j] * exp_poly(t1[j] - mx)
            m = ci[j]
            ci[j] = (t3[j] * m * neg_four_s2 + m) + q[j] * zq[j]
    # moments (sequential sums) and extremes, branch-free (a NaN theta makes s_th NaN; theta
    # is never infinite after the clip; ci_chk is NaN if some i is NaN or infinite)
    lo = th[0]
    hi = lo
    ci_min = ci[0]
    ci_chk = 0.0
    sw = 0.0
    s_th = 0.0
    s_th2 = 0.0
    s_w2 = 0.0
    for j in range(n):
        x = th[j]
        wj = w[j]
        sw += wj
        s_th += x * wj
        s_th2 += (x * x) * wj
        s_w2 += wj * wj
        lo = x if x < lo else lo
        hi = x if x > hi else hi
        v = ci[j]
        ci_min = v if v < ci_min else ci_min
        ci_chk += v * 0.0
    if math.isnan(s_th) or math.isnan(ci_chk):  # rare: NaN-propagating extremes, as numpy's
        lo = th[0]
        hi = lo
        ci_min = ci[0]
        for j in range(n):
            x = th[j]
            if not math.isnan(lo) and (x < lo or math.isnan(x)):
                lo = x
            if not math.isnan(hi) and (x > hi or math.isnan(x)):
                hi = x
            v = ci[j]
            if not math.isnan(ci_min) and (v < ci_min or math.isnan(v)):
                ci_min = v
    return sw, s_th, s_th2, s_w2, lo, hi, ci_min
