"""Parts of the production throttle estimator (vecu.estimators.throttle.production).

Eq. (3) (Vargas et al. 2015, Table I, or the calibration the filter is given, a ThrottleModel)
laid out for the particle filter as class matrices, and its particle buffers. The filter splits
theta into four classes, inside each of which eq. (3) is linear in [theta, rho, i, 1, sgn(rho)]
(b1, b2: the mode switching angles, 8 and 16 deg in Table I); the matrices are read off the
one source, vecu.models.throttle.mode_step, and both particle drivers (numpy, compiled loops)
and the Kalman stretches evaluate them:
  class 0: theta <= 1        mode 1, sgn(theta - 1) = -1
  class 1: 1 < theta <= b1   mode 1, sgn(theta - 1) = +1
  class 2: b1 < theta <= b2  mode 2
  class 3: theta > b2        mode 3
(theta = 1 exactly has sgn 0 in eq. 3; the filter uses -1 there: a 0.007 change of rho on a
measure-zero set.)
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from vecu.estimators.common.small_linalg import chol3_floored
from vecu.kernels import backend, kernel
from vecu.models.throttle import (
    C3,
    MODE_BOUNDS_DEG,
    PAPER_THROTTLE,
    THETA_MAX_DEG,
    THETA_MIN_DEG,
    ThrottleModel,
    mode_step,
)

CLASS_BOUNDS_DEG: tuple[float, float, float] = (1.0, MODE_BOUNDS_DEG[0], MODE_BOUNDS_DEG[1])
HIGH_CLASS = 3
_CLASS_MODE = (0, 0, 1, 2)
_CLASS_SGN_THETA = (-1.0, 1.0, 1.0, 1.0)

# Plausible range of the wattmeter reading. |i| is below 15 A 99.6 % of the time, but a
# mode-2 -> mode-3 crossing with large rho drives it to 42 A (y = 1788 W) in simulation at both
# alpha; v ~ N(0, 1) never puts y below -10 W in practice. Outside (Y_MIN_W, Y_MAX_W): rejected.
I_MAX_A = 50.0
Y_MAX_W = I_MAX_A * I_MAX_A
Y_MIN_W = -50.0

# The reported theta std (deg): floored, capped (ThrottleParticleFilter.theta_std_deg)
STD_FLOOR_DEG = 0.3
MAX_STD_DEG = 51.0

# Column of the constant term in the class matrices (the i row gets b*u there every step).
U_COL = 3


def class_bounds(model: ThrottleModel = PAPER_THROTTLE) -> tuple[float, float, float]:
    """The class boundaries (1, b1, b2) in deg for a calibration."""
    b1, b2 = model.mode_bounds_deg
    return (1.0, float(b1), float(b2))


def _class_rows(c: int, model: ThrottleModel) -> list[list[float]]:
    """3x5: [theta, rho, i, 1, sgn(rho)] -> [theta', rho', E i'] for class c, read off eq. (3)
    (mode_step, affine in those inputs within a class): column j is mode_step at the unit
    vector e_j with the constant terms off (c3 = 0, u = 0, sgn(theta - 1) = 0), so the
    coefficients come out exactly; the constant column is mode_step at 0 with the class's
    sgn(theta - 1). The input column (b u) is class_b. `+ 0.0` turns -0.0 into 0.0."""
    p = model.rows[_CLASS_MODE[c]]
    lin = p[:C3] + (0.0,)
    cols = (mode_step.py(lin, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0),  # theta
            mode_step.py(lin, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0),  # rho
            mode_step.py(lin, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0),  # i
            mode_step.py(p, 0.0, 0.0, 0.0, 0.0, 0.0, _CLASS_SGN_THETA[c]),  # 1
            mode_step.py(lin, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0))  # sgn(rho)
    return [[col[r] + 0.0 for col in cols] for r in range(3)]  # [2, U_COL] <- b u


def class_matrix_stack(model: ThrottleModel = PAPER_THROTTLE) -> np.ndarray:
    """12x5: the four classes' 3x5 matrices stacked (a fresh, writable copy)."""
    return np.array([row for c in range(4) for row in _class_rows(c, model)])


def class_b(model: ThrottleModel = PAPER_THROTTLE) -> tuple[float, ...]:
    """b of each class's mode (the input gain of the current row): mode_step's i' at u = 1."""
    return tuple(float(mode_step.py(model.rows[_CLASS_MODE[c]], 0.0, 0.0, 0.0, 1.0, 0.0,
                                    0.0)[2]) + 0.0 for c in range(4))


CLASS_B: tuple[float, ...] = class_b()


class Frame:
    """One particle set. F rows: theta, rho, i, 1, sgn(rho), theta^2, weight (cached views);
    F is a view of the caller's buffer when given (a Bank's FB)."""

    def __init__(self, n: int, F: np.ndarray | None = None) -> None:
        self.F: np.ndarray = np.zeros((7, n)) if F is None else F
        self.F[3] = 1.0
        self.F[6] = 1.0
        self.th, self.rh, self.ci, self.one, self.sg, self.th2, self.w = self.F
        self.top3 = self.F[:3]
        self.top5 = self.F[:5]


class Bank:
    """Buffers for one particle count: current / next frame, scratch rows and every constant of
    the step pre-broadcast to length n (numpy is ~40 % slower with a Python-float operand)."""

    def __init__(self, n: int, s_i: float, r_watt: float = 1.0,
                 bounds: tuple[float, float, float] = CLASS_BOUNDS_DEG,
                 sel: np.ndarray | None = None) -> None:
        self.n = n
        # FB: frames 0 and 1, then the scratch rows (also the compiled step's, careful mode);
        # sel[0] says which frame is the current one (shared by a filter's banks, kept in its
        # state vector; the compiled tick swaps by flipping it)
        self.FB = np.zeros((3, 7, n))
        self.frames = (Frame(n, self.FB[0]), Frame(n, self.FB[1]))
        self.sel = np.zeros(1) if sel is None else sel
        self.T = self.FB[2, :3]
        self.t1, self.t2, self.t3 = self.T
        self.cs = np.empty(n)  # resampling: cumulative weights
        self.ics = np.empty(n, dtype=np.intp)  # resampling: floor(cumulative * n_new + u0)
        self.counts = np.empty(n, dtype=np.intp)  # resampling: copies of each particle
        self.Y = np.empty((12, n))  # all four classes' predictions (mixed-class steps)
        self.Yflat = self.Y.reshape(-1)
        self.base = np.arange(3 * n).reshape(3, n)  # flat index of class 0's rows
        self.cls = np.empty(n, dtype=np.intp)
        self.idx = np.empty((3, n), dtype=np.intp)
        self.ar = np.arange(n)
        # class * 3n by ceil(theta) in 0..90: ceil <= 1 -> 0, 2..8 -> 1, 9..16 -> 2, >= 17 -> 3
        # (exact for whole-degree bounds; others: class_offset None, classes by searchsorted)
        self.bounds = np.array(bounds)
        whole = all(float(b).is_integer() for b in bounds)
        ceil_class = np.searchsorted(self.bounds, np.arange(91.0))
        self.class_offset = ceil_class * (3 * n) if whole else None
        inv_c = 1.0 / (2.0 * s_i)  # S = R + (2 s m)^2 = (2 s)^2 (R/(2s)^2 + m^2)
        kappa = np.sqrt(0.5) * inv_c
        self.inv_c2 = np.full(n, r_watt * (inv_c * inv_c))
        self.kappa = np.full(n, kappa)  # q = kappa / h = sqrt(0.5 / S), h^2 = 1/(2s)^2 + m^2
        self.neg_k2 = np.full(n, -kappa * kappa)  # -0.5 / S = neg_k2 / h^2
        self.neg_four_s2 = np.full(n, -4.0 * s_i * s_i)
        self.ninety = np.full(n, 90.0)
        self.zero = np.zeros(n)

    @property
    def cur(self) -> Frame:
        """The frame holding the particles."""
        return self.frames[int(self.sel[0])]

    @property
    def nxt(self) -> Frame:
        """The other frame (a step writes there, then swap())."""
        return self.frames[1 - int(self.sel[0])]

    def swap(self) -> None:
        """nxt becomes cur."""
        self.sel[0] = 1.0 - self.sel[0]


@kernel
def mode3_predict(x: Any, coef: Any, q_th: float, q_i: float, u: float) -> Any:
    """ModeThreeKalman's prediction on its state x = (th, rh, ci, p00, p01, p02, p11, p12, p22):
    x' = M [x, 1, E sgn rho] with the class-3 matrix M (its constant b u in the i row),
    P' = A P A^T + Q with A = M's first three columns, then the censored-Gaussian moments at the
    90 deg stop when it is within 4 sigma (theta' = min(theta, 90); with b = (90 - m) / s:
    E = m Phi(b) - s phi(b) + 90 (1 - Phi(b)), E[theta'^2] = (m^2 + s^2) Phi(b) - s (m + 90)
    phi(b) + 90^2 (1 - Phi(b)), and by Stein's lemma Cov(theta', z) = Cov(theta, z) Phi(b))."""
    (a00, a01, a02, k0, s0, a10, a11, a12, k1, s1, a20, a21, a22, b, s2) = coef
    th, rh, ci, p00, p01, p02, p11, p12, p22 = x
    sr = math.sqrt(p11) if p11 > 1e-12 else 1e-6
    e = math.erf(rh / (sr * 1.4142135623730951))  # E[sgn rho] under N(rh, p11)
    nth = a00 * th + a01 * rh + a02 * ci + k0 + s0 * e
    nrh = a10 * th + a11 * rh + a12 * ci + k1 + s1 * e
    nci = a20 * th + a21 * rh + a22 * ci + b * u + s2 * e
    # columns P r_j^T of the rows r_j of A
    u0 = a00 * p00 + a01 * p01 + a02 * p02
    u1 = a00 * p01 + a01 * p11 + a02 * p12
    u2 = a00 * p02 + a01 * p12 + a02 * p22
    v0 = a10 * p00 + a11 * p01 + a12 * p02
    v1 = a10 * p01 + a11 * p11 + a12 * p12
    v2 = a10 * p02 + a11 * p12 + a12 * p22
    w0 = a20 * p00 + a21 * p01 + a22 * p02
    w1 = a20 * p01 + a21 * p11 + a22 * p12
    w2 = a20 * p02 + a21 * p12 + a22 * p22
    n00 = a00 * u0 + a01 * u1 + a02 * u2 + q_th
    n01 = a00 * v0 + a01 * v1 + a02 * v2
    n02 = a00 * w0 + a01 * w1 + a02 * w2
    n11 = a10 * v0 + a11 * v1 + a12 * v2
    n12 = a10 * w0 + a11 * w1 + a12 * w2
    n22 = a20 * w0 + a21 * w1 + a22 * w2 + q_i
    if nth + 4.0 * math.sqrt(n00) > THETA_MAX_DEG:
        m, v = nth, n00
        sd = math.sqrt(v)
        top = THETA_MAX_DEG
        bb = (top - m) / sd
        cdf = 0.5 * math.erfc(-bb * 0.7071067811865476)
        pdf = math.exp(-0.5 * bb * bb) * 0.3989422804014327
        mean = m * cdf - sd * pdf + top * (1.0 - cdf)
        second = (m * m + v) * cdf - sd * (m + top) * pdf + top * top * (1.0 - cdf)
        nth = top if top < mean else mean  # noqa: FURB136 (min(mean, top) with its NaN order, compiled too)
        n00 = second - mean * mean
        n00 = 1e-9 if 1e-9 > n00 else n00  # noqa: FURB136 (max(n00, 1e-9), likewise)
        n01 *= cdf
        n02 *= cdf
    return (nth, nrh, nci, n00, n01, n02, n11, n12, n22)


@kernel
def mode3_update(x: Any, r: float, s: float) -> Any:
    """ModeThreeKalman's linear minimum-variance update with the innovation r = y - E[y] and its
    variance s (eq. 4 moments), Cov(x, y) = 2 m P[:, i]."""
    th, rh, ci, p00, p01, p02, p11, p12, p22 = x
    g = 2.0 * ci / s
    c = g * 2.0 * ci
    return (th + g * p02 * r, rh + g * p12 * r, ci + g * p22 * r, p00 - c * p02 * p02,
            p01 - c * p02 * p12, p02 - c * p02 * p22, p11 - c * p12 * p12,
            p12 - c * p12 * p22, p22 - c * p22 * p22)


@kernel
def mode3_step(x: Any, coef: Any, prm: Any, u: float, y: float, may_gate: bool) -> int:
    """One Kalman-stretch step on the state x (9 entries, updated in place): mode3_predict, then
    (y not NaN) mode3_update unless the innovation is beyond the gate (r^2 > gate S) and
    may_gate. prm = (q_th, q_i, R, gate). Returns 0 (no y: predicted only), 1 (updated) or 2
    (gated). Compiled: x, coef, prm are float64 arrays (one call, no tuple boxing); plain
    Python: lists / tuples."""
    st = mode3_predict((x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8]),
                       (coef[0], coef[1], coef[2], coef[3], coef[4], coef[5], coef[6], coef[7],
                        coef[8], coef[9], coef[10], coef[11], coef[12], coef[13], coef[14]),
                       prm[0], prm[1], u)
    status = 0
    if y == y:
        m, s2 = st[2], st[8]
        r = y - (m * m + s2)
        sv = 4.0 * m * m * s2 + 2.0 * s2 * s2 + prm[2]
        if r * r > prm[3] * sv and may_gate:
            status = 2
        else:
            st = mode3_update(st, r, sv)
            status = 1
    for k in range(9):
        x[k] = st[k]
    return status


@kernel
def mode3_leave(th: float, rh: float, ci: float, p00: float, p22: float, lo_deg: float,
                top_sigmas: float, i_min: float) -> bool:
    """The particle filter must take over again: True if theta - 3 sigma < lo_deg, theta +
    top_sigmas sigma > 90 (too much mass at the stop for the censored moments), i - 3 sigma <
    i_min, or P / x are broken (on the state's th, rh, ci, p00, p22)."""
    if not (p00 > 0.0 and p22 > 0.0 and p00 < 1e6 and p22 < 1e6):
        return True
    st = math.sqrt(p00)
    return (th - 3.0 * st < lo_deg or th + top_sigmas * st > THETA_MAX_DEG
            or ci - 3.0 * math.sqrt(p22) < i_min or not math.isfinite(th + rh))


@kernel
def theta_moments(sw: float, s_th: float, s_th2: float) -> tuple[bool, float, float]:
    """(ok, mean, variance) of theta from the weight sums w, w theta, w theta^2; not ok when
    sw is not > 0 or the mean, variance or sw are not finite (the filter's "no weight left")."""
    if not sw > 0.0:
        return False, 0.0, 0.0
    th = s_th / sw
    var = s_th2 / sw - th * th
    if not (math.isfinite(th) and math.isfinite(var) and math.isfinite(sw)):
        return False, 0.0, 0.0
    return True, th, var


@kernel
def report(th: float, var: float, inflation: float) -> tuple[float, float]:
    """The filter's output from a posterior mean / variance of theta: (theta clipped to the
    stops, std x inflation floored at STD_FLOOR_DEG and capped at MAX_STD_DEG); NaN th stays
    NaN (as Python's min(th, 90), compiled too)."""
    t = THETA_MIN_DEG if th < THETA_MIN_DEG else (THETA_MAX_DEG if THETA_MAX_DEG < th else th)  # noqa: FURB136
    sd = (math.sqrt(var) if var > 0.0 else 0.0) * inflation
    sd = STD_FLOOR_DEG if sd < STD_FLOOR_DEG else (MAX_STD_DEG if MAX_STD_DEG < sd else sd)  # noqa: FURB136
    return t, sd


@kernel
def mode3_tick(x: Any, coef: Any, prm: Any, u: float, y: float, may_gate: bool,
               cfg: Any) -> tuple[int, bool, float, float]:
    """One Kalman-stretch tick in one call: mode3_step, mode3_leave with cfg = (lo_deg,
    top_sigmas, i_min, inflation), report. Returns (status, leave, theta, std)."""
    status = mode3_step(x, coef, prm, u, y, may_gate)
    out = mode3_leave(x[0], x[1], x[2], x[3], x[8], cfg[0], cfg[1], cfg[2])
    th, sd = report(x[0], x[3], cfg[3])
    return status, out, th, sd


@kernel
def mode3_tick_buf(buf: Any, u: float, y: float, may_gate: bool) -> tuple[int, bool, float,
                                                                           float]:
    """mode3_tick on ModeThreeKalman.buf = x (9) | coef (15) | prm (4) | cfg (4): compiled, one
    array argument instead of four (~0.05 us each in numba's dispatch)."""
    return mode3_tick(buf[0:9], buf[9:24], buf[24:28], u, y, may_gate, buf[28:32])


class ModeThreeKalman:
    """Moment-matched Kalman filter for the stretches where the posterior is well inside mode 3.

    There eq. (3) is linear (the class-3 matrix, read off mode_step; the tiny friction
    c1 sgn(rho), |c1| = 0.0055, uses E[sgn rho] = erf(rho / (sqrt 2 sigma_rho))), and eq. (4)
    is handled with the exact Gaussian moments of i^2: E = m^2 + P_ii, Var = 4 m^2 P_ii + 2 P_ii^2 + 1, Cov(x, i^2) = 2 m P[:, i].
    Plain floats, unrolled 3x3 symmetric algebra, as kernels (mode3_predict / mode3_update /
    mode3_step: compiled under numba, the same Python otherwise) on the state tuple
    x = (th, rh, ci, p00, p01, p02, p11, p12, p22).
    The stop at 90 deg is handled by censored-Gaussian moments after each prediction.
    mode3_leave says when the particle filter must take over again (a mode switch or a current
    whose sign is no longer certain within reach); tick() is mode3_tick (step, leave, output).
    """

    __slots__ = ("buf", "cfg", "coef", "prm", "q_i", "q_th", "r", "x")

    def __init__(self, q_th: float, q_i: float, model: ThrottleModel = PAPER_THROTTLE,
                 gate: float = 49.0, buf: np.ndarray | None = None) -> None:
        rows = _class_rows(HIGH_CLASS, model)  # eq. (3) in mode 3, sgn(theta - 1) = 1
        rows[2][U_COL] = class_b(model)[HIGH_CLASS]  # this row's constant is b u
        self.coef = tuple(v for row in rows for v in row)
        self.q_th, self.q_i = q_th, q_i
        self.r = model.h_wattmeter * model.h_wattmeter
        self.prm = (q_th, q_i, self.r, float(gate))
        # one buffer x | coef | prm | cfg (mode3_tick_buf: one compiled argument), views of it
        # (buf: a view of the caller's, 32 entries)
        self.buf = np.zeros(9 + 15 + 4 + 4) if buf is None else buf
        self.x = self.buf[:9]  # th, rh, ci, p00, p01, p02, p11, p12, p22
        self.buf[9:24], self.buf[24:28] = self.coef, self.prm
        self.set_tick(-math.inf, math.inf, -math.inf, 1.0)

    th = property(lambda self: float(self.x[0]))
    rh = property(lambda self: float(self.x[1]))
    ci = property(lambda self: float(self.x[2]))
    p00 = property(lambda self: float(self.x[3]))
    p01 = property(lambda self: float(self.x[4]))
    p02 = property(lambda self: float(self.x[5]))
    p11 = property(lambda self: float(self.x[6]))
    p12 = property(lambda self: float(self.x[7]))
    p22 = property(lambda self: float(self.x[8]))

    def load(self, mean: np.ndarray, cov: np.ndarray) -> None:
        self.x[:] = (mean[0], mean[1], mean[2], cov[0, 0], cov[0, 1], cov[0, 2], cov[1, 1],
                     cov[1, 2], cov[2, 2])

    def predict(self, u: float) -> None:
        """mode3_predict."""
        self.x[:] = mode3_predict(tuple(self.x.tolist()), self.coef, self.q_th, self.q_i, u)

    def innovation(self, y: float) -> tuple[float, float]:
        """(y - E[y], Var[y]) under the current Gaussian (eq. 4 moments)."""
        m, s2 = self.ci, self.p22
        return y - (m * m + s2), 4.0 * m * m * s2 + 2.0 * s2 * s2 + self.r

    def update(self, r: float, s: float) -> None:
        """mode3_update."""
        self.x[:] = mode3_update(tuple(self.x.tolist()), r, s)

    def set_tick(self, lo_deg: float, top_sigmas: float, i_min: float,
                 inflation: float) -> None:
        """tick()'s leave thresholds (mode3_leave's) and output std inflation (report)."""
        self.cfg = (lo_deg, top_sigmas, i_min, inflation)
        self.buf[28:] = self.cfg

    def tick(self, u: float, y: float, may_gate: bool) -> tuple[int, bool, float, float]:
        """mode3_tick with set_tick's cfg: (status, leave, theta, std)."""
        if backend() == "numba":
            return mode3_tick_buf.compiled(self.buf, u, y, may_gate)
        x = self.x.tolist()
        out = mode3_tick.py(x, self.coef, self.prm, u, y, may_gate, self.cfg)
        self.x[:] = x
        return out

    def cholesky(self) -> tuple[float, float, float, float, float, float]:
        """Lower Cholesky factor (l00, l10, l11, l20, l21, l22) of P (pivots floored at 1e-12:
        a tiny jitter if needed; common.small_linalg.chol3_floored)."""
        return chol3_floored.py(tuple(self.x[3:].tolist()), 1e-12)


def systematic_counts(b: Bank, w: np.ndarray, n_new: int, u0: float) -> np.ndarray:
    """Systematic resampling of b.n weighted particles into n_new: the copy count of each
    (floor differences of the scaled cumulative weights; no binary search, no Python loop)."""
    cs, ics, counts = b.cs, b.ics, b.counts
    w.cumsum(out=cs)
    np.multiply(cs, n_new / float(cs[-1]), out=cs)
    cs += u0
    np.floor(cs, out=ics, casting="unsafe")
    counts[0] = ics[0]
    np.subtract(ics[1:], ics[:-1], out=counts[1:])
    counts[-1] += n_new - int(ics[-1])  # float rounding of the last cumulative sum
    return counts
