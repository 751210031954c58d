"""Filter-side model for the steering-wheel angle and side-slip (after Khalid et al., eqs. 1-3).

x = [v_y, r, delta, delta_dot]: the lateral (4) and yaw (11) motion of vecu.models.lateral plus
the road-wheel angle driven by white delta_ddot (PSD q_delta). SWA = i_s delta, beta =
atan(v_y / v_x); input v_x held over a step; y = [r, a_y] (eq. 2 with a nonlinear h).
Heun on the continuous dynamics (dt = 10 ms): x+ = x + dt/2 (g(x) + g(x + dt g(x)));
`jacobian_f` is that map's exact Jacobian, `jacobian_h` h's. `accelerations` and `transition`
are the one copy of the equations, small kernels on a constants vector (`constants`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vecu.estimators.common.covariance import DivergenceBounds
from vecu.kernels import kernel
from vecu.models.lateral import (
    DT_S,
    TyreConsts,
    VehicleParams,
    lateral_motion,
    tyre_consts,
    tyre_force_slope,
)
from vecu.units import RAD_PER_DEG

N_STATE = 4
V_X_MIN = 3.0  # m/s: the single-track model is singular at standstill; v_x is clipped to this
STEERING_BOUNDS = DivergenceBounds(max_trace=1e3, max_abs_state=1e2)

State = tuple[float, float, float, float]


@dataclass(frozen=True)
class SteeringModel:
    """Model, noise and prior of the steering filters: q_delta (PSD of delta_ddot), q_vy, q_r (model
    error on v_y', r'), sensor sigmas, prior std p0_std (values and sweep: docs/models.md, "Steering ›
    Filters — decisions")."""

    params: VehicleParams = field(default_factory=VehicleParams)
    dt_s: float = DT_S
    q_delta: float = (200.0 / 16.0 * RAD_PER_DEG) ** 2
    q_vy: float = 0.2 ** 2
    q_r: float = (2.0 * RAD_PER_DEG) ** 2
    sigma_r: float = 0.2 * RAD_PER_DEG
    sigma_ay: float = 0.1
    p0_std: State = (1.0, 0.2, 5.0 * RAD_PER_DEG, 20.0 * RAD_PER_DEG)
    # Plausible ranges: outside (or non-finite) a reading is rejected and counted.
    max_abs_r: float = 2.5  # rad/s (~143 deg/s)
    max_abs_ay: float = 15.0  # m/s^2 (~1.5 g; road tyres stay below ~1.1 g)
    # State limits (projection after every step): beyond them the tyre curve is past its peak
    # and the a_y update can push the estimate further away (a trap seen with a spike at start).
    max_abs_delta: float = 0.6  # rad road wheel (SWA ~550 deg, about lock-to-lock / 2)
    max_slip_ratio: float = 0.35  # |v_y| <= this * v_x (|beta| <= 19 deg)
    max_v_x: float = 100.0  # m/s; v_x below V_X_MIN is clipped, above rejected (last kept)
    gate_sigma: float = 8.0  # innovation gate (in innovation std) ...
    gate_after_updates: int = 100  # ... armed after this many accepted readings (1 s)
    max_gated_in_row: int = 10  # ... then this many are accepted ungated
    bounds: DivergenceBounds = STEERING_BOUNDS
    # The reported covariance (reported_cov: the broadcast sigmas, the SWA plausibility gate,
    # NEES) is report_var_scale x (P + stiffness_rel_sigma^2 g g^T), g = stiffness_sensitivity:
    # a calibration error of the cornering stiffnesses is considered (Schmidt), and q_vy, q_r
    # (raised for the smoother) make P itself ~2x too wide (docs/models.md, "Consistency").
    stiffness_rel_sigma: float = 0.1
    report_var_scale: float = 0.45

    @property
    def tyres(self) -> TyreConsts:
        return tyre_consts(self.params)

    def x0(self) -> np.ndarray:
        return np.zeros(N_STATE)

    def P0(self) -> np.ndarray:
        return np.diag(np.square(self.p0_std))


# constants vector (`constants`): what the filters' equations read, as plain floats (the UKF's
# kernels take it as vecu.kernels.constants gives it; the same indices)
DT, M, IZ, LF, LR, DF, BF, DR, BR, C, IS, R_R, R_AY, Q0 = range(14)  # Q: 10 entries from Q0
N_CONSTS = Q0 + 10


def constants(model: SteeringModel) -> tuple[float, ...]:
    """(dt, M, I_z, l_f, l_r, D_f, B_f, D_r, B_r, C, i_s, sigma_r^2, sigma_ay^2, Q's upper
    triangle row by row), indexed by the names above."""
    p, t = model.params, model.tyres
    Q = process_noise(model)
    return tuple(float(v) for v in (
        model.dt_s, p.mass_kg, p.yaw_inertia_kgm2, p.l_f_m, p.l_r_m, t.d_f, t.b_f, t.d_r, t.b_r,
        t.c, p.steering_ratio, model.sigma_r ** 2, model.sigma_ay ** 2,
        *(Q[i, j] for i in range(4) for j in range(i, 4))))


@kernel(small=True)
def accelerations(vy: float, r: float, d: float, vx: float, cst: Any) -> tuple[float, float]:
    """(a_y, r'): the paper's lateral (4) and yaw (11) motion (models.lateral.lateral_motion)
    on the packed constants; a_y is eq. 2's nonlinear h."""
    return lateral_motion(vy, r, d, vx, cst[DF], cst[BF], cst[DR], cst[BR], cst[C], cst[LF],
                          cst[LR], cst[M], cst[IZ])


@kernel(small=True)
def transition(vy: float, r: float, d: float, dd: float, vx: float, cst: Any
               ) -> tuple[float, float, float, float]:
    """x_{k+1} = f(x_k, v_x): one Heun step of `deriv` (module docstring), dt = cst[DT];
    x + dt/2 (g(x) + g(x + dt g(x))) with the sums in this order (the golden logs' bits)."""
    dt = cst[DT]
    ay1, rd1 = accelerations(vy, r, d, vx, cst)
    a1 = ay1 - vx * r
    vy2, r2, d2 = vy + dt * a1, r + dt * rd1, d + dt * dd
    ay2, rd2 = accelerations(vy2, r2, d2, vx, cst)
    h2 = 0.5 * dt
    return vy + h2 * (a1 + ay2 - vx * r2), r + h2 * (rd1 + rd2), d2, dd


def deriv(x: State, vx: float, cst: Any) -> State:
    """Continuous dynamics g(x) = (v_y', r', delta', delta_dot') (eqs. 4, 11; delta_ddot = 0)."""
    vy, r, d, dd = x
    ay, rd = accelerations(vy, r, d, vx, cst)
    return (ay - vx * r, rd, dd, 0.0)


def h(x: State, vx: float, cst: Any) -> tuple[float, float]:
    """Measurement (r, a_y) (eq. 2 with a nonlinear h)."""
    return x[1], accelerations(x[0], x[1], x[2], vx, cst)[0]


def swa(x: Sequence[float] | np.ndarray, cst: Any) -> float:
    """Steering-wheel angle i_s * delta (rad)."""
    return cst[IS] * float(x[2])


def side_slip(x: Sequence[float] | np.ndarray, vx: float) -> float:
    """beta = atan(v_y / v_x) (rad)."""
    return math.atan2(float(x[0]), vx)


def stiffness_sensitivity(r: float, vx: float, p: VehicleParams) -> tuple[float, float]:
    """(d delta, d v_y) / d eps of the steady turn at yaw rate r when both cornering
    stiffnesses are (1 + eps) x the calibration: delta = (L + K v^2) r / v with K ~ 1/C gives
    -K v r; v_y = (l_r - M l_f v^2 / (L C_r)) r gives M l_f v^2 r / (L C_r)."""
    v = max(vx, V_X_MIN)
    return (-p.understeer_rad_per_mps2 * v * r,
            p.mass_kg * p.l_f_m * v * v * r / (p.wheelbase_m * p.c_r_n_per_rad))


# --------------------------------------------------------------------------- Jacobians
def _force_grads(vy: float, r: float, d: float, vx: float, k: Any
                 ) -> tuple[float, float, tuple[float, float, float], tuple[float, float]]:
    """(F_yf cos d, F_yr, d(F_yf cos d)/d(vy, r, d), dF_yr/d(vy, r))."""
    af = d - (vy + k[LF] * r) / vx
    ar = (k[LR] * r - vy) / vx
    ff, dff = tyre_force_slope(k[DF], k[C], k[BF], af)  # F_f, dF_f/d alpha_f
    fr, dfr = tyre_force_slope(k[DR], k[C], k[BR], ar)
    cd, sd = math.cos(d), math.sin(d)
    g_f = (-dff * cd / vx, -dff * cd * k[LF] / vx, dff * cd - ff * sd)
    g_r = (-dfr / vx, dfr * k[LR] / vx)
    return ff * cd, fr, g_f, g_r


def jacobian_g(x: State, vx: float, k: Any) -> np.ndarray:
    """A(x) = dg/dx of the continuous dynamics."""
    _, _, gf, gr = _force_grads(x[0], x[1], x[2], vx, k)
    m, iz, lf, lr = k[M], k[IZ], k[LF], k[LR]
    A = np.zeros((4, 4))
    A[0, 0] = (gf[0] + gr[0]) / m
    A[0, 1] = (gf[1] + gr[1]) / m - vx
    A[0, 2] = gf[2] / m
    A[1, 0] = (lf * gf[0] - lr * gr[0]) / iz
    A[1, 1] = (lf * gf[1] - lr * gr[1]) / iz
    A[1, 2] = lf * gf[2] / iz
    A[2, 3] = 1.0
    return A


def jacobian_f(x: State, vx: float, k: Any) -> np.ndarray:
    """Exact Jacobian of the Heun step `transition`: I + dt/2 (A(x) + A(x1) (I + dt A(x)))."""
    dt = k[DT]
    A0 = jacobian_g(x, vx, k)
    g0 = deriv(x, vx, k)
    x1 = (x[0] + dt * g0[0], x[1] + dt * g0[1], x[2] + dt * g0[2], x[3] + dt * g0[3])
    A1 = jacobian_g(x1, vx, k)
    eye = np.eye(4)
    return eye + 0.5 * dt * (A0 + A1 @ (eye + dt * A0))


def jacobian_h(x: State, vx: float, k: Any) -> np.ndarray:
    """H = dh/dx (2 x 4): [0, 1, 0, 0] and d a_y / dx."""
    _, _, gf, gr = _force_grads(x[0], x[1], x[2], vx, k)
    m = k[M]
    return np.array([[0.0, 1.0, 0.0, 0.0],
                     [(gf[0] + gr[0]) / m, (gf[1] + gr[1]) / m, gf[2] / m, 0.0]])


# --------------------------------------------------------------------------- noise
def process_noise(model: SteeringModel) -> np.ndarray:
    """Q per step: white delta_ddot (PSD q_delta) integrated exactly on [delta, delta_dot]
    (q [[dt^3/3, dt^2/2], [dt^2/2, dt]]), white q_vy dt, q_r dt on v_y, r."""
    dt, q = model.dt_s, model.q_delta
    Q = np.zeros((4, 4))
    Q[0, 0] = model.q_vy * dt
    Q[1, 1] = model.q_r * dt
    Q[2, 2] = q * dt ** 3 / 3.0
    Q[2, 3] = Q[3, 2] = q * dt ** 2 / 2.0
    Q[3, 3] = q * dt
    return Q
