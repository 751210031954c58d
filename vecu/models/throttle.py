"""Electronic throttle body model: piecewise-affine, 3 modes (Vargas et al. 2015, eq. 3-4, Table I).

Eq. (3) is written once, as two small kernels: `mode_step` (one mode's affine map) and `eq3_step`
(the switched system), called by the plant, the UKFs, the particle filter and the identification.
x = [theta, rho, i]: valve angle in degrees (the paper's 0.1 factor dropped, docs/models.md),
angular velocity, motor current in A; u: terminal voltage in V; wattmeter y = i**2 + v (eq. 4).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any

from vecu.kernels import kernel

THETA_MIN_DEG = 0.0
THETA_MAX_DEG = 90.0
MODE_BOUNDS_DEG = (8.0, 16.0)  # Theta_1 = [0, 8], Theta_2 = (8, 16], Theta_3 = (16, 90]
DT_S = 1e-3  # the paper's sampling period

# A mode's row of Table I, as mode_step reads it (ModeParams' fields in this order)
(A12, A21, A22, A23, A32, A33, B, C1, C2, C3) = range(10)
ModeRow = tuple[float, float, float, float, float, float, float, float, float, float]


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

    @property
    def row(self) -> ModeRow:
        """(a12, a21, a22, a23, a32, a33, b, c1, c2, c3) as floats: mode_step's `p`."""
        return (float(self.a12), float(self.a21), float(self.a22), float(self.a23),
                float(self.a32), float(self.a33), float(self.b), float(self.c1), float(self.c2),
                float(self.c3))


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

    @cached_property
    def rows(self) -> tuple[ModeRow, ModeRow, ModeRow]:
        """The three modes' rows (ModeParams.row): eq3_step's `rows` (computed once)."""
        return (self.mode1.row, self.mode2.row, self.mode3.row)


PAPER_THROTTLE = ThrottleModel()


@kernel(small=True)
def clip_theta(theta: float) -> float:
    """Mechanical stops: theta in [0, 90] deg (see docs/models.md, 'clip after every step');
    NaN passes."""
    if theta < THETA_MIN_DEG:
        return THETA_MIN_DEG
    if theta > THETA_MAX_DEG:
        return THETA_MAX_DEG
    return theta


@kernel(small=True)
def mode_step(p: Any, theta: Any, rho: Any, i: Any, u: Any, s_rho: Any, s_theta: Any
              ) -> tuple[Any, Any, Any]:
    """Eq. (3) inside one mode, noise-free, before the clip: x_{k+1} = A_s x_k + B_s u_k + c_s,
    c_s = (0, c1 s_rho + c2 s_theta + c3, 0); p the mode's row (A12 .. C3). Floats or arrays."""
    return (theta + p[A12] * rho,
            p[A21] * theta + p[A22] * rho + p[A23] * i + p[C1] * s_rho + p[C2] * s_theta + p[C3],
            p[A32] * rho + p[A33] * i + p[B] * u)


@kernel(small=True)
def mode_of(b1: float, b2: float, theta: float) -> int:
    """The active mode s - 1 of eq. (3): 0 for Theta_1 = theta <= b1, 1 for Theta_2 = (b1, b2],
    2 above (NaN counts as Theta_3)."""
    return 0 if theta <= b1 else (1 if theta <= b2 else 2)


@kernel(small=True)
def eq3_step(rows: Any, b1: float, b2: float, theta: float, rho: float, i: float, u: float
             ) -> tuple[float, float, float]:
    """Noise-free eq. (3), before the clip: the mode by theta (mode_of), then mode_step with
    sgn(rho) and sgn(theta - 1). rows: the three modes' rows (ThrottleModel.rows, or a 3x10
    array)."""
    p = rows[mode_of(b1, b2, theta)]
    return mode_step(p, theta, rho, i, u, 1.0 if rho > 0.0 else (-1.0 if rho < 0.0 else 0.0),
                     1.0 if theta > 1.0 else (-1.0 if theta < 1.0 else 0.0))


def step_mean(theta: float, rho: float, i: float, u: float,
              modes: tuple[ModeParams, ...] = TABLE_I,
              bounds: tuple[float, float] = MODE_BOUNDS_DEG) -> tuple[float, float, float]:
    """Noise-free part of eq. (3): x_{k+1} = A_s x_k + B_s u_k + c_s(x_k), before the clip
    (eq3_step for the given modes; callers in a loop call eq3_step with the rows)."""
    rows = PAPER_THROTTLE.rows if modes is TABLE_I else tuple(m.row for m in modes)
    return eq3_step(rows, bounds[0], bounds[1], theta, rho, i, u)


@kernel(small=True)
def wattmeter_reading(i: float, h: float, v: float) -> float:
    """y = i**2 + H v (eq. 4) for the standard Gaussian draw v."""
    return i * i + h * v

