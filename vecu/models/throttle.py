"""Electronic throttle body model: piecewise-affine, 3 modes (Vargas et al. 2015, eq. 3-4, Table I).

Pure equations and constants, shared by the plant simulator and the estimators.

State x = [theta, rho, i]: valve angle theta in degrees (the paper's 0.1 factor dropped, see
docs/models.md), angular velocity rho in the model's own units, motor current i in A.
Input u: terminal voltage in V. Wattmeter measurement y = i**2 + v (eq. 4).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

THETA_MIN_DEG = 0.0
THETA_MAX_DEG = 90.0
MODE_BOUNDS_DEG = (8.0, 16.0)  # Theta_1 = [0, 8], Theta_2 = (8, 16], Theta_3 = (16, 90]
DT_S = 1e-3  # the paper's sampling period


@dataclass(frozen=True)
class ModeParams:
    """One column of Table I."""

    a12: float
    a21: float
    a22: float
    a23: float
    a32: float
    a33: float
    b: float
    c1: float
    c2: float
    c3: float


TABLE_I: tuple[ModeParams, ModeParams, ModeParams] = (
    ModeParams(-0.003, 0.148, 0.9625, -0.8673, 0.0005, 0.944, 0.0741, -0.0654, -0.007, 0.2255),
    ModeParams(0.0021, -0.143, 0.9941, 1.8944, -0.0004, 0.9514, 0.0346, -0.1068, 0.0529, -0.3419),
    ModeParams(0.0442, -0.0192, 0.7981, 0.3538, 0.0349, 0.9043, 0.0442, -0.0055, 0.0615, -0.0862),
)

# Process-noise gain F = diag(sqrt(0.35), 0, sqrt(0.18)) per 1 ms step (Section III-B).
F_DIAG: tuple[float, float, float] = (math.sqrt(0.35), 0.0, math.sqrt(0.18))
# Wattmeter noise gain H = 1 (eq. 4, v standard Gaussian).
H_WATTMETER = 1.0


@dataclass(frozen=True)
class ThrottleModel:
    """One throttle body: the three modes of eq. (3) (Table I columns), the mode switching
    angles, the process-noise gain F and the wattmeter noise gain H. PAPER_THROTTLE is Table I."""

    mode1: ModeParams = TABLE_I[0]
    mode2: ModeParams = TABLE_I[1]
    mode3: ModeParams = TABLE_I[2]
    mode_bounds_deg: tuple[float, float] = MODE_BOUNDS_DEG
    f_diag: tuple[float, float, float] = F_DIAG
    h_wattmeter: float = H_WATTMETER

    @property
    def modes(self) -> tuple[ModeParams, ModeParams, ModeParams]:
        return (self.mode1, self.mode2, self.mode3)


PAPER_THROTTLE = ThrottleModel()


def mode_index(theta: float, bounds: tuple[float, float] = MODE_BOUNDS_DEG) -> int:
    """Return 0, 1 or 2 for Theta_1, Theta_2, Theta_3 (negative theta counts as Theta_1)."""
    if theta <= bounds[0]:
        return 0
    if theta <= bounds[1]:
        return 1
    return 2


def _sgn(v: float) -> float:
    return 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)


def clip_theta(theta: float) -> float:
    """Mechanical stops: theta in [0, 90] deg (see docs/models.md, 'clip after every step')."""
    if theta < THETA_MIN_DEG:
        return THETA_MIN_DEG
    if theta > THETA_MAX_DEG:
        return THETA_MAX_DEG
    return theta


def step_mean(theta: float, rho: float, i: float, u: float,
              modes: tuple[ModeParams, ...] = TABLE_I,
              bounds: tuple[float, float] = MODE_BOUNDS_DEG) -> tuple[float, float, float]:
    """Noise-free part of eq. (3): x_{k+1} = A_s x_k + B_s u_k + c_s(x_k), before the clip."""
    p = modes[mode_index(theta, bounds)]
    theta_n = theta + p.a12 * rho
    rho_n = (
        p.a21 * theta + p.a22 * rho + p.a23 * i
        + p.c1 * _sgn(rho) + p.c2 * _sgn(theta - 1.0) + p.c3
    )
    i_n = p.a32 * rho + p.a33 * i + p.b * u
    return theta_n, rho_n, i_n


def wattmeter_mean(i: float) -> float:
    """h(x) of eq. (4): the power reading without noise, i**2."""
    return i * i
