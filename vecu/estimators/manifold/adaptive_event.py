"""The adaptive manifold EKF's event as one kernel: event.ekf_event with the parameter states c,
c_th, g, k_zeta, k_omega of vecu.estimators.manifold.adaptive (docs/models.md, "Adaptive air
charge")."""

# ruff: noqa: FURB136 (x if c else y mirrors min()/max() exactly)
from __future__ import annotations

import math

import numpy as np

from vecu.estimators.manifold import event as K
from vecu.estimators.manifold.event import (
    DIVERGED,
    F_GATE2,
    F_MAX_ABS,
    F_MAX_GATED,
    F_MAX_TRACE,
    F_OMEGA0,
    F_R0,
    F_TAU,
    F_ZETA,
    FALLBACK,
)
from vecu.kernels import kernel
from vecu.models.manifold import event_coefficients

# states: the EKF's six, c, c_th, g, k_zeta, k_omega
N_XA = 11
I_C, I_CTH, I_G, I_KZ, I_KW = range(6, 11)
(A_C_LO, A_C_HI, A_FD_C, A_PR_FREEZE, A_ALPHA_GATE, A_G_LO, A_G_HI, A_K_LO, A_K_HI,
 A_FD_K) = range(10)
ZETA_MAX = 0.99


@kernel
def _consider(x, P, xp, Pp, lo, hi):
    """Undo the update of states lo..hi-1 in (xp, Pp) from the prior (x, P): the Schmidt
    (consider) filter's result, for which the other states' update is unchanged (their gain,
    and so their cross-covariance with the considered states, is the optimal update's)."""
    n = x.shape[0]
    for i in range(lo, hi):
        xp[i] = x[i]
        for j in range(n):
            Pp[i, j] = P[i, j] if lo <= j < hi else Pp[j, i]


@kernel
def _angle_update(x, P, xp, Pp, y0, run0, fc):
    """The TA channel's EKF update with the measurement TA = g alpha (H: g in the alpha
    column, alpha in g's), gated as event.update. Returns 1 (gated), 0 or FALLBACK."""
    n = x.shape[0]
    g, alpha = x[I_G], x[1]
    e = y0 - g * alpha
    s = g * g * P[1, 1] + 2.0 * g * alpha * P[1, I_G] + alpha * alpha * P[I_G, I_G] + fc[F_R0]
    if not (math.isfinite(s) and s > 0.0):
        return FALLBACK
    if e * e > fc[F_GATE2] * s and run0 < fc[F_MAX_GATED]:
        xp[:] = x
        Pp[:, :] = P
        return 1
    ph = np.empty(n)  # P H^T
    for i in range(n):
        ph[i] = g * P[i, 1] + alpha * P[i, I_G]
    for i in range(n):
        xp[i] = x[i] + ph[i] * e / s
    for i in range(n):
        for j in range(i + 1):
            v = P[i, j] - ph[i] * ph[j] / s
            Pp[i, j] = v
            Pp[j, i] = v
    return 0


@kernel
def _actuator_coeffs(ts, fc, kz, kw):
    """event.coefficients with zeta and omega0 scaled by k_zeta, k_omega (zeta kept below
    ZETA_MAX: eq. 1's discretisation is the underdamped one)."""
    z = fc[F_ZETA] * kz
    return event_coefficients(ts, z if z < ZETA_MAX else ZETA_MAX, fc[F_OMEGA0] * kw, fc[F_TAU])


@kernel
def adaptive_event(x, P, xo, Po, sp, n_rpm, p_a, t_a, t_cool, ts, y0, y1, y2, chans, run0,
                   run1, run2, fc, Q, fd, ac, c, cd_alpha, cd_table, prs, eta_rpm, eta_val):
    """One event of the adaptive EKF from the prior (x, P) (as event.ekf_event, 11 states):
    update (below), clamping (the corrections to their boxes), divergence check, then the event
    map with eta scaled by c, the throttle flow by c_th and the actuator's (zeta, omega0) by
    (k_zeta, k_omega), its Jacobian (one-sided differences) and P = sym(F P F^T + Q). Writes
    xo (3 x 11), Po (2 x 11 x 11); returns the gated channels | DIVERGED | FALLBACK."""
    n = x.shape[0]
    xp = xo[1]
    Pp = Po[1]
    # g, k_zeta, k_omega learn from TA, c, c_th from P_im; other channels consider them (Schmidt
    # update; docs/models.md, "Adaptive air charge").
    e_alpha = y0 - x[I_G] * x[1]
    s_alpha = (x[I_G] * x[I_G] * P[1, 1] + 2.0 * x[I_G] * x[1] * P[1, I_G]
               + x[1] * x[1] * P[I_G, I_G] + fc[F_R0])
    alpha_odd = not (chans & 1) or (
        e_alpha * e_alpha > ac[A_ALPHA_GATE] * ac[A_ALPHA_GATE] * s_alpha)
    xa = np.empty(n)
    Pa = np.empty((n, n))
    gated = 0
    if chans & 1:
        gated = _angle_update(x, P, xa, Pa, y0, run0, fc)
        if gated & FALLBACK:
            return FALLBACK
        _consider(x, P, xa, Pa, I_C, I_G)
    else:
        xa[:] = x
        Pa[:, :] = P
    xm = np.empty(n)
    Pm = np.empty((n, n))
    g1 = K.update(xa, Pa, xm, Pm, (y0, y1, y2), (run0, run1, run2), chans & 4, fc)
    if g1 & FALLBACK:
        return FALLBACK
    gated |= g1
    _consider(xa, Pa, xm, Pm, I_C, n)
    g2 = K.update(xm, Pm, xp, Pp, (y0, y1, y2), (run0, run1, run2), chans & 2, fc)
    if g2 & FALLBACK:
        return FALLBACK
    gated |= g2
    if x[3] > ac[A_PR_FREEZE] * p_a or alpha_odd:
        _consider(xm, Pm, xp, Pp, I_C, n)
    else:
        _consider(xm, Pm, xp, Pp, I_G, n)
    K.clamp(xp, fc)  # the first six states
    for i in range(I_C, n):
        lo = ac[A_C_LO] if i < I_G else (ac[A_G_LO] if i == I_G else ac[A_K_LO])
        hi = ac[A_C_HI] if i < I_G else (ac[A_G_HI] if i == I_G else ac[A_K_HI])
        xp[i] = lo if lo > xp[i] else xp[i]
        xp[i] = hi if hi < xp[i] else xp[i]
    if not K.in_bounds(xp, Pp, fc[F_MAX_TRACE], fc[F_MAX_ABS]):
        return gated | DIVERGED
    kz, kw = xp[I_KZ], xp[I_KW]
    co = _actuator_coeffs(ts, fc, kz, kw)
    ev = eta_val * xp[I_C]
    cdt = cd_table * xp[I_CTH]
    p_n, t_n, m = K.integrate_event(float(xp[3]), float(xp[4]), float(xp[1]), p_a, t_a, t_cool,
                                    n_rpm, ts, c, cd_alpha, cdt, prs, eta_rpm, ev)
    F = np.zeros((n, n))
    K.jacobian(F, xp, p_n, t_n, m, co, fd, ac[A_FD_C], 5, p_a, t_a, t_cool, n_rpm, ts, c,
                cd_alpha, cdt, prs, eta_rpm, ev, cd_table, eta_val)
    # the actuator row's columns k_zeta, k_omega (eq. 1 is linear in alpha, not in them)
    alpha_n = co[0] * xp[1] + co[1] * xp[2] + co[2] * sp + co[3] * xp[0]
    d = ac[A_FD_K]
    cz = _actuator_coeffs(ts, fc, kz + d, kw)
    cw = _actuator_coeffs(ts, fc, kz, kw + d)
    F[1, I_KZ] = (cz[0] * xp[1] + cz[1] * xp[2] + cz[2] * sp + cz[3] * xp[0] - alpha_n) / d
    F[1, I_KW] = (cw[0] * xp[1] + cw[1] * xp[2] + cw[2] * sp + cw[3] * xp[0] - alpha_n) / d
    K.map_out(xo, xp, sp, p_n, t_n, co, fc)
    if not K.propagate(F, Pp, Q, xo, Po, fc):
        return gated | DIVERGED
    return gated


def _signature() -> tuple:
    _, f8, i8, v, m, tables = K.signature_types()
    return (v, m, m, f8[:, :, ::1]) + (f8,) * 9 + (i8,) * 4 + (v, m, v, v) + tables


adaptive_event.fix_signature(_signature)
