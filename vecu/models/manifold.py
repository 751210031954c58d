"""Intake manifold and electronic throttle (Dutka et al. 2006, eq. 1-9), corrected: docs/models.md.

The paper's units (eq. 5, 6 and 8 hold literally): kPa, dm^3, K, rad, kg/s, W, rpm, s; only Xi of
eq. 2-3 needs P_a in Pa. Event state (eq. 10): x = (u_prev, alpha, alpha_prev, P_im, T_im,
T_im.meas), (u_prev, alpha, alpha_prev) the actuator state x_ET of eq. 1; input EngineInput.
Kernels for eq. 1/9, 2-4 and 8 and their functions on a parameter set; `integrate_manifold` (eq.
5-6 by ROS2 sub-steps); `f`/`h` of the augmented model; steady states.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import brentq

from vecu.kernels import kernel
from vecu.models.manifold_integrator import P_FLOOR_KPA, ROS2_GAMMA, interp, search_right, tables  # noqa: F401 (re-exported)
from vecu.models.manifold_integrator import integrate_manifold as _integrate_fast
from vecu.models.manifold_params import V8_5L7, EngineInput, ManifoldParams

N_STATE = 6


def nominal_input(ta_sp: float, n_rpm: float, params: ManifoldParams = V8_5L7) -> EngineInput:
    """EngineInput with the parameter set's nominal ambient and coolant conditions."""
    return EngineInput(ta_sp, n_rpm, params.p_a_kpa, params.t_a_k, params.t_cool_k)


# ------------------------------------------------------------------------- event timing

def sample_time(n_rpm: float, n_cyl: int = 8) -> float:
    """Event period T_s = 120 / (n_cyl N) s (Section II; 120/(8N) for the V8)."""
    return 120.0 / (n_cyl * n_rpm)


# ------------------------------------------------------------------------- actuator, eq. 1

@kernel
def event_coefficients(ts, zeta, omega0, tau):
    """(a1, a2, b1, b2, a_T, b_T) of one event of length ts: the corrected eq. 1 (the exact
    zero-order-hold discretisation of the actuator; formulas in docs/models.md, "Corrections to the
    printed equations") and eq. 9 for the IAT sensor, a_T = exp(-ts / tau), b_T = 1 - a_T."""
    zw = zeta * omega0
    w_et = omega0 * math.sqrt(1.0 - zeta * zeta)
    a = math.exp(-zw * ts)
    b = math.cos(w_et * ts)
    g = math.sin(w_et * ts)
    a_t = math.exp(-ts / tau)
    return (2.0 * a * b, -a * a, 1.0 - a * (b + zw * g / w_et), a * a + a * (zw * g / w_et - b),
            a_t, 1.0 - a_t)


@kernel
def event_map(co, u_prev, alpha, alpha_prev, sp, t, tm):
    """(alpha_{n+1}, T_meas,n+1): the corrected eq. 1 and eq. 9 of one event, co =
    event_coefficients(...), input sp now and u_prev before, T_im,n = t."""
    a1, a2, b1, b2, a_t, b_t = co
    return a1 * alpha + a2 * alpha_prev + b1 * sp + b2 * u_prev, a_t * tm + b_t * t


# ------------------------------------------------------------------------- throttle flow, eq. 2-4

@kernel
def flow_function_of(pr, c):
    """psi(pr) with dpsi/dpr on the integrator's constants c (manifold_integrator._param_consts):
    choked (eq. 3), subsonic (eq. 2), C1 quadratic near pr = 1 (see flow_function)."""
    if pr <= c[4]:
        return c[5], 0.0
    if pr < c[11]:
        root = math.sqrt(c[6] * (1.0 - pr ** c[8]))
        pe1 = pr ** c[7]
        return pe1 * root, c[7] * pr ** c[9] * root - pe1 * c[6] * c[8] * pr ** c[10] / (2.0 * root)
    s = 1.0 - pr
    if s < c[12]:
        return c[13], 0.0
    return c[14] * s + c[15] * s * abs(s), -(c[14] + 2.0 * c[15] * abs(s))


@kernel
def discharge_of(pr, alpha, c, cd_alpha, cd_table, prs):
    """(C_d, dC_d/dpr) by bilinear lookup on the tables (eq. 2-3 text), pr clamped to the table."""
    a = 0.0 if 0.0 > alpha else alpha  # noqa: FURB136 (min/max with Python's NaN behaviour)
    a_deg = math.degrees(c[26] if c[26] < a else a)  # noqa: FURB136 (as above)
    n = len(prs)
    lo_pr, hi_pr = float(prs[0]), float(prs[n - 1])  # plain floats in Python
    p = lo_pr if lo_pr > pr else pr  # noqa: FURB136 (as above)
    p = hi_pr if hi_pr < p else p  # noqa: FURB136 (as above)
    j = search_right(prs, p) - 1
    j = n - 2 if n - 2 < j else j  # noqa: FURB136 (as above)
    lo, _ = interp(a_deg, cd_alpha, cd_table[j])
    hi, _ = interp(a_deg, cd_alpha, cd_table[j + 1])
    pj = float(prs[j])
    s = (hi - lo) / (float(prs[j + 1]) - pj)
    return lo + s * (p - pj), s if lo_pr < pr < hi_pr else 0.0


@kernel
def throttle_flow_of(alpha, p_im, p_a, t_a, c, cd_alpha, cd_table, prs):
    """Eq. 2-4 on the integrator's constants and tables: (mdot_at, d mdot_at / dP_im)."""
    pr = p_im / p_a
    psi, dpsi = flow_function_of(pr, c)
    cd, dcd = discharge_of(pr, alpha, c, cd_alpha, cd_table, prs)
    a = 0.0 if 0.0 > alpha else alpha  # noqa: FURB136 (min/max with Python's NaN behaviour)
    a = c[26] if c[26] < a else a  # noqa: FURB136 (as above)
    xi0 = math.pi * c[27] * c[27] * (1.0 - math.cos(a)) * (1000.0 * p_a) / math.sqrt(c[1] * t_a)
    return xi0 * cd * psi, xi0 * (dcd * psi + cd * dpsi) / p_a


def critical_pressure_ratio(kappa: float) -> float:
    """Choking boundary (2/(kappa+1))^(kappa/(kappa-1)) of eq. 2-3 (0.5283 for kappa = 1.4)."""
    return (2.0 / (kappa + 1.0)) ** (kappa / (kappa - 1.0))


def psi_choked(kappa: float) -> float:
    """Eq. 3 corrected: sqrt(kappa) (2/(kappa+1))^((kappa+1)/(2(kappa-1))) = 0.6847 for kappa = 1.4.

    As printed, with 2/(kappa-1), it is 147.9.
    """
    return math.sqrt(kappa) * (2.0 / (kappa + 1.0)) ** ((kappa + 1.0) / (2.0 * (kappa - 1.0)))


def flow_function(pr: float, params: ManifoldParams = V8_5L7) -> tuple[float, float]:
    """psi(pr) with dpsi/dpr: choked (eq. 3), subsonic (eq. 2, the root over the whole bracket),
    and for s = 1 - pr < 1 - pr_reg the C1 quadratic psi = a s + b s|s| (no infinite slope at
    pr -> 1; a small reverse flow for pr > 1, saturated)."""
    return flow_function_of(pr, tables(params)[0])


def throttle_flow(alpha: float, p_im: float, p_a: float, t_a: float,
                  params: ManifoldParams = V8_5L7) -> tuple[float, float]:
    """Eq. 2-3: (mdot_at in kg/s, d mdot_at / dP_im in kg/s per kPa); Xi with P_a in Pa."""
    c, cd_alpha, cd_table, prs, _, _ = tables(params)
    return throttle_flow_of(alpha, p_im, p_a, t_a, c, cd_alpha, cd_table, prs)


# ------------------------------------------------------------------------- port flow, eq. 8

@kernel
def efficiency_of(n_rpm, p_im, c, eta_rpm, eta_val):
    """volumetric_efficiency on the integrator's constants c and the eta_N table."""
    eta_n, _ = interp(n_rpm, eta_rpm, eta_val)
    floor = P_FLOOR_KPA
    p = floor if floor > p_im else p_im  # noqa: FURB136 (max() with Python's NaN behaviour)
    resid = (c[20] / p) ** c[21]
    scale = eta_n / (c[19] - 1.0)
    return scale * (c[19] - resid), scale * c[21] * resid / p if p_im > floor else 0.0


@kernel
def air_charge_of(n_rpm, p_im, t_im, c, v_cyl, eta_rpm, eta_val):
    """cylinder_air_charge (kg per cylinder event): eta P_im V_cyl / (R_air T_im)."""
    eta, _ = efficiency_of(n_rpm, p_im, c, eta_rpm, eta_val)
    return eta * p_im * v_cyl / (c[1] * t_im)


@kernel
def port_flow_of(n_rpm, p_im, t_im, c, eta_rpm, eta_val):
    """port_flow, eq. 8 (kg/s): eta P_im N V_d / (120 R_air T_im)."""
    eta, _ = efficiency_of(n_rpm, p_im, c, eta_rpm, eta_val)
    return eta * p_im * n_rpm * c[28] / (120.0 * c[1] * t_im)


def volumetric_efficiency(
    n_rpm: float, p_im: float, params: ManifoldParams = V8_5L7,
) -> tuple[float, float]:
    """eta(N, P) = eta_N(N) (r_c - (P_exh/P)^(1/kappa)) / (r_c - 1): (eta, d eta/dP_im per kPa)."""
    c, _, _, _, eta_rpm, eta_val = tables(params)
    return efficiency_of(n_rpm, p_im, c, eta_rpm, eta_val)


def port_flow(p_im: float, t_im: float, n_rpm: float, params: ManifoldParams = V8_5L7) -> float:
    """Eq. 8: mdot_ac = eta P_im N V_d / (120 R_air T_im), kg/s (kPa dm^3 = J)."""
    c, _, _, _, eta_rpm, eta_val = tables(params)
    return port_flow_of(n_rpm, p_im, t_im, c, eta_rpm, eta_val)


def cylinder_air_charge(
    p_im: float, t_im: float, n_rpm: float, params: ManifoldParams = V8_5L7,
) -> float:
    """Air mass trapped per cylinder event, kg: mdot_ac T_s = eta P_im V_cyl / (R_air T_im)."""
    c, _, _, _, eta_rpm, eta_val = tables(params)
    return air_charge_of(n_rpm, p_im, t_im, c, params.v_cyl_dm3, eta_rpm, eta_val)


def heat_flow(t_im: float, t_a: float, t_cool: float, params: ManifoldParams = V8_5L7) -> float:
    """Q_ext = h1 (T_coolant - T_im) + h2 (T_a - T_im), W (eq. 5-6 text)."""
    return params.h1_w_per_k * (t_cool - t_im) + params.h2_w_per_k * (t_a - t_im)


# ------------------------------------------------------------------------- manifold, eq. 5-6

def integrate_manifold(p_im: float, t_im: float, alpha: float, u: EngineInput, dt: float,
                       params: ManifoldParams = V8_5L7) -> tuple[float, float, int]:
    """Advance (P_im, T_im) by dt with alpha and u held: (P_im, T_im, M). Eq. 5-6 in M ROS2
    sub-steps (gamma = 1 + 1/sqrt 2, W = diag(min(J_PP, 0), min(J_TT, 0))): k1 = f(x) /
    (1 - gamma h W), k2 = (f(x + h k1) - 2 k1) / (1 - gamma h W), x += h (1.5 k1 + 0.5 k2); M the
    smallest with h (|J_PP| + |J_TT|) <= lam_dt_max and the dP, dT steps bounded. Damps the
    throttle-flow pole for any h; the steady state is a fixed point (manifold_integrator)."""
    return _integrate_fast(p_im, t_im, alpha, u, dt, params)


def steady_state(
    alpha: float, u: EngineInput, params: ManifoldParams = V8_5L7,
) -> tuple[float, float]:
    """(P_im, T_im) with dP/dt = dT/dt = 0 at a fixed angle: mdot_at = mdot_ac and
    T_im = (kappa R mdot T_a + (kappa-1)(h1 T_cool + h2 T_a)) / (kappa R mdot + (kappa-1)(h1 + h2)).
    """
    k, r = params.kappa, params.r_air
    hsum = params.h1_w_per_k + params.h2_w_per_k
    hq = params.h1_w_per_k * u.t_cool + params.h2_w_per_k * u.t_a

    def temp(mdot: float) -> float:
        return (k * r * mdot * u.t_a + (k - 1.0) * hq) / (k * r * mdot + (k - 1.0) * hsum)

    def gap(p: float) -> float:
        mdot, _ = throttle_flow(alpha, p, u.p_a, u.t_a, params)
        return mdot - port_flow(p, temp(mdot), u.n_rpm, params)

    p_lo = 1.0
    if gap(p_lo) <= 0.0:  # throttle (nearly) shut: the residual-gas term balances at very low P
        p_lo = P_FLOOR_KPA
    p = brentq(gap, p_lo, u.p_a, xtol=1e-10, rtol=1e-12)
    mdot, _ = throttle_flow(alpha, p, u.p_a, u.t_a, params)
    return p, temp(mdot)


# ------------------------------------------------------------------------- augmented model

def f(
    x: np.ndarray, u: EngineInput, params: ManifoldParams = V8_5L7, dt: float | None = None,
) -> np.ndarray:
    """Noise-free eq. 10, one event: the manifold sees alpha_n (B_IM C_ET x_ET,n), the actuator
    moves by the corrected eq. 1, the IAT sensor follows T_im,n (eq. 9); dt defaults to T_s."""
    ts = sample_time(u.n_rpm, params.n_cyl) if dt is None else dt
    u_prev, alpha, alpha_prev, p, t, tm = (float(v) for v in x)
    co = event_coefficients(ts, params.zeta, params.omega0, params.tau_temp_s)
    p_n, t_n, _ = integrate_manifold(p, t, alpha, u, ts, params)
    alpha_n, tm_n = event_map(co, u_prev, alpha, alpha_prev, u.ta_sp, t, tm)
    return np.array([u.ta_sp, alpha_n, alpha, p_n, t_n, tm_n])


def h(x: np.ndarray) -> np.ndarray:
    """Outputs of eq. 10 without noise: y = (TA, P_im, T_im.meas) = (x[1], x[3], x[5])."""
    return np.array([x[1], x[3], x[5]])


def steady_state_vector(u: EngineInput, params: ManifoldParams = V8_5L7) -> np.ndarray:
    """Augmented state at rest with alpha = TA_SP: actuator, manifold and sensor in equilibrium."""
    p, t = steady_state(u.ta_sp, u, params)
    return np.array([u.ta_sp, u.ta_sp, u.ta_sp, p, t, t])
