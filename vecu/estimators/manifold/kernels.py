"""Compiled manifold SDKF event and CAC prediction (numba backend only).

`sdkf_event` is one whole event of ManifoldSDKF with riccati="iterate"
(vecu/estimators/manifold_filters.py) after the Python-side input checks: the SDC matrix A(x_n|n-1)
(manifold_model.sdc_matrices), one Riccati iteration P = A P_post A^T + Q, gating and the
measurement update of the valid channels, clamping, both divergence checks and the prediction
through the event map (manifold_model.f, with the plant's integrator kernel
vecu.models.manifold_integrator._integrate_event called from inside). It returns a status word
that Python turns into counter increments, a reset, or (rare: S not positive definite or not
finite) a re-run of the event on the Python path, which then decides exactly as it always did.
`predict_events` is cac_predict.predict_state / predict_cac in one call.

The scalar model arithmetic (SDC entries, event map, integrator, air charge) is the Python
code's operation by operation; the matrix products are the same expressions (numba calls BLAS
and LAPACK through scipy, numpy through its own copy of OpenBLAS), so on a machine where both
are the same OpenBLAS build the results are bit-identical (tests/estimators/manifold/test_kernels.py asserts
== and reports the difference if a BLAS build ever rounds otherwise).

The Python backend never runs these functions (the numpy code stays the reference); they are
plain Python all the same. Caveat (numba's cache): the compiled integrator is linked into these
kernels' cache entries, and numba does not notice when manifold_integrator.py changes;
`prepare` checks the linked integrator against the stand-alone one on first use and rebuilds
both kernels from source when they differ.
"""

# ruff: noqa: FURB136 (x if c else y mirrors Python's min()/max(), NaN included)
from __future__ import annotations

import math
from typing import Any

import numpy as np

from vecu.estimators.common.small_linalg import chol3, inverse_from_chol3
from vecu.kernels import kernel, rebuild_if_stale
from vecu.models import manifold_integrator as mi
from vecu.models.manifold_kernels import eta_value, interp_value, throttle_flow_value

# status word of sdkf_event: bits 0-2 channel i gated
DIVERGED = 8
FALLBACK = 16

# filter constants vector (filter_constants)
(F_R0, F_R1, F_R2, F_GATE2, F_MAX_GATED, F_A_LO, F_A_HI, F_P_LO, F_P_HI, F_T_LO, F_T_HI,
 F_MAX_TRACE, F_MAX_ABS, F_ZETA, F_OMEGA0, F_TAU, F_VCYL, F_NCYL, F_ALPHA_MIN) = range(19)
N_FILTER_CONSTS = 19

_ready = False


# ----------------------------------------------------------------------------- helpers
# Plain functions; prepare() rebinds these names to numba-compiled versions before the kernels
# compile, so numba inlines them (globals are resolved at compile time).

_interp_py = interp_value.py
_eta_py = eta_value.py
_mdot_py = throttle_flow_value.py


def _in_bounds_py(x, P, max_trace, max_abs):
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


def _clamp_py(x, fc):
    """_ManifoldKF._clamp (min(max(v, lo), hi) with Python's NaN behaviour)."""
    for i in range(6):
        lo, hi = (fc[F_A_LO], fc[F_A_HI]) if i < 3 else (
            (fc[F_P_LO], fc[F_P_HI]) if i == 3 else (fc[F_T_LO], fc[F_T_HI]))
        v = x[i]
        v = lo if lo > v else v
        x[i] = hi if hi < v else v


def _update_py(x, Pn, xp, Pp, yv, runs, chans, fc):
    """_ManifoldKF._update on the prior (x, Pn) into (xp, Pp): per-channel gating, then the
    update of the channels used (_gain_all for three, the general path otherwise). Returns the
    channels gated (bits 0-2), or FALLBACK (S not finite or not positive definite)."""
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
    if nc == 0:
        xp[:] = x
        Pp[:, :] = Pn
    else:
        nx = x.shape[0]
        PCt = np.empty((nx, nc))  # P C^T over the channels used
        for i in range(nx):
            for m in range(nc):
                PCt[i, m] = Pn[i, 2 * ch[m] + 1]
        e = np.empty(nc)
        for m in range(nc):
            e[m] = yv[ch[m]] - x[2 * ch[m] + 1]
        if nc == 3:  # _gain_all: unrolled 3x3 Cholesky, S^-1 = M^T M (common.small_linalg)
            s00 = Pn[1, 1] + rd[0]
            s10 = Pn[3, 1] + 0.0
            s11 = Pn[3, 3] + rd[1]
            s20 = Pn[5, 1] + 0.0
            s21 = Pn[5, 3] + 0.0
            s22 = Pn[5, 5] + rd[2]
            if not math.isfinite(s00 + s10 + s11 + s20 + s21 + s22):
                return FALLBACK
            ok, low = chol3((s00, s10, s20, s11, s21, s22))
            if not ok:
                return FALLBACK
            i00, i01, i02, i11, i12, i22 = inverse_from_chol3(low)
            Si = np.array([[i00, i01, i02], [i01, i11, i12], [i02, i12, i22]])
            K = PCt @ Si
            xp[:] = x + K @ e
            X = Pn - K @ PCt.T
            Pp[:, :] = 0.5 * (X + X.T)
        else:  # the general path: cholesky_lower's first try, inv, S^-1 = L^-T L^-1
            S = np.empty((nc, nc))
            for a_ in range(nc):
                for b_ in range(nc):
                    S[a_, b_] = PCt[2 * ch[a_] + 1, b_] + (rd[ch[a_]] if a_ == b_ else 0.0)
                    if not math.isfinite(S[a_, b_]):
                        return FALLBACK
            try:
                L = np.linalg.cholesky(S)
            except Exception:  # noqa: BLE001 (numba: LinAlgError; the jitter fallbacks in Python)
                return FALLBACK
            Li = np.linalg.solve(L, np.eye(nc))  # as numpy's inv: gesv with the identity
            K = PCt @ (Li.T @ Li)
            xp[:] = x + K @ e
            X = Pn - K @ PCt.T
            Pp[:, :] = 0.5 * (X + X.T)
    return gated


def _jacobian_py(F, xp, p_n, t_n, m, co, fd, fd_c, ncol, p_a, t_a, t_cool, n_rpm, ts, cst,
                 cd_alpha, cdt, prs, eta_rpm, ev, cd_table, eta_val):
    """F = df/dx at the posterior xp into F (zeros on entry): manifold_model.f_and_jacobian's
    analytic actuator/IAT rows, identity rows for parameter states beyond the sixth, and
    one-sided differences of the event integrator (p_n, t_n, m its output at xp; steps fd =
    (FD_ALPHA, FD_REL), flipped when the sub-step count would change) for the columns alpha, P,
    T and, with ncol = 5 (the adaptive filter), c and c_th: the eta_N and C_d tables scaled by
    xp[6], xp[7] (ev, cdt: the scaled tables; fd_c the step in c)."""
    a1, a2, _, b2, a_t, b_t = co
    F[1, 0], F[1, 1], F[1, 2] = b2, a1, a2
    F[2, 1] = 1.0
    F[5, 4], F[5, 5] = b_t, a_t
    for i in range(6, xp.shape[0]):
        F[i, i] = 1.0
    alpha, p, t = xp[1], xp[3], xp[4]
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
            pp, tt, mm = _integrate(p_, t_, a_, p_a, t_a, t_cool, n_rpm, ts, cst, cd_alpha, c_,
                                    prs, eta_rpm, e_)
            if mm == m:
                break
        F[3, col] = (pp - p_n) / (sign * d)
        F[4, col] = (tt - t_n) / (sign * d)


def _map_out_py(xo, xp, sp, p_n, t_n, co, fc):
    """xo[2] = the event map's output from the posterior xp (eq. 1 with the coefficients co,
    the integrator's P_n, T_n, eq. 9; parameter states beyond the sixth held), xo[0] = it
    clamped (the next prior)."""
    a1, a2, b1, b2, a_t, b_t = co
    u_prev, alpha, alpha_prev, t, tm = xp[0], xp[1], xp[2], xp[4], xp[5]
    xf = xo[2]
    xf[0], xf[1], xf[2] = sp, a1 * alpha + a2 * alpha_prev + b1 * sp + b2 * u_prev, alpha
    xf[3], xf[4], xf[5] = p_n, t_n, a_t * tm + b_t * t
    n = xp.shape[0]
    for i in range(6, n):
        xf[i] = xp[i]
    xn = xo[0]
    for i in range(n):
        xn[i] = xf[i]
    _clamp(xn, fc)


def _propagate_py(F, Pp, Q, xo, Po, fc):
    """EKF covariance prediction Po[0] = sym(F Pp F^T + Q); False when the new prior (xo[0],
    Po[0]) is out of bounds (covariance.diverged)."""
    X = F @ Pp @ F.T + Q
    Pn = Po[0]
    Pn[:, :] = 0.5 * (X + X.T)
    return _in_bounds(xo[0], Pn, fc[F_MAX_TRACE], fc[F_MAX_ABS])


def _coeffs_py(ts, zeta, omega0, tau):
    """(a1, a2, b1, b2, a_t, b_t) of one event of length ts for the actuator (zeta, omega0)
    and the IAT sensor (tau): plant.manifold.actuator_coeffs and iat_coeffs, the same
    operations in the same order."""
    zw = zeta * omega0
    w_et = omega0 * math.sqrt(1.0 - zeta * zeta)
    a = math.exp(-zw * ts)
    b = math.cos(w_et * ts)
    g = math.sin(w_et * ts)
    a_t = math.exp(-ts / tau)
    return (2.0 * a * b, -a * a, 1.0 - a * (b + zw * g / w_et), a * a + a * (zw * g / w_et - b),
            a_t, 1.0 - a_t)


def _event_coeffs_py(ts, fc):
    """_coeffs with the calibration's actuator and IAT sensor (fc)."""
    return _coeffs(ts, fc[F_ZETA], fc[F_OMEGA0], fc[F_TAU])


def _air_charge_py(n_rpm, p, t, fc, c, eta_rpm, eta_val):
    """Cylinder air charge (kg) at (P_im, T_im) and speed n_rpm: models.manifold.
    cylinder_air_charge, the same operations (eta P V_cyl / (R T))."""
    return _eta(n_rpm, p, c, eta_rpm, eta_val) * p * fc[F_VCYL] / (c[1] * t)


def _const_tuple_py(c):
    """The integrator's 29 per-parameter-set constants as the tuple it takes."""
    return (c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8], c[9], c[10], c[11], c[12],
            c[13], c[14], c[15], c[16], c[17], c[18], c[19], c[20], c[21], c[22], c[23], c[24],
            c[25], c[26], c[27], c[28])


_coeffs = _coeffs_py
_event_coeffs = _event_coeffs_py
_const_tuple = _const_tuple_py
_air_charge = _air_charge_py
_interp = _interp_py
_eta = _eta_py
_mdot = _mdot_py
_in_bounds = _in_bounds_py
_clamp = _clamp_py
_update = _update_py
_jacobian = _jacobian_py
_map_out = _map_out_py
_propagate = _propagate_py
_integrate = mi._integrate_event.py
P_FLOOR_KPA = mi.P_FLOOR_KPA


def _jit_helpers() -> None:
    global _interp, _eta, _mdot, _in_bounds, _clamp, _integrate, _coeffs, _event_coeffs
    global _const_tuple, _air_charge
    global _update, _jacobian, _map_out, _propagate
    import numba

    _coeffs = numba.njit(_coeffs_py)
    _event_coeffs = numba.njit(_event_coeffs_py)
    _const_tuple = numba.njit(_const_tuple_py)
    _air_charge = numba.njit(_air_charge_py)
    _interp = interp_value.compiled
    _eta = eta_value.compiled
    _mdot = throttle_flow_value.compiled
    _in_bounds = numba.njit(_in_bounds_py)
    _clamp = numba.njit(_clamp_py)
    _update = numba.njit(_update_py)
    _jacobian = numba.njit(_jacobian_py)
    _map_out = numba.njit(_map_out_py)
    _propagate = numba.njit(_propagate_py)
    _integrate = mi._integrate_event.compiled


def filter_constants(config: Any, alpha_sdc_min: float) -> np.ndarray:
    """Constants of sdkf_event from a ManifoldFilterConfig (layout: the F_* indices)."""
    prm = config.params
    r = config.noise.r_diag()
    b = config.bounds
    return np.array([
        r[0], r[1], r[2], config.gate_sigma * config.gate_sigma, float(config.max_gated_in_row),
        *config.alpha_box, *config.p_box, *config.t_box, b.max_trace, b.max_abs_state,
        prm.zeta, prm.omega0, prm.tau_temp_s, prm.v_cyl_dm3, float(prm.n_cyl), alpha_sdc_min,
    ], dtype=np.float64)


def model_constants(prm: Any) -> np.ndarray:
    """The constants predict_events reads (actuator, IAT, V_cyl, n_cyl) for a parameter set."""
    out = np.zeros(N_FILTER_CONSTS)
    out[F_ZETA], out[F_OMEGA0], out[F_TAU] = prm.zeta, prm.omega0, prm.tau_temp_s
    out[F_VCYL], out[F_NCYL] = prm.v_cyl_dm3, float(prm.n_cyl)
    return out


def prepare() -> None:
    """Before the first numba call (idempotent): the integrator's search overload and signature,
    the helpers, each kernel's one signature (compiled or loaded from numba's cache; further
    compilation off, so int or numpy-scalar arguments convert to float64), then the check that
    the integrator linked into the cached kernels is the current one (see module)."""
    global _ready
    if _ready:
        return
    if not mi._numba_sig_ready:
        mi._prepare_numba()
    _jit_helpers()
    _compile_signatures()
    rebuild_if_stale((sdkf_event, predict_events, ekf_event), _linked_integrator_is_current,
                     _compile_signatures, "manifold filter kernels")
    _ready = True


def signature_types() -> tuple[Any, Any, Any, Any, Any, tuple]:
    """numba's (types, float64, int64, contiguous vector, contiguous matrix, the integrator's
    tables: c, cd_alpha, cd_table, prs, eta_rpm, eta_val) for the kernels' one signatures."""
    from numba import types

    f8, i8 = types.float64, types.int64
    v, m = f8[::1], f8[:, ::1]
    return types, f8, i8, v, m, (v, v, m, v, v, v)


def _compile_signatures() -> None:
    types, f8, i8, v, m, tables = signature_types()
    for k, sig in (
        (sdkf_event, (v, m, m, m, f8[:, :, ::1]) + (f8,) * 9 + (i8,) * 4
         + (types.boolean, v, m) + tables),
        (predict_events, (v, m, i8, v, v) + tables),
        (ekf_event, (v, m, m, f8[:, :, ::1]) + (f8,) * 9 + (i8,) * 4 + (v, m, v) + tables),
    ):
        k.fix_signature(sig)


def numba_tables(params: Any) -> tuple | None:
    """(constants array, C_d alpha, C_d table, C_d pr, eta_N rpm, eta_N values) as float64
    arrays for the kernels, or None when the parameter set runs on the Python path only."""
    nb = mi._tables(params)[2]
    if nb is None:
        return None
    return (np.array(nb[0], dtype=np.float64), *nb[1:])


def _linked_integrator_is_current() -> bool:
    from vecu.models.manifold_params import V8_5L7

    tabs = mi._tables(V8_5L7)[2]
    fc = model_constants(V8_5L7)
    out = np.empty(6)
    x = np.array([0.31, 0.3, 0.29, 61.0, 321.0, 318.0])
    u = np.array([[0.35, 2345.0, 99.0, 297.0, 361.0]])
    predict_events.compiled(x, u, 1, out, fc, np.array(tabs[0]), *tabs[1:])
    ts = 120.0 / (8.0 * 2345.0)
    ref = mi._integrate_event.compiled(61.0, 321.0, 0.3, 99.0, 297.0, 361.0, 2345.0, ts,
                                       tabs[0], *tabs[1:])
    return (float(out[3]), float(out[4])) == (ref[0], ref[1])


@kernel
def predict_events(x, u, count, out, fc, c, cd_alpha, cd_table, prs, eta_rpm, eta_val):
    """x after `count` events through the event map (cac_predict.predict_state) into out;
    returns the CAC (kg) there at the last input's speed (predict_cac). u: rows (TA_SP, N, P_a,
    T_a, T_cool); event i uses row min(i, len(u) - 1) (one row: input held)."""
    cst = _const_tuple(c)
    u_prev, alpha, alpha_prev, p, t, tm = x[0], x[1], x[2], x[3], x[4], x[5]
    ts_prev = math.nan
    a1 = a2 = b1 = b2 = a_t = b_t = 0.0
    n_rpm = 0.0
    last = u.shape[0] - 1
    for i in range(count):
        r = i if i < last else last
        sp, n_rpm, p_a, t_a, t_cool = u[r, 0], u[r, 1], u[r, 2], u[r, 3], u[r, 4]
        ts = 120.0 / (fc[F_NCYL] * n_rpm)
        if ts != ts_prev:
            a1, a2, b1, b2, a_t, b_t = _event_coeffs(ts, fc)
            ts_prev = ts
        p_n, t_n, _ = _integrate(p, t, alpha, p_a, t_a, t_cool, n_rpm, ts, cst, cd_alpha,
                                 cd_table, prs, eta_rpm, eta_val)
        u_prev, alpha, alpha_prev, p, t, tm = (
            sp, a1 * alpha + a2 * alpha_prev + b1 * sp + b2 * u_prev, alpha, p_n, t_n,
            a_t * tm + b_t * t)
    out[0], out[1], out[2], out[3], out[4], out[5] = u_prev, alpha, alpha_prev, p, t, tm
    return _air_charge(n_rpm, p, t, fc, c, eta_rpm, eta_val)




@kernel
def sdkf_event(x, P, P_post, xo, Po, sp, n_rpm, p_a, t_a, t_cool, ts, y0, y1, y2, chans,
               run0, run1, run2, iterate, fc, Q, c, cd_alpha, cd_table, prs, eta_rpm, eta_val):
    """One ManifoldSDKF "iterate" event from the prior (x, P; P_post the previous posterior) with
    the checked input and the valid channels (bit i of chans; y_i their values, run_i their
    gated-in-a-row counts). Writes xo = (prior x_n+1|n clamped, posterior x_n|n, event-map output
    before clamping) and Po = (prior P_n|n-1, posterior P_n|n). Returns the channels gated (bits
    0-2) | DIVERGED (reset the filter) | FALLBACK (run the event on the Python path instead)."""
    cst = _const_tuple(c)
    # --- event coefficients (actuator_coeffs, iat_coeffs) and A(x_n|n-1) (sdc_matrices)
    a1, a2, b1, b2, a_t, b_t = _event_coeffs(ts, fc)
    k, r, v = c[0], c[1], c[2]
    alpha, p, t = x[1], x[3], x[4]
    eta = _eta(n_rpm, p, c, eta_rpm, eta_val)
    mdot = _mdot(alpha, p, p_a, t_a, c, cd_alpha, cd_table, prs)
    q = c[16] * (t_cool - t) + c[17] * (t_a - t)
    ps = 1e-3 if 1e-3 > p else p
    tsx = 1.0 if 1.0 > t else t
    pump = k * eta * n_rpm * c[28] * ts / (120.0 * v)
    amin = fc[F_ALPHA_MIN]
    flow = ts * mdot / (amin if amin > alpha else alpha)
    A = np.zeros((6, 6))
    A[1, 0], A[1, 1], A[1, 2] = b2, a1, a2
    A[2, 1] = 1.0
    A[3, 1] = k * r * t_a * flow / v
    A[4, 1] = tsx * (k * r * t_a - r * tsx) * flow / (v * ps)
    A[3, 3] = 1.0 - pump
    A[3, 4] = (k - 1.0) * ts * q / (tsx * v)
    A[4, 4] = 1.0 - (k - 1.0) / k * pump + (k - 1.0) * ts * q / (v * ps)
    A[5, 4], A[5, 5] = b_t, a_t
    # --- prior covariance: one Riccati iteration P = sym(A P_post A^T + Q)
    Pn = Po[0]
    if iterate:
        X = A @ P_post @ A.T + Q
        Pn[:, :] = 0.5 * (X + X.T)
    else:
        Pn[:, :] = P
    # --- gating (per channel) and the measurement update of the channels used
    xp = xo[1]
    Pp = Po[1]
    gated = _update(x, Pn, xp, Pp, (y0, y1, y2), (run0, run1, run2), chans, fc)
    if gated & FALLBACK:
        return FALLBACK
    _clamp(xp, fc)
    if not _in_bounds(xp, Pp, fc[F_MAX_TRACE], fc[F_MAX_ABS]):
        return gated | DIVERGED
    # --- prediction through the event map (manifold_model.f)
    p_n, t_n, _ = _integrate(xp[3], xp[4], xp[1], p_a, t_a, t_cool, n_rpm, ts, cst, cd_alpha,
                             cd_table, prs, eta_rpm, eta_val)
    _map_out(xo, xp, sp, p_n, t_n, (a1, a2, b1, b2, a_t, b_t), fc)
    if not _in_bounds(xo[0], Pn, fc[F_MAX_TRACE], fc[F_MAX_ABS]):
        return gated | DIVERGED
    return gated


@kernel
def ekf_event(x, P, xo, Po, sp, n_rpm, p_a, t_a, t_cool, ts, y0, y1, y2, chans, run0, run1,
              run2, fc, Q, fd, c, cd_alpha, cd_table, prs, eta_rpm, eta_val):
    """One ManifoldEKF event from the prior (x, P) with the checked input and the valid
    channels (as sdkf_event): the update (_update), clamping and the divergence check, then
    manifold_model.f_and_jacobian at x_n|n (analytic actuator/IAT rows, one-sided differences
    of the event integrator with steps fd = (FD_ALPHA, FD_REL), flipped when the sub-step count
    would change) and P = sym(F P F^T + Q). Writes xo, Po as sdkf_event (Po[0] the new prior
    P_n+1|n); returns the gated channels | DIVERGED | FALLBACK."""
    cst = _const_tuple(c)
    xp = xo[1]
    Pp = Po[1]
    gated = _update(x, P, xp, Pp, (y0, y1, y2), (run0, run1, run2), chans, fc)
    if gated & FALLBACK:
        return FALLBACK
    _clamp(xp, fc)
    if not _in_bounds(xp, Pp, fc[F_MAX_TRACE], fc[F_MAX_ABS]):
        return gated | DIVERGED
    co = _event_coeffs(ts, fc)
    p_n, t_n, m = _integrate(xp[3], xp[4], xp[1], p_a, t_a, t_cool, n_rpm, ts, cst, cd_alpha,
                             cd_table, prs, eta_rpm, eta_val)
    F = np.zeros((6, 6))
    _jacobian(F, xp, p_n, t_n, m, co, fd, 0.0, 3, p_a, t_a, t_cool, n_rpm, ts, cst, cd_alpha,
              cd_table, prs, eta_rpm, eta_val, cd_table, eta_val)
    _map_out(xo, xp, sp, p_n, t_n, co, fc)
    if not _propagate(F, Pp, Q, xo, Po, fc):
        return gated | DIVERGED
    return gated
