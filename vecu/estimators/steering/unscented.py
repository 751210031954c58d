"""The steering UKF's equations (Khalid et al., eqs. 16-26), each once, as kernels.

`sigma_offsets` (eq. 16: chi_j = x + S z_j, S = chol(P)); `predict` (eqs. 17-18, 26's + Q; when
recording also the smoother's C = sum_j w_j (chi_j - x)(f(chi_j) - x_pred)^T into the history
row); `ay_moments` (eqs. 19-22, points redrawn from (x, P)); `scalar_update` (eqs. 23-25: K =
P_xy / s, also the gyro's exact linear update). A P that chol4 cannot factor returns ok = False;
the caller passes chol4_or_fallback's factor to the `*_with_factor` forms. x, p as tuples (p the
10 upper-triangle entries), `cst` model.constants, `pts` the pattern rows (z0..z3, w).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from vecu.estimators.common.sigma_sets import SigmaSet
from vecu.estimators.common.small_linalg import chol4
from vecu.estimators.steering.history import COL_C, COL_PP, COL_XP, N_COLS
from vecu.estimators.steering.model import N_CONSTS, Q0, R_AY, accelerations, transition
from vecu.kernels import constants, kernel

P10 = tuple[float, float, float, float, float, float, float, float, float, float]
X4 = tuple[float, float, float, float]


def pattern(s: SigmaSet) -> tuple[tuple[float, ...], ...]:
    """(z0, z1, z2, z3, w) of the sigma set's pattern columns with w != 0 (the cubature set's
    zero-weight centre point dropped)."""
    cols = (tuple(float(v) for v in (*s.Z[:, j], s.w[j])) for j in range(s.points))
    return tuple(c for c in cols if c[4] != 0.0)


@kernel
def sigma_offsets(low: Any, pts: Any) -> list:
    """eq. 16: S z_j for each pattern row, S the lower factor `low` (10 entries, row by row)."""
    l00, l10, l11, l20, l21, l22, l30, l31, l32, l33 = low
    out = []
    for j in range(len(pts)):
        z = pts[j]
        z0, z1, z2, z3 = z[0], z[1], z[2], z[3]
        out.append((l00 * z0, l10 * z0 + l11 * z1, l20 * z0 + l21 * z1 + l22 * z2,
                    l30 * z0 + l31 * z1 + l32 * z2 + l33 * z3))
    return out


@kernel
def predict_with_factor(low: Any, x: Any, vx: float, cst: Any, pts: Any, hist: Any, slot: int,
                        rec: bool) -> tuple[bool, X4, P10]:
    """eqs. 17-18 from the factor `low` of P: (True, x_pred, P_pred); with rec, x_pred, P_pred
    and C into hist[slot] (module docstring)."""
    x0, x1, x2, x3 = x[0], x[1], x[2], x[3]
    dz = sigma_offsets(low, pts)
    n = len(dz)
    props = []
    for j in range(n):
        d0, d1, d2, d3 = dz[j]
        props.append(transition(x0 + d0, x1 + d1, x2 + d2, x3 + d3, vx, cst))
    m0 = m1 = m2 = m3 = 0.0
    for j in range(n):
        w = pts[j][4]
        c0, c1, c2, c3 = props[j]
        m0 += w * c0
        m1 += w * c1
        m2 += w * c2
        m3 += w * c3
    p00, p01, p02, p03, p11 = cst[Q0], cst[Q0 + 1], cst[Q0 + 2], cst[Q0 + 3], cst[Q0 + 4]
    p12, p13, p22, p23, p33 = cst[Q0 + 5], cst[Q0 + 6], cst[Q0 + 7], cst[Q0 + 8], cst[Q0 + 9]
    cr = [0.0] * 16
    for j in range(n):
        w = pts[j][4]
        c0, c1, c2, c3 = props[j]
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
            dj = dz[j]
            for i in range(4):
                di = dj[i]
                cr[4 * i] += di * a0
                cr[4 * i + 1] += di * a1
                cr[4 * i + 2] += di * a2
                cr[4 * i + 3] += di * a3
    xp = (m0, m1, m2, m3)
    pp = (p00, p01, p02, p03, p11, p12, p13, p22, p23, p33)
    if rec:
        for i in range(4):
            hist[slot, COL_XP + i] = xp[i]
        for i in range(10):
            hist[slot, COL_PP + i] = pp[i]
        for i in range(16):
            hist[slot, COL_C + i] = cr[i]
    return True, xp, pp


@kernel
def predict(x: Any, p: Any, vx: float, cst: Any, pts: Any, hist: Any, slot: int, rec: bool
            ) -> tuple[bool, X4, P10]:
    """`predict_with_factor` with chol4(P); ok = False (nothing written) if chol4 fails."""
    ok, low = chol4(p)
    if not ok:
        return False, (0.0, 0.0, 0.0, 0.0), low
    return predict_with_factor(low, x, vx, cst, pts, hist, slot, rec)


@kernel
def ay_moments_with_factor(low: Any, x: Any, vx: float, cst: Any, pts: Any
                           ) -> tuple[bool, float, float, float, float, float, float]:
    """eqs. 19-22 for a_y from the factor `low` of P: (True, y_mean, s = P_yy + sigma_ay^2,
    P_xy as c0..c3)."""
    x0, x1, x2 = x[0], x[1], x[2]
    dz = sigma_offsets(low, pts)
    n = len(dz)
    gam = []
    for j in range(n):
        d0, d1, d2, _ = dz[j]
        gam.append(accelerations(x0 + d0, x1 + d1, x2 + d2, vx, cst)[0])
    ym = 0.0
    for j in range(n):
        ym += pts[j][4] * gam[j]
    s = cst[R_AY]
    c0 = c1 = c2 = c3 = 0.0
    for j in range(n):
        g = gam[j]
        a = pts[j][4] * (g - ym)
        s += a * (g - ym)
        d0, d1, d2, d3 = dz[j]
        c0 += a * d0
        c1 += a * d1
        c2 += a * d2
        c3 += a * d3
    return True, ym, s, c0, c1, c2, c3


@kernel
def ay_moments(x: Any, p: Any, vx: float, cst: Any, pts: Any
               ) -> tuple[bool, float, float, float, float, float, float]:
    """`ay_moments_with_factor` with chol4(P); ok = False if chol4 fails."""
    ok, low = chol4(p)
    if not ok:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    return ay_moments_with_factor(low, x, vx, cst, pts)


@kernel(small=True)
def scalar_update(x: Any, p: Any, e: float, s: float, c0: float, c1: float, c2: float,
                  c3: float) -> tuple[X4, P10]:
    """eqs. 23-25 for one scalar reading: innovation e, its variance s, c = P_xy = P h^T;
    K = c / s, x + K e, P - K c^T (upper triangle)."""
    k0, k1, k2, k3 = c0 / s, c1 / s, c2 / s, c3 / s
    p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = p
    return ((x[0] + k0 * e, x[1] + k1 * e, x[2] + k2 * e, x[3] + k3 * e),
            (p00 - k0 * c0, p01 - k0 * c1, p02 - k0 * c2, p03 - k0 * c3,
             p11 - k1 * c1, p12 - k1 * c2, p13 - k1 * c3,
             p22 - k2 * c2, p23 - k2 * c3, p33 - k3 * c3))


_prepared = False


def prepare() -> None:
    """Once: run the step's kernels now (compiled or loaded from numba's disk cache under
    numba), the rarely used with-factor ones included, so that none compiles in the middle of
    a live run."""
    global _prepared
    if _prepared:
        return
    _prepared = True
    x, p = (0.0,) * 4, (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 1.0)
    cst, pts, hist = constants(np.ones(N_CONSTS)), constants(np.zeros((1, 5))), np.zeros((1, N_COLS))
    predict(x, p, 10.0, cst, pts, hist, 0, True)
    predict_with_factor(p, x, 10.0, cst, pts, hist, 0, True)
    ay_moments(x, p, 10.0, cst, pts)
    ay_moments_with_factor(p, x, 10.0, cst, pts)
