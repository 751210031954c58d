"""The Kalman stretches of the throttle particle filter: a moment-matched Kalman filter while the
posterior is well inside mode 3 (eq. (3) linear, the exact Gaussian moments of eq. (4)'s i^2,
the 90 deg stop by censored moments; docs/models.md, "Production throttle estimator"), and the
hand-overs. Kernels on the record's kf_x = (th, rh, ci, p00, p01, p02, p11, p12, p22).
"""

# ruff: noqa: FURB136 (explicit selects: their NaN order, the same compiled and in Python)

from __future__ import annotations

import math
from typing import Any

import numpy as np

from vecu.estimators.common.small_linalg import chol3_floored
from vecu.estimators.throttle.pf.model import HIGH_CLASS, U_COL, class_b, class_rows, report
from vecu.estimators.throttle.pf.state import Frame
from vecu.kernels import kernel
from vecu.models.throttle import PAPER_THROTTLE, THETA_MAX_DEG, THETA_MIN_DEG, ThrottleModel


@kernel
def mode3_predict(x: Any, coef: Any, q_th: float, q_i: float, u: float) -> Any:
    """The prediction on the state x: x' = M [x, 1, E sgn rho] with the class-3 matrix M of eq. (3),
    P' = A P A^T + Q (A = M's first three columns), then the censored-Gaussian moments at the 90 deg
    stop within 4 sigma (docs/models.md, "Production throttle estimator")."""
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
        nth = top if top < mean else mean  # min(mean, top) with its NaN order
        n00 = second - mean * mean
        n00 = 1e-9 if 1e-9 > n00 else n00  # max(n00, 1e-9), likewise
        n01 *= cdf
        n02 *= cdf
    return (nth, nrh, nci, n00, n01, n02, n11, n12, n22)


@kernel
def mode3_update(x: Any, r: float, s: float) -> Any:
    """The linear minimum-variance update with the innovation r = y - E[y] and its variance s
    (eq. 4 moments), Cov(x, y) = 2 m P[:, i]."""
    th, rh, ci, p00, p01, p02, p11, p12, p22 = x
    g = 2.0 * ci / s
    c = g * 2.0 * ci
    return (th + g * p02 * r, rh + g * p12 * r, ci + g * p22 * r, p00 - c * p02 * p02,
            p01 - c * p02 * p12, p02 - c * p02 * p22, p11 - c * p12 * p12,
            p12 - c * p12 * p22, p22 - c * p22 * p22)


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


def _mode3_tick(x: Any, coef: Any, prm: Any, u: float, y: float, may_gate: bool,
               cfg: Any) -> tuple[int, bool, float, float]:
    """One Kalman-stretch tick on the state x (updated in place): mode3_predict, then (y not
    NaN) mode3_update unless the innovation is beyond the gate (r^2 > gate S) and may_gate;
    mode3_leave with cfg = (lo_deg, top_sigmas, i_min, inflation); report. prm = (q_th, q_i,
    R, gate). Returns (status: 0 predicted only, 1 updated, 2 gated; leave, theta, std)."""
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
    out = mode3_leave(st[0], st[1], st[2], st[3], st[8], cfg[0], cfg[1], cfg[2])
    th, sd = report(st[0], st[3], cfg[3])
    return status, out, th, sd


def _tick_on_floats(x: Any, coef: Any, prm: Any, u: float, y: float, may_gate: bool,
                    cfg: Any) -> tuple[int, bool, float, float]:
    """mode3_tick's python form: the same function on Python floats (in plain Python, numpy's
    element access and float64 scalars would cost a Kalman tick about twice its time)."""
    xl = x.tolist()
    out = _mode3_tick(xl, coef.tolist(), prm.tolist(), u, y, may_gate, cfg.tolist())
    x[:] = xl
    return out


mode3_tick = kernel(_mode3_tick, python=_tick_on_floats)


def set_constants(s: Any, q_th: float, q_i: float, model: ThrottleModel = PAPER_THROTTLE,
                  gate: float = 49.0) -> None:
    """The stretch's constants in the state record s: eq. (3)'s class-3 rows (sgn(theta - 1) =
    1; the i row's constant is b u), (q_th, q_i, R, gate); leave thresholds off until set."""
    rows = class_rows(HIGH_CLASS, model)
    rows[2][U_COL] = class_b(model)[HIGH_CLASS]
    s.kf_coef[:] = [v for row in rows for v in row]
    s.kf_prm[:] = (q_th, q_i, model.h_wattmeter * model.h_wattmeter, float(gate))
    s.kf_cfg[:] = (-math.inf, math.inf, -math.inf, 1.0)


def usable(x: np.ndarray) -> bool:
    """The state x can seed particles: finite, variances of theta and i > 0, of rho >= 0."""
    th, rh, ci, p00, _, _, p11, _, p22 = x.tolist()
    return math.isfinite(th + rh + ci + p00 + p11 + p22) and p00 > 0.0 and p11 >= 0.0 and p22 > 0.0


def moment_match(f: Frame, sw: float, x: np.ndarray, theta_var_floor: float) -> None:
    """Hand the particles of frame f (weight sum sw) to the Kalman state x: their weighted mean
    and covariance, the covariance scaled up to theta_var_floor if theta's is below it (a
    freshly collapsed cloud, e.g. right after a mode-2 -> 3 throw, can be narrower than the
    truth's spread)."""
    w = f.w * (1.0 / sw)
    mean = f.top3.dot(w)
    d = f.top3 - mean[:, None]
    cov = (d * w).dot(d.T)
    if cov[0, 0] < theta_var_floor:
        cov *= theta_var_floor / max(float(cov[0, 0]), 1e-12)
    x[:] = (mean[0], mean[1], mean[2], cov[0, 0], cov[0, 1], cov[0, 2], cov[1, 1], cov[1, 2],
            cov[2, 2])


def draw_from(x: np.ndarray, f: Frame, z0: np.ndarray, z1: np.ndarray, z2: np.ndarray) -> None:
    """Particles of frame f (weights 1) from the Kalman state x's Gaussian, mean + L z with L
    the Cholesky factor of P (pivots floored at 1e-12, chol3_floored) and the standard normals
    z0, z1, z2; theta clipped to the stops."""
    th, rh, ci = x[:3].tolist()
    l00, l10, l11, l20, l21, l22 = chol3_floored(tuple(x[3:].tolist()), 1e-12)
    np.clip(th + l00 * z0, THETA_MIN_DEG, THETA_MAX_DEG, out=f.th)
    f.rh[:] = rh + l10 * z0 + l11 * z1
    f.ci[:] = ci + l20 * z0 + l21 * z1 + l22 * z2
    f.w.fill(1.0)
