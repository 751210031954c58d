"""The adaptive manifold EKF's event as one kernel (vecu.estimators.manifold.adaptive has the
filter and the model it implements): kernels.ekf_event with two more states, the volumetric-
efficiency correction c and the throttle-flow correction c_th, scaling the eta_N and C_d tables
of the event integrator."""

# ruff: noqa: FURB136 (x if c else y mirrors min()/max() exactly)
from __future__ import annotations

import numpy as np

from vecu.estimators.manifold import kernels as K
from vecu.estimators.manifold.kernels import (
    DIVERGED,
    F_MAX_ABS,
    F_MAX_TRACE,
    F_R0,
    FALLBACK,
)
from vecu.kernels import kernel

N_XA = 8  # the EKF's six states, the eta correction c and the throttle-flow correction c_th
(A_C_LO, A_C_HI, A_FD_C, A_PR_FREEZE, A_ALPHA_GATE) = range(5)


def _consider_py(x, P, xp, Pp):
    """Undo the update of c, c_th (states 6, 7) in (xp, Pp) from the prior (x, P): the Schmidt
    (consider) filter's result, for which the other states' update is unchanged."""
    xp[6], xp[7] = x[6], x[7]
    for i in range(6, 8):
        for j in range(8):
            Pp[i, j] = P[i, j] if j >= 6 else Pp[j, i]


_consider = kernel(_consider_py)


@kernel
def adaptive_event(x, P, xo, Po, sp, n_rpm, p_a, t_a, t_cool, ts, y0, y1, y2, chans, run0,
                   run1, run2, fc, Q, fd, ac, c, cd_alpha, cd_table, prs, eta_rpm, eta_val):
    """One event of the adaptive EKF from the prior (x, P) (as kernels.ekf_event, 8 states):
    update (below), clamping (c, c_th to their box), divergence check, then the event map with
    eta scaled by c and the throttle flow by c_th, its Jacobian (five one-sided differences) and
    P = sym(F P F^T + Q). Writes xo (3 x 8), Po (2 x 8 x 8); returns the gated channels |
    DIVERGED | FALLBACK."""
    cst = K._const_tuple(c)
    xp = xo[1]
    Pp = Po[1]
    # c, c_th learn from the pressure channel only (the angle and the slow IAT sensor would
    # pull them to explain their own errors: actuator model, sensor gain): first TA and T_im.out
    # with c, c_th as considered parameters (Schmidt update: they and their covariance keep the
    # prior), then P_im, also considered when the model is not trustworthy: near wide open
    # (the flow function is steep as P_im / P_a -> 1) or while the throttle does not follow its
    # model (TA innovation beyond eta_alpha_gate sigma). Sequential channel updates equal the
    # joint one for a diagonal R.
    e_alpha = y0 - x[1]
    alpha_odd = not (chans & 1) or (
        e_alpha * e_alpha > ac[A_ALPHA_GATE] * ac[A_ALPHA_GATE] * (P[1, 1] + fc[F_R0]))
    xm = np.empty(8)
    Pm = np.empty((8, 8))
    gated = K._update(x, P, xm, Pm, (y0, y1, y2), (run0, run1, run2), chans & 5, fc)
    if gated & FALLBACK:
        return FALLBACK
    _consider(x, P, xm, Pm)
    g2 = K._update(xm, Pm, xp, Pp, (y0, y1, y2), (run0, run1, run2), chans & 2, fc)
    if g2 & FALLBACK:
        return FALLBACK
    gated |= g2
    if x[3] > ac[A_PR_FREEZE] * p_a or alpha_odd:
        _consider(xm, Pm, xp, Pp)
    K._clamp(xp, fc)  # the first six states
    for i in range(6, 8):
        xp[i] = ac[A_C_LO] if ac[A_C_LO] > xp[i] else xp[i]
        xp[i] = ac[A_C_HI] if ac[A_C_HI] < xp[i] else xp[i]
    if not K._in_bounds(xp, Pp, fc[F_MAX_TRACE], fc[F_MAX_ABS]):
        return gated | DIVERGED
    co = K._event_coeffs(ts, fc)
    ev = eta_val * xp[6]
    cdt = cd_table * xp[7]
    p_n, t_n, m = K._integrate(xp[3], xp[4], xp[1], p_a, t_a, t_cool, n_rpm, ts, cst, cd_alpha,
                               cdt, prs, eta_rpm, ev)
    F = np.zeros((8, 8))
    K._jacobian(F, xp, p_n, t_n, m, co, fd, ac[A_FD_C], 5, p_a, t_a, t_cool, n_rpm, ts, cst,
                cd_alpha, cdt, prs, eta_rpm, ev, cd_table, eta_val)
    K._map_out(xo, xp, sp, p_n, t_n, co, fc)
    if not K._propagate(F, Pp, Q, xo, Po, fc):
        return gated | DIVERGED
    return gated


_ready = False


def prepare() -> None:
    """kernels.prepare (the helpers this kernel calls), then its one signature."""
    global _ready
    if _ready:
        return
    K.prepare()
    from numba import types

    f8, i8 = types.float64, types.int64
    v, m = f8[::1], f8[:, ::1]
    tables = (v, v, m, v, v, v)
    disp = adaptive_event.compiled
    disp.compile((v, m, m, f8[:, :, ::1]) + (f8,) * 9 + (i8,) * 4 + (v, m, v, v) + tables)
    disp.disable_compile()
    _ready = True
