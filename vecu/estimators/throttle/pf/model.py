"""The throttle particle filter's model: eq. (3) as class matrices, eq. (4)'s plausible range,
and the reported estimate.

Eq. (3) (Table I, or the calibration given) is linear in [theta, rho, i, 1, sgn(rho)] inside
each of four theta classes, its matrices read off vecu.models.throttle.mode_step: class 0
theta <= 1 (mode 1, sgn(theta - 1) = -1; also at theta = 1 exactly, a measure-zero change),
class 1 1 < theta <= b1 (mode 1, +1), class 2 b1 < theta <= b2 (mode 2), class 3 theta > b2.
"""

# ruff: noqa: FURB136 (explicit selects: their NaN order, the same compiled and in Python)

from __future__ import annotations

import math

import numpy as np

from vecu.kernels import kernel
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
U_COL = 3  # column of the constant term in the class matrices (the i row gets b u there)

# Plausible range of the wattmeter reading. |i| is below 15 A 99.6 % of the time, but a
# mode-2 -> mode-3 crossing with large rho drives it to 42 A (y = 1788 W) in simulation at both
# alpha; v ~ N(0, 1) never puts y below -10 W in practice. Outside (Y_MIN_W, Y_MAX_W): rejected.
I_MAX_A = 50.0
Y_MAX_W = I_MAX_A * I_MAX_A
Y_MIN_W = -50.0

# The reported theta std (deg): floored, capped (ThrottleParticleFilter.theta_std_deg)
STD_FLOOR_DEG = 0.3
MAX_STD_DEG = 51.0


def class_bounds(model: ThrottleModel = PAPER_THROTTLE) -> tuple[float, float, float]:
    """The class boundaries (1, b1, b2) in deg for a calibration."""
    b1, b2 = model.mode_bounds_deg
    return (1.0, float(b1), float(b2))


def class_rows(c: int, model: ThrottleModel = PAPER_THROTTLE) -> list[list[float]]:
    """3x5: [theta, rho, i, 1, sgn(rho)] -> [theta', rho', E i'] for class c, read off eq. (3)
    (mode_step, affine in those inputs within a class): column j is mode_step at the unit
    vector e_j with the constant terms off (c3 = 0, u = 0, sgn(theta - 1) = 0), so the
    coefficients come out exactly; the constant column is mode_step at 0 with the class's
    sgn(theta - 1). The input column (b u) is class_b. `+ 0.0` turns -0.0 into 0.0."""
    p = model.rows[_CLASS_MODE[c]]
    lin = p[:C3] + (0.0,)
    cols = (mode_step(lin, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0),  # theta
            mode_step(lin, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0),  # rho
            mode_step(lin, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0),  # i
            mode_step(p, 0.0, 0.0, 0.0, 0.0, 0.0, _CLASS_SGN_THETA[c]),  # 1
            mode_step(lin, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0))  # sgn(rho)
    return [[float(col[r]) + 0.0 for col in cols] for r in range(3)]  # [2, U_COL] <- b u


def class_matrix_stack(model: ThrottleModel = PAPER_THROTTLE) -> np.ndarray:
    """12x5: the four classes' 3x5 matrices stacked (a fresh, writable copy)."""
    return np.array([row for c in range(4) for row in class_rows(c, model)])


def class_b(model: ThrottleModel = PAPER_THROTTLE) -> tuple[float, ...]:
    """b of each class's mode (the input gain of the current row): mode_step's i' at u = 1."""
    return tuple(float(mode_step(model.rows[_CLASS_MODE[c]], 0.0, 0.0, 0.0, 1.0, 0.0,
                                 0.0)[2]) + 0.0 for c in range(4))


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
    t = THETA_MIN_DEG if th < THETA_MIN_DEG else (THETA_MAX_DEG if THETA_MAX_DEG < th else th)
    sd = (math.sqrt(var) if var > 0.0 else 0.0) * inflation
    sd = STD_FLOOR_DEG if sd < STD_FLOOR_DEG else (MAX_STD_DEG if MAX_STD_DEG < sd else sd)
    return t, sd


@kernel
def reported_std(th: float, sd: float, u: float, lock_below: float, lock_var: float,
                 lock_u: float) -> float:
    """The reported theta std: the posterior's sd, with lock_var added in quadrature while the
    filter is prone to be stuck below the mode-3 bound (theta <= lock_below and u > lock_u;
    False for NaN u), capped at MAX_STD_DEG (docs/models.md, Consistency)."""
    if th <= lock_below and u > lock_u:
        v = math.sqrt(sd * sd + lock_var)
        return MAX_STD_DEG if v > MAX_STD_DEG else v
    return sd
