"""One engine event of the manifold EKF and SDKF (Dutka 2006, eq. 10-14), written once as kernels:
`sdkf_event` (SDC matrix of eq. 7/10, one Riccati iteration of eq. 14 or the DARE's P, the update
of eq. 13, the mean through eq. 5-6), `ekf_event` (the same update, P = F P F^T + Q). Status
word: bits 0-2 the channels gated, DIVERGED, FALLBACK (S not positive definite: the caller
factors it with jitter, then `apply_gain` and `sdkf_finish` / `ekf_finish`).
"""

# ruff: noqa: FURB136 (x if c else y mirrors Python's min()/max(), NaN included)
from __future__ import annotations

import math
from typing import Any

import numpy as np

from vecu.estimators.common.small_linalg import chol3, inverse_from_chol3
from vecu.kernels import kernel
from vecu.models import manifold_integrator as mi
from vecu.models.manifold import efficiency_of, event_coefficients, event_map, throttle_flow_of

integrate_event = mi._integrate_event

# status word: bits 0-2 channel i gated
DIVERGED = 8
FALLBACK = 16

# filter constants vector (filter_constants)
(F_R0, F_R1, F_R2, F_GATE2, F_MAX_GATED, F_A_LO, F_A_HI, F_P_LO, F_P_HI, F_T_LO, F_T_HI,
 F_MAX_TRACE, F_MAX_ABS, F_ZETA, F_OMEGA0, F_TAU, F_VCYL, F_NCYL, F_ALPHA_MIN) = range(19)
N_FILTER_CONSTS = 19

ALPHA_SDC_MIN = 1e-3  # rad: B_IM divides by alpha (eq. 7); below this the flow term is ~0 anyway
# Finite-difference steps for the manifold block of F (relative for P and T).
FD_ALPHA = 1e-6  # rad
FD_REL = 1e-6

# input_fault's answers
INPUT_OK, INPUT_SPEED, INPUT_SETPOINT, INPUT_AMBIENT = range(4)


@kernel
def input_fault(sp, n_rpm, p_a, t_a, t_cool, n_lo, n_hi):
    """Which part of an event's input is implausible (NaN fails): INPUT_SPEED (N outside
    n_lo..n_hi rpm), INPUT_SETPOINT (TA_SP outside -0.2..1.9 rad), INPUT_AMBIENT (P_a outside
    50..120 kPa, T_a or T_coolant outside 200..450 K), else INPUT_OK."""
    if not n_lo <= n_rpm <= n_hi:
        return INPUT_SPEED
    if not -0.2 <= sp <= 1.9:
        return INPUT_SETPOINT
    if not (50.0 <= p_a <= 120.0 and 200.0 <= t_a <= 450.0 and 200.0 <= t_cool <= 450.0):
        return INPUT_AMBIENT
    return INPUT_OK


@kernel
def coefficients(ts, fc):
    """(a1, a2, b1, b2, a_T, b_T) of eq. 1 and 9 for one event with the calibration's actuator
    and IAT sensor (fc)."""
    return event_coefficients(ts, fc[F_ZETA], fc[F_OMEGA0], fc[F_TAU])


@kernel
def in_bounds(x, P, max_trace, max_abs):
    """not covariance.diverged_floats(x, trace P, sum P): finite, 0 <= trace <= max_trace,
    |x_i| <= max_abs."""
    tr = 0.0
    tot = 0.0
    nx = x.shape[0]
    for i in range(nx):
        tr += P[i, i]
        for j in range(nx):
            tot += P[i, j]
    if not 0.0 <= tr <= max_trace:
        return False
    for i in range(nx):
        if not -max_abs <= x[i] <= max_abs:
            return False
    return tot - tot == 0.0


@kernel
def clamp(x, fc):
    """The state box on the first six states: alpha_box (actuator), p_box, t_box (both T)."""
    for i in range(6):
        lo, hi = (fc[F_A_LO], fc[F_A_HI]) if i < 3 else (
            (fc[F_P_LO], fc[F_P_HI]) if i == 3 else (fc[F_T_LO], fc[F_T_HI]))
        v = x[i]
        v = lo if lo > v else v
        x[i] = hi if hi < v else v


@kernel
def sdc_matrix(A, x, n_rpm, p_a, t_a, t_cool, ts, co, alpha_min, c, cd_alpha, cd_table, prs,
               eta_rpm, eta_val):
    """A(x) of eq. 10 into A (zeros on entry) with the paper's SDC factorisation (eq. 7):
    A_IM = [[1 - pi, (kappa-1) T_s Q_ext / (T_im V_im)],
            [0, 1 - (kappa-1)/kappa pi + (kappa-1) T_s Q_ext / (V_im P_im)]],
    B_IM = T_s mdot_at / alpha * [kappa R T_a / V_im, T_im (kappa R T_a - R T_im) / (V_im P_im)],
    pi = kappa eta N V_d T_s / (120 V_im); B_IM C_ET in the alpha column, alpha >= alpha_min in
    the division; the actuator rows of eq. 1 (co: coefficients) and the IAT rows of eq. 9."""
    a1, a2, _, b2, a_t, b_t = co
    k, r, v = c[0], c[1], c[2]
    alpha, p, t = x[1], x[3], x[4]
    eta, _ = efficiency_of(n_rpm, p, c, eta_rpm, eta_val)
    mdot, _ = throttle_flow_of(alpha, p, p_a, t_a, c, cd_alpha, cd_table, prs)
    q = c[16] * (t_cool - t) + c[17] * (t_a - t)  # Q_ext (models.manifold.heat_flow)
    ps = 1e-3 if 1e-3 > p else p
    tsx = 1.0 if 1.0 > t else t
    pump = k * eta * n_rpm * c[28] * ts / (120.0 * v)
    flow = ts * mdot / (alpha_min if alpha_min > alpha else alpha)
    A[1, 0], A[1, 1], A[1, 2] = b2, a1, a2
    A[2, 1] = 1.0
    A[3, 1] = k * r * t_a * flow / v
    A[4, 1] = tsx * (k * r * t_a - r * tsx) * flow / (v * ps)
    A[3, 3] = 1.0 - pump
    A[3, 4] = (k - 1.0) * ts * q / (tsx * v)
    A[4, 4] = 1.0 - (k - 1.0) / k * pump + (k - 1.0) * ts * q / (v * ps)
    A[5, 4], A[5, 5] = b_t, a_t


@kernel
def gate(x, Pn, yv, runs, chans, fc):
    """Per-channel innovation gate: (channels gated as bits, the channels used, how many). A
    channel i of chans (bit i) is gated when e^2 > gate_sigma^2 (P_jj + R_i) and it was gated
    fewer than max_gated_in_row times in a row (runs[i])."""
    rd = (fc[F_R0], fc[F_R1], fc[F_R2])
    gated = 0
    nc = 0
    ch = np.zeros(3, dtype=np.int64)
    for i in range(3):
        if chans >> i & 1:
            j = 2 * i + 1  # Y_INDEX
            e = yv[i] - x[j]
            s = Pn[j, j] + rd[i]
            if e * e > fc[F_GATE2] * s and runs[i] < fc[F_MAX_GATED]:
                gated |= 1 << i
            else:
                ch[nc] = i
                nc += 1
    return gated, ch, nc


@kernel
def innovation_inverse(Pn, ch, nc, fc):
    """(ok, S^-1) of S = C P C^T + R over the nc channels ch: all three by the unrolled 3x3
    Cholesky (common.small_linalg), fewer by LAPACK's; ok False when S is not finite or not
    positive definite (the caller then factors it with jitter)."""
    rd = (fc[F_R0], fc[F_R1], fc[F_R2])
    if nc == 3:
        s00 = Pn[1, 1] + rd[0]
        s10 = Pn[3, 1] + 0.0
        s11 = Pn[3, 3] + rd[1]
        s20 = Pn[5, 1] + 0.0
        s21 = Pn[5, 3] + 0.0
        s22 = Pn[5, 5] + rd[2]
        if not math.isfinite(s00 + s10 + s11 + s20 + s21 + s22):
            return False, np.empty((3, 3))
        ok, low = chol3((s00, s10, s20, s11, s21, s22))
        if not ok:
            return False, np.empty((3, 3))
        i00, i01, i02, i11, i12, i22 = inverse_from_chol3(low)
        return True, np.array([[i00, i01, i02], [i01, i11, i12], [i02, i12, i22]])
    S = np.empty((nc, nc))
    for a_ in range(nc):
        for b_ in range(nc):
            S[a_, b_] = Pn[2 * ch[a_] + 1, 2 * ch[b_] + 1] + (rd[ch[a_]] if a_ == b_ else 0.0)
            if not math.isfinite(S[a_, b_]):
                return False, np.empty((nc, nc))
    try:
        L = np.linalg.cholesky(S)
    except Exception:  # noqa: BLE001 (numba: LinAlgError; the jitter fallback is the caller's)
        return False, np.empty((nc, nc))
    Li = np.linalg.solve(L, np.eye(nc))  # as numpy's inv: gesv with the identity
    return True, Li.T @ Li


@kernel
def apply_gain(x, Pn, xp, Pp, yv, ch, nc, Si):
    """Eq. 13's update of the prior (x, Pn) into (xp, Pp) over the nc channels ch (C a row
    selection, Y_INDEX = 1, 3, 5): K = P C^T S^-1, x + K (y - C x), sym(P - K C P)."""
    nx = x.shape[0]
    PCt = np.empty((nx, nc))
    for i in range(nx):
        for m in range(nc):
            PCt[i, m] = Pn[i, 2 * ch[m] + 1]
    e = np.empty(nc)
    for m in range(nc):
        e[m] = yv[ch[m]] - x[2 * ch[m] + 1]
    K = PCt @ Si
    xp[:] = x + K @ e
    X = Pn - K @ PCt.T
    Pp[:, :] = 0.5 * (X + X.T)


@kernel
def update(x, Pn, xp, Pp, yv, runs, chans, fc):
    """Gating and the update of the channels used (prior (x, Pn) -> (xp, Pp)). Returns the
    channels gated, | FALLBACK when S has to be factored with jitter (xp, Pp not written)."""
    gated, ch, nc = gate(x, Pn, yv, runs, chans, fc)
    if nc == 0:
        xp[:] = x
        Pp[:, :] = Pn
        return gated
    ok, Si = innovation_inverse(Pn, ch, nc, fc)
    if not ok:
        return gated | FALLBACK
    apply_gain(x, Pn, xp, Pp, yv, ch, nc, Si)
    return gated


@kernel
def jacobian(F, xp, p_n, t_n, m, co, fd, fd_c, ncol, p_a, t_a, t_cool, n_rpm, ts, c,
             cd_alpha, cdt, prs, eta_rpm, ev, cd_table, eta_val):
    """F = df/dx at the posterior xp into F (zeros on entry): the analytic rows of eq. 1 and 9,
    identity rows for parameter states beyond the sixth, and one-sided differences of the event
    integrator (p_n, t_n, m its output at xp; steps fd = (FD_ALPHA, FD_REL), flipped when the
    sub-step count would change, so no difference straddles a switch) for the columns alpha,
    P, T and, with ncol = 5 (the adaptive filter), c and c_th: the eta_N and C_d tables scaled
    by xp[6], xp[7] (ev, cdt: the scaled tables; fd_c the step in c)."""
    a1, a2, _, b2, a_t, b_t = co
    F[1, 0], F[1, 1], F[1, 2] = b2, a1, a2
    F[2, 1] = 1.0
    F[5, 4], F[5, 5] = b_t, a_t
    for i in range(6, xp.shape[0]):
        F[i, i] = 1.0
    alpha, p, t = float(xp[1]), float(xp[3]), float(xp[4])  # plain floats in Python
    steps = (fd[0], fd[1] * (abs(p) if abs(p) > 1.0 else 1.0),
             fd[1] * (abs(t) if abs(t) > 1.0 else 1.0), fd_c, fd_c)
    for j in range(ncol):
        col = 1 if j == 0 else (j + 2 if j < 3 else j + 3)
        d = steps[j]
        sign = 1.0
        pp = tt = 0.0
        for s in range(2):
            sign = 1.0 if s == 0 else -1.0
            a_ = alpha + sign * d if j == 0 else alpha
            p_ = p + sign * d if j == 1 else p
            t_ = t + sign * d if j == 2 else t
            e_ = eta_val * (xp[6] + sign * d) if j == 3 else ev
            c_ = cd_table * (xp[7] + sign * d) if j == 4 else cdt
            pp, tt, mm = integrate_event(p_, t_, a_, p_a, t_a, t_cool, n_rpm, ts, c, cd_alpha,
                                         c_, prs, eta_rpm, e_)
            if mm == m:
                break
        F[3, col] = (pp - p_n) / (sign * d)
        F[4, col] = (tt - t_n) / (sign * d)


@kernel
def map_out(xo, xp, sp, p_n, t_n, co, fc):
    """xo[2] = the event map of eq. 10 from the posterior xp (eq. 1 with the coefficients co,
    the integrator's P_n, T_n, eq. 9; parameter states beyond the sixth held), xo[0] = it
    clamped (the next prior)."""
    u_prev, alpha, alpha_prev, t, tm = xp[0], xp[1], xp[2], xp[4], xp[5]
    alpha_n, tm_n = event_map(co, u_prev, alpha, alpha_prev, sp, t, tm)
    xf = xo[2]
    xf[0], xf[1], xf[2] = sp, alpha_n, alpha
    xf[3], xf[4], xf[5] = p_n, t_n, tm_n
    n = xp.shape[0]
    for i in range(6, n):
        xf[i] = xp[i]
    xn = xo[0]
    for i in range(n):
        xn[i] = xf[i]
    clamp(xn, fc)


@kernel
def propagate(F, Pp, Q, xo, Po, fc):
    """EKF covariance prediction Po[0] = sym(F Pp F^T + Q); False when the new prior (xo[0],
    Po[0]) is out of bounds (covariance.diverged)."""
    X = F @ Pp @ F.T + Q
    Pn = Po[0]
    Pn[:, :] = 0.5 * (X + X.T)
    return in_bounds(xo[0], Pn, fc[F_MAX_TRACE], fc[F_MAX_ABS])


@kernel
def sdkf_finish(xo, Po, sp, n_rpm, p_a, t_a, t_cool, ts, gated, fc, c, cd_alpha, cd_table, prs,
                eta_rpm, eta_val):
    """The SDKF event after its update (posterior xo[1], Po[1]; prior covariance Po[0]):
    clamping, the divergence checks and the mean through the event map. Returns the status."""
    xp = xo[1]
    clamp(xp, fc)
    if not in_bounds(xp, Po[1], fc[F_MAX_TRACE], fc[F_MAX_ABS]):
        return gated | DIVERGED
    p_n, t_n, _ = integrate_event(float(xp[3]), float(xp[4]), float(xp[1]), p_a, t_a, t_cool,
                                  n_rpm, ts, c, cd_alpha, cd_table, prs, eta_rpm,
                                  eta_val)
    map_out(xo, xp, sp, p_n, t_n, coefficients(ts, fc), fc)
    if not in_bounds(xo[0], Po[0], fc[F_MAX_TRACE], fc[F_MAX_ABS]):
        return gated | DIVERGED
    return gated


@kernel
def sdkf_event(x, P, P_post, xo, Po, sp, n_rpm, p_a, t_a, t_cool, ts, y0, y1, y2, chans,
               run0, run1, run2, iterate, fc, Q, c, cd_alpha, cd_table, prs, eta_rpm, eta_val):
    """One ManifoldSDKF event from the prior (x, P; P_post the last posterior), channels chans
    (bits), readings y_i, gated runs run_i: xo = (next prior clamped, posterior, event-map output),
    Po = (prior P_n|n-1, posterior); returns the status word."""
    Pn = Po[0]
    if iterate:  # one Riccati iteration of eq. 14: P = sym(A P_post A^T + Q)
        A = np.zeros((6, 6))
        sdc_matrix(A, x, n_rpm, p_a, t_a, t_cool, ts, coefficients(ts, fc), fc[F_ALPHA_MIN], c,
                   cd_alpha, cd_table, prs, eta_rpm, eta_val)
        X = A @ P_post @ A.T + Q
        Pn[:, :] = 0.5 * (X + X.T)
    else:
        Pn[:, :] = P
    gated = update(x, Pn, xo[1], Po[1], (y0, y1, y2), (run0, run1, run2), chans, fc)
    if gated & FALLBACK:
        return gated
    return sdkf_finish(xo, Po, sp, n_rpm, p_a, t_a, t_cool, ts, gated, fc, c, cd_alpha,
                       cd_table, prs, eta_rpm, eta_val)


@kernel
def ekf_finish(xo, Po, sp, n_rpm, p_a, t_a, t_cool, ts, gated, fc, Q, fd, c, cd_alpha, cd_table,
               prs, eta_rpm, eta_val):
    """The EKF event after its update (posterior xo[1], Po[1]): clamping, the divergence check,
    the event map and F = df/dx at x_n|n, P = sym(F P F^T + Q) into Po[0]. Returns the status."""
    xp = xo[1]
    Pp = Po[1]
    clamp(xp, fc)
    if not in_bounds(xp, Pp, fc[F_MAX_TRACE], fc[F_MAX_ABS]):
        return gated | DIVERGED
    co = coefficients(ts, fc)
    p_n, t_n, m = integrate_event(float(xp[3]), float(xp[4]), float(xp[1]), p_a, t_a, t_cool,
                                  n_rpm, ts, c, cd_alpha, cd_table, prs, eta_rpm, eta_val)
    F = np.zeros((6, 6))
    jacobian(F, xp, p_n, t_n, m, co, fd, 0.0, 3, p_a, t_a, t_cool, n_rpm, ts, c, cd_alpha,
             cd_table, prs, eta_rpm, eta_val, cd_table, eta_val)
    map_out(xo, xp, sp, p_n, t_n, co, fc)
    if not propagate(F, Pp, Q, xo, Po, fc):
        return gated | DIVERGED
    return gated


@kernel
def ekf_event(x, P, xo, Po, sp, n_rpm, p_a, t_a, t_cool, ts, y0, y1, y2, chans, run0, run1,
              run2, fc, Q, fd, c, cd_alpha, cd_table, prs, eta_rpm, eta_val):
    """One ManifoldEKF event (arguments and outputs as sdkf_event, Po[0] the new prior P_n+1|n):
    the update, then ekf_finish."""
    gated = update(x, P, xo[1], Po[1], (y0, y1, y2), (run0, run1, run2), chans, fc)
    if gated & FALLBACK:
        return gated
    return ekf_finish(xo, Po, sp, n_rpm, p_a, t_a, t_cool, ts, gated, fc, Q, fd, c, cd_alpha,
                      cd_table, prs, eta_rpm, eta_val)


def filter_constants(config: Any, alpha_sdc_min: float = ALPHA_SDC_MIN) -> np.ndarray:
    """Constants of the event kernels from a ManifoldFilterConfig (layout: the F_* indices)."""
    prm = config.params
    r = config.noise.r_diag()
    b = config.bounds
    return np.array([
        r[0], r[1], r[2], config.gate_sigma * config.gate_sigma, float(config.max_gated_in_row),
        *config.alpha_box, *config.p_box, *config.t_box, b.max_trace, b.max_abs_state,
        prm.zeta, prm.omega0, prm.tau_temp_s, prm.v_cyl_dm3, float(prm.n_cyl), alpha_sdc_min,
    ], dtype=np.float64)


def model_constants(prm: Any) -> np.ndarray:
    """The constants the model pieces read (actuator, IAT, V_cyl, n_cyl, ALPHA_SDC_MIN) for a
    parameter set, in the filter constants' layout."""
    out = np.zeros(N_FILTER_CONSTS)
    out[F_ZETA], out[F_OMEGA0], out[F_TAU] = prm.zeta, prm.omega0, prm.tau_temp_s
    out[F_VCYL], out[F_NCYL], out[F_ALPHA_MIN] = prm.v_cyl_dm3, float(prm.n_cyl), ALPHA_SDC_MIN
    return out


def signature_types() -> tuple[Any, Any, Any, Any, Any, tuple]:
    """numba's (types, float64, int64, contiguous vector, contiguous matrix, the integrator's
    tables: c, cd_alpha, cd_table, prs, eta_rpm, eta_val) for the kernels' one signatures."""
    from numba import types

    f8, i8 = types.float64, types.int64
    v, m = f8[::1], f8[:, ::1]
    return types, f8, i8, v, m, (types.UniTuple(f8, mi.N_CONSTS), v, m, v, v, v)


def _sdkf_signature() -> tuple:
    types, f8, i8, v, m, tables = signature_types()
    return ((v, m, m, m, f8[:, :, ::1]) + (f8,) * 9 + (i8,) * 4 + (types.boolean, v, m)
            + tables)


def _ekf_signature() -> tuple:
    _, f8, i8, v, m, tables = signature_types()
    return (v, m, m, f8[:, :, ::1]) + (f8,) * 9 + (i8,) * 4 + (v, m, v) + tables


sdkf_event.fix_signature(_sdkf_signature)
ekf_event.fix_signature(_ekf_signature)
