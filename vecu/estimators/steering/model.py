"""Filter-side model for the steering-wheel angle and side-slip (after Khalid et al., eqs. 1-3).

State x = [v_y, r, delta, delta_dot] (lateral velocity m/s, yaw rate rad/s, road-wheel angle rad
and its rate): the paper's lateral (4) and yaw (11) motion on the single-track model of
vecu.models.lateral, plus the steering angle as an estimated state driven by white delta_ddot
(PSD q_delta: a steering-rate random walk). Steering-wheel angle = i_s * delta; side slip
beta = atan(v_y / v_x). Input: the measured speed v_x (held over a step). Measurements
y = [r, a_y] (gyro, accelerometer; the paper's eq. 2 with a nonlinear h).

Discretisation (dt = 10 ms): Heun (explicit trapezoid) on the continuous dynamics, the input held:
  k1 = g(x), x1 = x + dt k1, k2 = g(x1), x+ = x + dt/2 (k1 + k2).
`jacobian_f` is the exact Jacobian of that map, I + dt/2 (A(x) + A(x1) (I + dt A(x))), and
`jacobian_h` that of h; both are tested against finite differences.
Pure functions on tuples of floats (the filters' hot path) with numpy wrappers for the matrices.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vecu.estimators.common.covariance import DivergenceBounds
from vecu.models.lateral import (
    DT_S,
    TyreConsts,
    VehicleParams,
    tyre_consts,
    tyre_force,
    tyre_force_slope,
)
from vecu.units import RAD_PER_DEG

N_STATE = 4
V_X_MIN = 3.0  # m/s: the single-track model is singular at standstill; v_x is clipped to this
STEERING_BOUNDS = DivergenceBounds(max_trace=1e3, max_abs_state=1e2)

State = tuple[float, float, float, float]
_tyre = tyre_force.py  # the plain-Python reference (hot path: no backend dispatch)
_tyre_slope = tyre_force_slope.py


@dataclass(frozen=True)
class SteeringModel:
    """Model, noise and prior of the steering filters (docs/models.md, 'Steering-wheel angle').

    q_delta: PSD of delta_ddot, rad^2/s^3: (200/16 deg/s^2)^2/Hz at the road wheel, i.e.
    (200 deg/s^2)^2/Hz at the steering wheel (the design note's 400 was second best in our sweep,
    docs/models.md). q_vy, q_r: white-noise PSDs on v_y', r' for model error (tyre curve,
    discretisation, speed noise); raising them from 0.05 m/s^2 / 0.5 deg/s^2 to 0.2 / 2 cut the
    smoother's error by a third (the filter then explains yaw transients less by delta). sigma_*: sensor noise matching vecu.plant.lateral.LateralSensors.
    Prior: x0 = 0 (the filters start at 0, possibly in a curve) with std p0_std.
    """

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

    @property
    def tyres(self) -> TyreConsts:
        return tyre_consts(self.params)

    def x0(self) -> np.ndarray:
        return np.zeros(N_STATE)

    def P0(self) -> np.ndarray:
        return np.diag(np.square(self.p0_std))


@dataclass(frozen=True)
class Consts:
    """Everything the hot path needs, as plain floats (built once per filter)."""

    dt: float
    m: float
    iz: float
    lf: float
    lr: float
    d_f: float
    b_f: float
    d_r: float
    b_r: float
    c: float
    i_s: float


def consts(model: SteeringModel) -> Consts:
    p, t = model.params, model.tyres
    return Consts(model.dt_s, p.mass_kg, p.yaw_inertia_kgm2, p.l_f_m, p.l_r_m,
                  t.d_f, t.b_f, t.d_r, t.b_r, t.c, p.steering_ratio)


def _forces(vy: float, r: float, d: float, vx: float, k: Consts) -> tuple[float, float]:
    """(F_yf cos delta, F_yr) from the slip angles (vecu.models.lateral.tyre_force)."""
    ff = _tyre(k.d_f, k.c, k.b_f, d - (vy + k.lf * r) / vx)
    fr = _tyre(k.d_r, k.c, k.b_r, (k.lr * r - vy) / vx)
    return ff * math.cos(d), fr


def deriv(x: State, vx: float, k: Consts) -> State:
    """Continuous dynamics g(x) = (v_y', r', delta', delta_dot') (eqs. 4, 11; delta_ddot = 0)."""
    vy, r, d, dd = x
    ffc, fr = _forces(vy, r, d, vx, k)
    return ((ffc + fr) / k.m - vx * r, (k.lf * ffc - k.lr * fr) / k.iz, dd, 0.0)


def f(x: State, vx: float, k: Consts) -> State:
    """Discrete transition x_{k+1} = f(x_k, v_x) (Heun, dt = k.dt). `deriv` inlined twice (this
    is the UKF's hot path); equal to x + dt/2 (g(x) + g(x + dt g(x))) (tested)."""
    dt = k.dt
    vy, r, d, dd = x
    lf, lr, m, iz, c = k.lf, k.lr, k.m, k.iz, k.c
    tyre, cos = _tyre, math.cos
    ffc = tyre(k.d_f, c, k.b_f, d - (vy + lf * r) / vx) * cos(d)
    fr = tyre(k.d_r, c, k.b_r, (lr * r - vy) / vx)
    a1 = (ffc + fr) / m - vx * r
    b1 = (lf * ffc - lr * fr) / iz
    vy2, r2, d2 = vy + dt * a1, r + dt * b1, d + dt * dd
    ffc = tyre(k.d_f, c, k.b_f, d2 - (vy2 + lf * r2) / vx) * cos(d2)
    fr = tyre(k.d_r, c, k.b_r, (lr * r2 - vy2) / vx)
    h2 = 0.5 * dt
    return (vy + h2 * (a1 + (ffc + fr) / m - vx * r2),
            r + h2 * (b1 + (lf * ffc - lr * fr) / iz), d2, dd)


def f_reference(x: State, vx: float, k: Consts) -> State:
    """`f` written plainly with `deriv` (for tests)."""
    dt = k.dt
    g1 = deriv(x, vx, k)
    x1 = tuple(x[i] + dt * g1[i] for i in range(4))
    g2 = deriv(x1, vx, k)  # type: ignore[arg-type]  # a 4-tuple built by a generator
    return tuple(x[i] + 0.5 * dt * (g1[i] + g2[i]) for i in range(4))  # type: ignore[return-value]  # a 4-tuple built by a generator


def h(x: State, vx: float, k: Consts) -> tuple[float, float]:
    """Measurement (r, a_y) with a_y = (F_yf cos delta + F_yr) / M."""
    ffc, fr = _forces(x[0], x[1], x[2], vx, k)
    return x[1], (ffc + fr) / k.m


def h_ay(x: State, vx: float, k: Consts) -> float:
    """The nonlinear row of h: a_y."""
    ffc, fr = _forces(x[0], x[1], x[2], vx, k)
    return (ffc + fr) / k.m


def swa(x: State | np.ndarray, k: Consts) -> float:
    """Steering-wheel angle i_s * delta (rad)."""
    return k.i_s * float(x[2])


def side_slip(x: State | np.ndarray, vx: float) -> float:
    """beta = atan(v_y / v_x) (rad)."""
    return math.atan2(float(x[0]), vx)


# --------------------------------------------------------------------------- Jacobians
def _force_grads(vy: float, r: float, d: float, vx: float, k: Consts
                 ) -> tuple[float, float, tuple[float, float, float], tuple[float, float]]:
    """(F_yf cos d, F_yr, d(F_yf cos d)/d(vy, r, d), dF_yr/d(vy, r))."""
    af = d - (vy + k.lf * r) / vx
    ar = (k.lr * r - vy) / vx
    ff, dff = _tyre_slope(k.d_f, k.c, k.b_f, af)  # F_f, dF_f/d alpha_f
    fr, dfr = _tyre_slope(k.d_r, k.c, k.b_r, ar)
    cd, sd = math.cos(d), math.sin(d)
    g_f = (-dff * cd / vx, -dff * cd * k.lf / vx, dff * cd - ff * sd)
    g_r = (-dfr / vx, dfr * k.lr / vx)
    return ff * cd, fr, g_f, g_r


def jacobian_g(x: State, vx: float, k: Consts) -> np.ndarray:
    """A(x) = dg/dx of the continuous dynamics."""
    _, _, gf, gr = _force_grads(x[0], x[1], x[2], vx, k)
    A = np.zeros((4, 4))
    A[0, 0] = (gf[0] + gr[0]) / k.m
    A[0, 1] = (gf[1] + gr[1]) / k.m - vx
    A[0, 2] = gf[2] / k.m
    A[1, 0] = (k.lf * gf[0] - k.lr * gr[0]) / k.iz
    A[1, 1] = (k.lf * gf[1] - k.lr * gr[1]) / k.iz
    A[1, 2] = k.lf * gf[2] / k.iz
    A[2, 3] = 1.0
    return A


def jacobian_f(x: State, vx: float, k: Consts) -> np.ndarray:
    """Exact Jacobian of the Heun step `f`: I + dt/2 (A(x) + A(x1) (I + dt A(x)))."""
    dt = k.dt
    A0 = jacobian_g(x, vx, k)
    g0 = deriv(x, vx, k)
    x1 = tuple(x[i] + dt * g0[i] for i in range(4))
    A1 = jacobian_g(x1, vx, k)  # type: ignore[arg-type]  # a 4-tuple built by a generator
    eye = np.eye(4)
    return eye + 0.5 * dt * (A0 + A1 @ (eye + dt * A0))


def jacobian_h(x: State, vx: float, k: Consts) -> np.ndarray:
    """H = dh/dx (2 x 4): [0, 1, 0, 0] and d a_y / dx."""
    _, _, gf, gr = _force_grads(x[0], x[1], x[2], vx, k)
    return np.array([[0.0, 1.0, 0.0, 0.0],
                     [(gf[0] + gr[0]) / k.m, (gf[1] + gr[1]) / k.m, gf[2] / k.m, 0.0]])


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


def measurement_noise(model: SteeringModel) -> np.ndarray:
    """R = diag(sigma_r^2, sigma_ay^2)."""
    return np.diag([model.sigma_r ** 2, model.sigma_ay ** 2])
