"""Single-track vehicle model after Khalid et al.: eq. (4) lateral and eq. (11) yaw motion, one
axle each, Pacejka tyres; sensors eq. (3), Y = G Y0 + nu (+ optional bias). Pure `f`, `h` of
(x, u, params), x = [v_y, r], u = [delta, v_x], SI units; equations and parameter sources:
docs/models.md, "Steering › Plant"."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vecu.kernels import kernel
from vecu.units import G_MPS2

DT_S = 0.01  # sample period of the sensors and of the ECU filter (100 Hz)


@dataclass(frozen=True)
class VehicleParams:
    """Single-track parameters. M, I_z: the paper, Section III. l_f, l_r, C_f, C_r, mu, i_s, C:
    design note (the paper's l_f = 1100 m, l_r = 1500 m are garbled). Understeer 1.78 deg/g,
    characteristic speed 28.7 m/s."""

    mass_kg: float = 1410.0
    yaw_inertia_kgm2: float = 1800.0
    l_f_m: float = 1.1
    l_r_m: float = 1.5
    c_f_n_per_rad: float = 100e3  # front axle cornering stiffness
    c_r_n_per_rad: float = 120e3
    mu: float = 1.0
    shape_c: float = 1.3  # Pacejka C
    steering_ratio: float = 16.0  # i_s: steering-wheel angle / road-wheel angle

    @property
    def wheelbase_m(self) -> float:
        return self.l_f_m + self.l_r_m

    @property
    def understeer_rad_per_mps2(self) -> float:
        """K = M / L (l_r / C_f - l_f / C_r): delta = (L + K v^2) r / v in a steady turn."""
        p = self
        return p.mass_kg / p.wheelbase_m * (p.l_r_m / p.c_f_n_per_rad - p.l_f_m / p.c_r_n_per_rad)


@dataclass(frozen=True)
class TyreConsts:
    """Per-axle D (N) and B (1/rad) derived once from VehicleParams (static axle loads)."""

    d_f: float
    b_f: float
    d_r: float
    b_r: float
    c: float


def tyre_consts(p: VehicleParams) -> TyreConsts:
    """D = mu F_z (static loads M g l_r / L front, M g l_f / L rear), B = C_alpha / (C D)."""
    fz_f = p.mass_kg * G_MPS2 * p.l_r_m / p.wheelbase_m
    fz_r = p.mass_kg * G_MPS2 * p.l_f_m / p.wheelbase_m
    d_f, d_r = p.mu * fz_f, p.mu * fz_r
    return TyreConsts(d_f, p.c_f_n_per_rad / (p.shape_c * d_f),
                      d_r, p.c_r_n_per_rad / (p.shape_c * d_r), p.shape_c)


@kernel(small=True)
def tyre_force(d: float, c: float, b: float, alpha: float) -> float:
    """Lateral tyre force F_y = D sin(C atan(B alpha)) (N) at slip angle alpha (rad): Pacejka's
    magic formula without shifts."""
    return d * math.sin(c * math.atan(b * alpha))


@kernel(small=True)
def tyre_force_slope(d: float, c: float, b: float, alpha: float) -> tuple[float, float]:
    """(F_y, dF_y/dalpha) of `tyre_force`: with u = C atan(B alpha),
    (D sin u, D cos u C B / (1 + (B alpha)^2)) (the EKF's Jacobians)."""
    u = c * math.atan(b * alpha)
    return d * math.sin(u), d * math.cos(u) * c * b / (1.0 + (b * alpha) ** 2)


@kernel(small=True)
def lateral_motion(v_y: float, r: float, delta: float, v_x: float, d_f: float, b_f: float,
                   d_r: float, b_r: float, c: float, l_f: float, l_r: float, mass: float,
                   i_z: float) -> tuple[float, float]:
    """(a_y, r'): the paper's lateral (4) and yaw (11) motion per axle; v_y' = a_y - v_x r."""
    ffc = tyre_force(d_f, c, b_f, delta - (v_y + l_f * r) / v_x) * math.cos(delta)
    fr = tyre_force(d_r, c, b_r, (l_r * r - v_y) / v_x)
    return (ffc + fr) / mass, (l_f * ffc - l_r * fr) / i_z


def _motion(x: tuple[float, float], u: tuple[float, float], p: VehicleParams,
            t: TyreConsts | None) -> tuple[float, float]:
    t = t if t is not None else tyre_consts(p)
    return lateral_motion(x[0], x[1], u[0], u[1], t.d_f, t.b_f, t.d_r, t.b_r, t.c, p.l_f_m,
                          p.l_r_m, p.mass_kg, p.yaw_inertia_kgm2)


def f(x: tuple[float, float], u: tuple[float, float], p: VehicleParams,
      t: TyreConsts | None = None) -> tuple[float, float]:
    """Continuous dynamics (v_y', r') of eqs. (4), (11) for x = (v_y, r), u = (delta, v_x)."""
    a_y, r_dot = _motion(x, u, p, t)
    return a_y - u[1] * x[1], r_dot


def h(x: tuple[float, float], u: tuple[float, float], p: VehicleParams,
      t: TyreConsts | None = None) -> tuple[float, float]:
    """True sensor quantities (r, a_y) for x = (v_y, r), u = (delta, v_x)."""
    return x[1], _motion(x, u, p, t)[0]


def motion_constants(p: VehicleParams, t: TyreConsts) -> tuple[float, ...]:
    """lateral_motion's constants in its order: (D_f, B_f, D_r, B_r, C, l_f, l_r, M, I_z)."""
    return (t.d_f, t.b_f, t.d_r, t.b_r, t.c, p.l_f_m, p.l_r_m, p.mass_kg, p.yaw_inertia_kgm2)


@kernel
def rk4_motion(vy: float, r: float, d0: float, v0: float, d1: float, v1: float, dt: float,
               cst: tuple[float, ...]) -> tuple[float, float]:
    """One RK4 step of `f` (eqs. 4, 11) from x = (v_y, r), the input (delta, v_x) linear from
    (d0, v0) to (d1, v1); cst: motion_constants. The sums' order is the golden logs' bits."""
    df, bf, dr, br, c, lf, lr, m, iz = cst
    dm, vm = 0.5 * (d0 + d1), 0.5 * (v0 + v1)
    a, k1r = lateral_motion(vy, r, d0, v0, df, bf, dr, br, c, lf, lr, m, iz)
    k1v = a - v0 * r
    y, q = vy + 0.5 * dt * k1v, r + 0.5 * dt * k1r
    a, k2r = lateral_motion(y, q, dm, vm, df, bf, dr, br, c, lf, lr, m, iz)
    k2v = a - vm * q
    y, q = vy + 0.5 * dt * k2v, r + 0.5 * dt * k2r
    a, k3r = lateral_motion(y, q, dm, vm, df, bf, dr, br, c, lf, lr, m, iz)
    k3v = a - vm * q
    y, q = vy + dt * k3v, r + dt * k3r
    a, k4r = lateral_motion(y, q, d1, v1, df, bf, dr, br, c, lf, lr, m, iz)
    k4v = a - v1 * q
    return (vy + dt / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v),
            r + dt / 6.0 * (k1r + 2.0 * k2r + 2.0 * k3r + k4r))


def steady_state(delta: float, v_x: float, p: VehicleParams, iters: int = 60) -> tuple[float, float]:
    """(v_y, r) of a steady turn at (delta, v_x): Newton on f = 0 from the linear solution."""
    t = tyre_consts(p)
    L = p.wheelbase_m
    r = v_x * delta / (L + p.understeer_rad_per_mps2 * v_x * v_x)
    x = np.array([r * (p.l_r_m - p.mass_kg * p.l_f_m * v_x * v_x / (p.c_r_n_per_rad * L)), r])
    for _ in range(iters):
        fx = np.array(f((x[0], x[1]), (delta, v_x), p, t))
        J = np.empty((2, 2))
        for j in range(2):
            e = np.zeros(2)
            e[j] = 1e-6
            J[:, j] = (np.array(f((x[0] + e[0], x[1] + e[1]), (delta, v_x), p, t)) - fx) / 1e-6
        x = x - np.linalg.solve(J, fx)
        if float(np.abs(fx).max()) < 1e-12:
            break
    return float(x[0]), float(x[1])
