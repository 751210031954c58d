"""Compiled steering UKF step and fixed-lag smoother work (numba backend, vecu.kernels).

Under the numba backend SteeringUKF.step crosses into compiled code three times:
  `predict`  Cholesky (unrolled) + sigma points + Heun transition f + mean / covariance / the
             smoother's cross-covariance C (written into the history ring when recording);
  `ay_moments`  the a_y unscented update's moments (points redrawn from the updated (x, P));
  `push`     records the step in the ring and, for a fixed-lag smoother, the gain
             G = C P_pred^-1 of the previous step (LAPACK dgesv, see `solve4`) and the backward
             pass over the window.
`prepare_numba()` must run before any of them is called compiled (SteeringUKF does it on its
first numba step): it registers the helpers and the LAPACK symbol and compiles / loads all six.
Input checks, gating, counters, divergence resets and the state projection stay in Python
(vecu.estimators.steering.filters). If the unrolled Cholesky (common.small_linalg.chol4) finds P
not positive definite the kernel returns ok = False and Python computes the fallback factor
(small_linalg.chol4_or_fallback) and calls the `*_chol` variant with it.

Each kernel repeats the Python reference's floating-point operations in the same order (scalar
IEEE arithmetic, libm sin / atan / cos, correctly rounded sqrt; no fastmath, no reductions), so
both backends give bit-identical results (tests/estimators/steering/test_kernels.py). The tyre curve
(vecu.models.lateral.tyre_force) and the Cholesky (common.small_linalg.chol4) are the shared
kernels, called from here.

History ring (`Ring`): one float64 row per step, columns below; rows are written at `head`
(mod capacity), the oldest of `count` rows is dropped first, as the deques of the Python path.
The gain G_k is stored in row k (it is computed when row k+1 arrives).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from vecu.estimators.common.small_linalg import chol4
from vecu.kernels import kernel
from vecu.models.lateral import tyre_force

# history ring columns
COL_X, COL_P, COL_XP, COL_PP, COL_C, COL_VX, COL_G = 0, 4, 14, 18, 28, 44, 45
N_COLS = 61
# constants vector (see `constants`)
_DT, _M, _IZ, _LF, _LR, _DF, _BF, _DR, _BR, _C, _RAY, _Q = range(12)
N_CONSTS = _Q + 10
# column offsets of P's 16 entries (row-major) in the 10-entry upper triangle
_IDX16 = np.array([0, 1, 2, 3, 1, 4, 5, 6, 2, 5, 7, 8, 3, 6, 8, 9])
UNBOUNDED_START = 256  # initial rows of an unbounded ring (doubled when full)
NO_OUT = np.empty((0, 4))  # push: no output rows wanted

_registered = False


def constants(k: Any, q: tuple[float, ...], r_ay: float) -> np.ndarray:
    """The float64 vector the kernels read: model constants (steering_model.Consts), sigma_ay^2
    and Q's 10 entries."""
    return np.array([k.dt, k.m, k.iz, k.lf, k.lr, k.d_f, k.b_f, k.d_r, k.b_r, k.c, r_ay, *q],
                    dtype=np.float64)


def point_table(pts: tuple[tuple[tuple[float, ...], float], ...]) -> np.ndarray:
    """(n, 5) rows z0..z3, w of the UKF's non-zero-weight sigma pattern columns."""
    return np.array([[*z, w] for z, w in pts], dtype=np.float64)


# --------------------------------------------------------------------------- helpers
def transition(vy: float, r: float, d: float, dd: float, vx: float, cst: Any
               ) -> tuple[float, float, float, float]:
    """steering_model.f, the same operations in the same order."""
    dt, m, iz, lf, lr = cst[_DT], cst[_M], cst[_IZ], cst[_LF], cst[_LR]
    d_f, b_f, d_r, b_r, c = cst[_DF], cst[_BF], cst[_DR], cst[_BR], cst[_C]
    ffc = tyre_force(d_f, c, b_f, d - (vy + lf * r) / vx) * math.cos(d)
    fr = tyre_force(d_r, c, b_r, (lr * r - vy) / vx)
    a1 = (ffc + fr) / m - vx * r
    b1 = (lf * ffc - lr * fr) / iz
    vy2, r2, d2 = vy + dt * a1, r + dt * b1, d + dt * dd
    ffc = tyre_force(d_f, c, b_f, d2 - (vy2 + lf * r2) / vx) * math.cos(d2)
    fr = tyre_force(d_r, c, b_r, (lr * r2 - vy2) / vx)
    h2 = 0.5 * dt
    return (vy + h2 * (a1 + (ffc + fr) / m - vx * r2),
            r + h2 * (b1 + (lf * ffc - lr * fr) / iz), d2, dd)


def lateral_accel(vy: float, r: float, d: float, vx: float, cst: Any) -> float:
    """steering_model.h_ay, the same operations in the same order."""
    ff = tyre_force(cst[_DF], cst[_C], cst[_BF], d - (vy + cst[_LF] * r) / vx)
    fr = tyre_force(cst[_DR], cst[_C], cst[_BR], (cst[_LR] * r - vy) / vx)
    return (ff * math.cos(d) + fr) / cst[_M]


def sigma_offsets(l: Any, pts: Any) -> np.ndarray:
    """(n, 4) rows S z_j with S the lower factor l (10 entries), as SteeringUKF._sigma."""
    l00, l10, l11, l20, l21, l22, l30, l31, l32, l33 = l
    n = pts.shape[0]
    dz = np.empty((n, 4))
    for j in range(n):
        z0, z1, z2, z3 = pts[j, 0], pts[j, 1], pts[j, 2], pts[j, 3]
        dz[j, 0] = l00 * z0
        dz[j, 1] = l10 * z0 + l11 * z1
        dz[j, 2] = l20 * z0 + l21 * z1 + l22 * z2
        dz[j, 3] = l30 * z0 + l31 * z1 + l32 * z2 + l33 * z3
    return dz


def predict_core(l: Any, x: Any, vx: float, cst: Any, pts: Any, hist: Any, slot: int,
                 rec: bool) -> tuple[bool, tuple[float, ...], tuple[float, ...]]:
    """SteeringUKF._predict from the factor l; when rec, x_pred, P_pred and C go to hist[slot]."""
    x0, x1, x2, x3 = x
    n = pts.shape[0]
    dz = sigma_offsets(l, pts)
    pr = np.empty((n, 4))
    for j in range(n):
        c0, c1, c2, c3 = transition(x0 + dz[j, 0], x1 + dz[j, 1], x2 + dz[j, 2],
                                    x3 + dz[j, 3], vx, cst)
        pr[j, 0], pr[j, 1], pr[j, 2], pr[j, 3] = c0, c1, c2, c3
    m0 = m1 = m2 = m3 = 0.0
    for j in range(n):
        w = pts[j, 4]
        m0 += w * pr[j, 0]
        m1 += w * pr[j, 1]
        m2 += w * pr[j, 2]
        m3 += w * pr[j, 3]
    q = _Q
    p00, p01, p02, p03, p11 = cst[q], cst[q + 1], cst[q + 2], cst[q + 3], cst[q + 4]
    p12, p13, p22, p23, p33 = cst[q + 5], cst[q + 6], cst[q + 7], cst[q + 8], cst[q + 9]
    if rec:
        for i in range(16):
            hist[slot, COL_C + i] = 0.0
    for j in range(n):
        w = pts[j, 4]
        e0, e1, e2, e3 = pr[j, 0] - m0, pr[j, 1] - m1, pr[j, 2] - m2, pr[j, 3] - m3
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
                di = dz[j, i]
                c = COL_C + 4 * i
                hist[slot, c] += di * a0
                hist[slot, c + 1] += di * a1
                hist[slot, c + 2] += di * a2
                hist[slot, c + 3] += di * a3
    xp = (m0, m1, m2, m3)
    pp = (p00, p01, p02, p03, p11, p12, p13, p22, p23, p33)
    if rec:
        for i in range(4):
            hist[slot, COL_XP + i] = xp[i]
        for i in range(10):
            hist[slot, COL_PP + i] = pp[i]
    return True, xp, pp


def ay_core(l: Any, x: Any, vx: float, cst: Any, pts: Any
            ) -> tuple[bool, float, float, float, float, float, float]:
    """Moments of SteeringUKF._update_ay from the factor l: (True, y_mean, s, c0..c3)."""
    x0, x1, x2 = x[0], x[1], x[2]
    n = pts.shape[0]
    dz = sigma_offsets(l, pts)
    gam = np.empty(n)
    for j in range(n):
        gam[j] = lateral_accel(x0 + dz[j, 0], x1 + dz[j, 1], x2 + dz[j, 2], vx, cst)
    ym = 0.0
    for j in range(n):
        ym += pts[j, 4] * gam[j]
    s = cst[_RAY]
    c0 = c1 = c2 = c3 = 0.0
    for j in range(n):
        g = gam[j]
        a = pts[j, 4] * (g - ym)
        s += a * (g - ym)
        c0 += a * dz[j, 0]
        c1 += a * dz[j, 1]
        c2 += a * dz[j, 2]
        c3 += a * dz[j, 3]
    return True, ym, s, c0, c1, c2, c3


def backward_pass(hist: Any, newest: int, n: int, out: Any) -> tuple[float, float, float, float]:
    """FixedLagSmoother._backward over the n rows ending at `newest`: returns the oldest
    smoothed mean and, if out has n rows, writes all of them there, oldest first."""
    cap = hist.shape[0]
    write = out.shape[0] == n
    i = newest
    m0, m1, m2, m3 = hist[i, 0], hist[i, 1], hist[i, 2], hist[i, 3]
    if write:
        out[n - 1, 0], out[n - 1, 1], out[n - 1, 2], out[n - 1, 3] = m0, m1, m2, m3
    for t in range(n - 2, -1, -1):
        nxt = i
        i = i - 1 if i > 0 else cap - 1
        e0 = m0 - hist[nxt, COL_XP]
        e1 = m1 - hist[nxt, COL_XP + 1]
        e2 = m2 - hist[nxt, COL_XP + 2]
        e3 = m3 - hist[nxt, COL_XP + 3]
        g = COL_G
        m0 = (hist[i, 0] + hist[i, g] * e0 + hist[i, g + 1] * e1 + hist[i, g + 2] * e2
              + hist[i, g + 3] * e3)
        m1 = (hist[i, 1] + hist[i, g + 4] * e0 + hist[i, g + 5] * e1 + hist[i, g + 6] * e2
              + hist[i, g + 7] * e3)
        m2 = (hist[i, 2] + hist[i, g + 8] * e0 + hist[i, g + 9] * e1 + hist[i, g + 10] * e2
              + hist[i, g + 11] * e3)
        m3 = (hist[i, 3] + hist[i, g + 12] * e0 + hist[i, g + 13] * e1 + hist[i, g + 14] * e2
              + hist[i, g + 15] * e3)
        if write:
            out[t, 0], out[t, 1], out[t, 2], out[t, 3] = m0, m1, m2, m3
    return m0, m1, m2, m3


def solve4(a: Any, b: Any, iw: Any) -> int:
    """LAPACK dgesv for a 4x4 system with 4 right-hand sides, in place: a (4, 4) column-major,
    b the 16 entries of B column-major (overwritten with X = A^-1 B), iw int32 scratch
    [n, nrhs, lda, ldb, info, ipiv x 4]; returns info (> 0: singular).

    Under numba this is a direct call of scipy.linalg.cython_lapack's dgesv (`prepare_numba`):
    np.linalg.solve calls the same routine (bit-identical on this machine; tested) but its numba
    implementation takes ~10 s to compile. As Python: np.linalg.solve."""
    try:
        x = np.linalg.solve(a.T, b.reshape(4, 4).T)
    except np.linalg.LinAlgError:
        return 1
    b[:] = x.T.ravel()
    return 0


def gain_into(hist: Any, slot: int, prev: int) -> None:
    """G = C P_pred^-1 from row slot into row prev's gain columns: G^T = P_pred^-1 C^T
    (FixedLagSmoother.step's np.linalg.solve(Pp, C.T).T; P_pred symmetric, so its row-major
    entries are its column-major ones, C row-major is C^T column-major and the solution X = G^T
    column-major is G row-major)."""
    a = np.empty((4, 4))
    k = COL_PP
    for i in range(4):
        for j in range(i, 4):
            a[i, j] = hist[slot, k]
            a[j, i] = hist[slot, k]
            k += 1
    b = np.empty(16)
    for i in range(16):
        b[i] = hist[slot, COL_C + i]
    iw = np.zeros(9, dtype=np.int32)
    iw[0] = iw[1] = iw[2] = iw[3] = 4
    if solve4(a, b, iw) != 0:
        raise np.linalg.LinAlgError("Singular matrix")
    for i in range(16):
        hist[prev, COL_G + i] = b[i]


_HELPERS = (gain_into, transition, lateral_accel, sigma_offsets, predict_core, ay_core,
            backward_pass)


# --------------------------------------------------------------------------- kernels
@kernel
def predict(x: Any, p: Any, vx: float, cst: Any, pts: Any, hist: Any, slot: int, rec: bool
            ) -> tuple[bool, tuple[float, ...], tuple[float, ...]]:
    """(ok, x_pred, P_pred); ok = False (nothing written) if the unrolled Cholesky fails."""
    ok, l = chol4(p)
    if not ok:
        return False, (0.0, 0.0, 0.0, 0.0), l
    return predict_core(l, x, vx, cst, pts, hist, slot, rec)


@kernel
def predict_chol(l: Any, x: Any, vx: float, cst: Any, pts: Any, hist: Any, slot: int,
                 rec: bool) -> tuple[bool, tuple[float, ...], tuple[float, ...]]:
    """`predict` with the lower factor given (the Cholesky fallback)."""
    return predict_core(l, x, vx, cst, pts, hist, slot, rec)


@kernel
def ay_moments(x: Any, p: Any, vx: float, cst: Any, pts: Any
               ) -> tuple[bool, float, float, float, float, float, float]:
    """(ok, y_mean, s, c0..c3) of the a_y update; ok = False if the unrolled Cholesky fails."""
    ok, l = chol4(p)
    if not ok:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    return ay_core(l, x, vx, cst, pts)


@kernel
def ay_moments_chol(l: Any, x: Any, vx: float, cst: Any, pts: Any
                    ) -> tuple[bool, float, float, float, float, float, float]:
    """`ay_moments` with the lower factor given (the Cholesky fallback)."""
    return ay_core(l, x, vx, cst, pts)


@kernel
def push(hist: Any, slot: int, prev: int, x: Any, p: Any, vx: float, n_back: int,
         out: Any) -> tuple[float, float, float, float]:
    """Write x, P, v_x into hist[slot]; if prev >= 0 the gain of row prev from this row's
    P_pred and C; if n_back > 0 the backward pass over the n_back rows ending here (its oldest
    mean is returned, all of them written to out if it has n_back rows)."""
    for i in range(4):
        hist[slot, COL_X + i] = x[i]
    for i in range(10):
        hist[slot, COL_P + i] = p[i]
    hist[slot, COL_VX] = vx
    if prev >= 0:
        gain_into(hist, slot, prev)
    if n_back > 0:
        return backward_pass(hist, slot, n_back, out)
    return 0.0, 0.0, 0.0, 0.0


@kernel
def smooth_window(hist: Any, newest: int, n: int, out: Any) -> None:
    """All n smoothed means of the window ending at `newest` into out (n, 4), oldest first."""
    backward_pass(hist, newest, n, out)


_DGESV_SYMBOL = "vecu_steering_dgesv"


def prepare_numba() -> None:
    """Once, before the first compilation or cache load of a kernel: make the helpers callable
    from compiled code and `solve4` a call of LAPACK dgesv (by symbol name, so numba's disk
    cache stays valid across processes)."""
    global _registered
    if _registered:
        return
    import llvmlite.binding as llvm
    from numba import types
    from numba.extending import get_cython_function_address, overload, register_jitable

    llvm.add_symbol(_DGESV_SYMBOL, get_cython_function_address("scipy.linalg.cython_lapack",
                                                               "dgesv"))
    ptr = types.voidptr
    dgesv = types.ExternalFunction(_DGESV_SYMBOL, types.void(ptr, ptr, ptr, ptr, ptr, ptr, ptr,
                                                             ptr))

    def solve4_lapack(a, b, iw):  # no annotations: numba compares them with the typer's
        # dgesv(n, nrhs, a, lda, ipiv, b, ldb, info)
        dgesv(iw[0:].ctypes, iw[1:].ctypes, a.ctypes, iw[2:].ctypes, iw[5:].ctypes, b.ctypes,
              iw[3:].ctypes, iw[4:].ctypes)
        return iw[4]

    overload(solve4)(lambda a, b, iw: solve4_lapack)
    for fn in _HELPERS:
        register_jitable(fn)
    _registered = True
    _load_all()


def _load_all() -> None:
    """Compile (or load from numba's cache) every kernel now, the rarely used Cholesky-fallback
    ones included, so that none compiles in the middle of a live run."""
    x, p = (0.0,) * 4, (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 1.0)
    cst = np.ones(N_CONSTS)
    pts = np.zeros((1, 5))
    hist = np.zeros((2, N_COLS))
    hist[:, COL_PP + np.array([0, 4, 7, 9])] = 1.0
    predict.compiled(x, p, 10.0, cst, pts, hist, 0, True)
    predict_chol.compiled(p, x, 10.0, cst, pts, hist, 0, True)
    ay_moments.compiled(x, p, 10.0, cst, pts)
    ay_moments_chol.compiled(p, x, 10.0, cst, pts)
    push.compiled(hist, 1, 0, x, p, 10.0, 2, NO_OUT)
    smooth_window.compiled(hist, 1, 2, np.empty((2, 4)))


# --------------------------------------------------------------------------- history ring


class Ring:
    """The recorded steps as rows of a float64 array (module docstring); maxlen None grows."""

    __slots__ = ("count", "head", "hist", "maxlen")

    def __init__(self, maxlen: int | None, rows: np.ndarray | None = None) -> None:
        self.maxlen = maxlen
        n = 0 if rows is None else rows.shape[0]
        cap = maxlen if maxlen is not None else max(UNBOUNDED_START, 2 * n)
        self.hist = np.zeros((max(cap, 1), N_COLS))
        if n:
            rows = rows[-cap:]
            n = rows.shape[0]
            self.hist[:n] = rows
        self.count = n
        self.head = n % self.hist.shape[0]

    def slot(self) -> int:
        """The row the next step writes (grows an unbounded ring first if it is full)."""
        cap = self.hist.shape[0]
        if self.maxlen is None and self.count == cap:
            self.hist = np.concatenate([self.hist, np.zeros((cap, N_COLS))])
            self.head = cap
        return self.head

    def advance(self) -> None:
        cap = self.hist.shape[0]
        self.head = (self.head + 1) % cap
        if self.count < cap:
            self.count += 1

    def newest(self) -> int:
        return (self.head - 1) % self.hist.shape[0]

    def ordered(self) -> np.ndarray:
        """Copy of the rows, oldest first."""
        cap = self.hist.shape[0]
        idx = (self.head - self.count + np.arange(self.count)) % cap
        return self.hist[idx]

    def record(self, slot: int, x: Any, p: Any, vx: float, smooth_lag: int | None, k: int
               ) -> tuple[float, float, float, float]:
        """Write step k's x, P, v_x into row `slot` (x_pred, P_pred, C are already there) and
        advance; with a fixed-lag smoother also the previous row's gain and, once k >= lag, the
        smoothed mean of step k - lag (returned; zeros otherwise). One kernel call."""
        prev, n_back = -1, 0
        cap = self.hist.shape[0]
        if smooth_lag is not None:
            if self.count and cap > 1:
                prev = self.newest()
            if k >= smooth_lag:
                n_back = min(self.count + 1, cap)
        out = push.compiled(self.hist, slot, prev, x, p, vx, n_back, NO_OUT)
        self.advance()
        return out

    def arrays(self) -> tuple[np.ndarray, ...]:
        """(x, P, x_pred, P_pred, C, v_x) over the rows, oldest first (a FilterRun's fields)."""
        rows = self.ordered()
        return (rows[:, COL_X:COL_P].copy(), rows[:, COL_P + _IDX16].reshape(-1, 4, 4),
                rows[:, COL_XP:COL_PP].copy(), rows[:, COL_PP + _IDX16].reshape(-1, 4, 4),
                rows[:, COL_C:COL_VX].reshape(-1, 4, 4), rows[:, COL_VX].copy())

    def vx(self) -> list[float]:
        return self.ordered()[:, COL_VX].tolist()

    def oldest_vx(self) -> float:
        return float(self.hist[(self.head - self.count) % self.hist.shape[0], COL_VX])

    def means(self) -> list[tuple[float, ...]]:
        """The smoothed means of the recorded window, oldest first (needs the gains)."""
        out = np.empty((self.count, 4))
        smooth_window.compiled(self.hist, self.newest(), self.count, out)
        return [tuple(m) for m in out.tolist()]


def rows_from_deques(hist: tuple, gains: Any) -> np.ndarray:
    """Ring rows from the Python path's history deques (x, P, x_pred, P_pred, C, v_x) and
    gains (G_k of all but the newest step, or None)."""
    xs, ps, xp, pp, cs, vs = hist
    rows = np.zeros((len(xs), N_COLS))
    if xs:
        rows[:, COL_X:COL_P] = np.array(xs)
        rows[:, COL_P:COL_XP] = np.array(ps)
        rows[:, COL_XP:COL_PP] = np.array(xp)
        rows[:, COL_PP:COL_C] = np.array(pp)
        rows[:, COL_C:COL_VX] = np.array(cs)
        rows[:, COL_VX] = np.array(vs, dtype=float)
        for j, g in enumerate(gains or ()):
            rows[j, COL_G:] = g
    return rows


def deques_from_rows(rows: np.ndarray, maxlen: int | None, smooth_lag: int | None
                     ) -> tuple[tuple, Any]:
    """The inverse of rows_from_deques: (history deques, gains deque or None)."""
    from collections import deque

    def col(a: int, b: int) -> deque:
        return deque((tuple(r) for r in rows[:, a:b].tolist()), maxlen=maxlen)

    hist = (col(COL_X, COL_P), col(COL_P, COL_XP), col(COL_XP, COL_PP), col(COL_PP, COL_C),
            deque(rows[:, COL_C:COL_VX].tolist(), maxlen=maxlen),
            deque(rows[:, COL_VX].tolist(), maxlen=maxlen))
    gains = None
    if smooth_lag is not None:
        gains = deque((tuple(r) for r in rows[:-1, COL_G:].tolist()), maxlen=smooth_lag)
    return hist, gains
