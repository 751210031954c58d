"""Compiled loops of the throttle identification (vecu.kernels: numba with vecu[fast]); eq. (3)
is vecu.models.throttle.eq3_step / mode_step, eq. (4) the wattmeter y = i^2 + v."""

from __future__ import annotations

import math

from vecu.kernels import kernel
from vecu.models.throttle import THETA_MAX_DEG, clip_theta, eq3_step, mode_of, mode_step

# innovations' columns: theta innovation and its variance, wattmeter innovation and its variance,
# the predicted current i_{k|k-1}
(E_TH, S_TH, E_Y, S_Y, I_PRED) = range(5)
SQRT2 = math.sqrt(2.0)
# an angle sample this near a stop (deg) is taken as clipped: > 4 sigma of the TPS noise
STOP_DEG = 0.2
NEAR_STOP_SIGMAS = 3.0  # an angle predicted within this many sigmas of a stop is not scored
RHO_PRIOR_VAR = 100.0  # rho_0 unknown: a wide prior (rho's typical size is a few units)


@kernel
def innovations(P, b1, b2, u, th, y, q, gate, g2, out):
    """The prediction errors of eq. (3)-(4) through an extended Kalman filter (second-order in
    the wattmeter's i^2): the predictor a prediction-error fit minimises.

    P: 3x10 mode rows (a12 .. c3), b1 / b2 the switching angles; u, th (TPS angle, deg), y
    (wattmeter, W) the samples k = 0..n-1 (y_k, th_k measured on x_k, then u_k drives x_k ->
    x_{k+1}); q = (F11, F33, H, TPS noise in deg). State (theta, rho, i), rho unmeasured,
    F22 = 0. Writes out[k] = (e_theta, S_theta, e_y, S_y, i_{k|k-1}): innovations and their
    variances, the angle first, then the wattmeter (sequential updates, diagonal R).

    gate[k] = (angle scored, wattmeter used). The wattmeter update is used only where the
    predicted current is clear of 0: i^2 tells no sign, and near i = 0 the filter's linear
    update is far from the conditional mean (a bimodal posterior), which biases a fit; the angle
    is not scored where its prediction is within NEAR_STOP_SIGMAS of a stop (clipped: its
    innovation is not zero-mean). With g2 > 0 the filter decides (and writes gate): wattmeter
    used where i_{k|k-1}^2 > g2 Var(i_{k|k-1}); with g2 <= 0 it reads gate (decisions frozen, so
    that the fit's cost is smooth in the parameters). Not scored / unused: e = 0, S = inf.
    """
    n = u.size
    decide = g2 > 0.0
    q11 = q[0] * q[0]
    q33 = q[1] * q[1]
    r_y = q[2] * q[2]
    r_th = q[3] * q[3]
    t = th[0]
    r = 0.0
    c = math.sqrt(max(y[0], 0.0))
    # covariance (symmetric): p00 p01 p02 / p11 p12 / p22
    p00 = r_th
    p01 = 0.0
    p02 = 0.0
    p11 = RHO_PRIOR_VAR
    p12 = 0.0
    p22 = 1.0
    for k in range(n):
        out[k, 4] = c
        if th[k] <= STOP_DEG or th[k] >= THETA_MAX_DEG - STOP_DEG:
            # at a mechanical stop the angle is clipped (censored): it tells where theta is,
            # nothing about rho and i; not scored
            out[k, 0] = 0.0
            out[k, 1] = math.inf
            t = th[k]
            p00, p01, p02 = r_th, 0.0, 0.0
        else:
            # angle update: H = (1, 0, 0)
            s = p00 + r_th
            e = th[k] - t
            if decide:
                near = NEAR_STOP_SIGMAS * math.sqrt(s)
                gate[k, 0] = 0.0 if (t < near or THETA_MAX_DEG - t < near) else 1.0
            if gate[k, 0] < 0.5:
                # predicted near a stop: the angle may be clipped, so its innovation is not
                # zero-mean (the update of rho, i given an unclipped angle is still exact)
                out[k, 0] = 0.0
                out[k, 1] = math.inf
            else:
                out[k, 0] = e
                out[k, 1] = s
            k0 = p00 / s
            k1 = p01 / s
            k2 = p02 / s
            t += k0 * e
            r += k1 * e
            c += k2 * e
            p00, p01, p02, p11, p12, p22 = (p00 - k0 * p00, p01 - k0 * p01, p02 - k0 * p02,
                                            p11 - k1 * p01, p12 - k1 * p02, p22 - k2 * p02)
        # wattmeter update: y = i^2 + v, E y = c^2 + p22, H = (0, 0, 2c)
        if decide:
            gate[k, 1] = 1.0 if c * c > g2 * p22 else 0.0
        if gate[k, 1] < 0.5:
            out[k, 2] = 0.0
            out[k, 3] = math.inf
        else:
            s = 4.0 * c * c * p22 + 2.0 * p22 * p22 + r_y
            e = y[k] - (c * c + p22)
            out[k, 2] = e
            out[k, 3] = s
            h = 2.0 * c
            k0 = p02 * h / s
            k1 = p12 * h / s
            k2 = p22 * h / s
            t += k0 * e
            r += k1 * e
            c += k2 * e
            p00, p01, p02, p11, p12, p22 = (p00 - k0 * k0 * s, p01 - k0 * k1 * s, p02 - k0 * k2 * s,
                                            p11 - k1 * k1 * s, p12 - k1 * k2 * s, p22 - k2 * k2 * s)
        # predict: eq. (3)'s mode by the angle, its affine map (mode_step) with the signs'
        # expectations E sgn(rho), E sgn(theta - 1) under the filter's Gaussian; A read off
        # mode_step at the unit states with the signs zero (its linear part; the slope of
        # E sgn(rho) is left out: a spike where rho's sigma is small that destabilises P)
        row = P[mode_of(b1, b2, t)]
        sg_r = math.erf(r / (math.sqrt(max(p11, 1e-12)) * SQRT2))
        sg_t = math.erf((t - 1.0) / (math.sqrt(max(p00, 1e-12)) * SQRT2))
        tn, rn, cn = mode_step(row, t, r, c, u[k], sg_r, sg_t)
        a0 = mode_step(row, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        a1 = mode_step(row, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0)
        a2 = mode_step(row, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
        z = mode_step(row, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        # A[i][j] = a_j[i] - z[i]
        A00, A10, A20 = a0[0] - z[0], a0[1] - z[1], a0[2] - z[2]
        A01, A11, A21 = a1[0] - z[0], a1[1] - z[1], a1[2] - z[2]
        A02, A12, A22 = a2[0] - z[0], a2[1] - z[1], a2[2] - z[2]
        # M = A Pk (rows of A times columns of P)
        m00 = A00 * p00 + A01 * p01 + A02 * p02
        m01 = A00 * p01 + A01 * p11 + A02 * p12
        m02 = A00 * p02 + A01 * p12 + A02 * p22
        m10 = A10 * p00 + A11 * p01 + A12 * p02
        m11 = A10 * p01 + A11 * p11 + A12 * p12
        m12 = A10 * p02 + A11 * p12 + A12 * p22
        m20 = A20 * p00 + A21 * p01 + A22 * p02
        m21 = A20 * p01 + A21 * p11 + A22 * p12
        m22 = A20 * p02 + A21 * p12 + A22 * p22
        # A Pk A^T + diag(F11^2, 0, F33^2)
        p00 = m00 * A00 + m01 * A01 + m02 * A02 + q11
        p01 = m00 * A10 + m01 * A11 + m02 * A12
        p02 = m00 * A20 + m01 * A21 + m02 * A22
        p11 = m10 * A10 + m11 * A11 + m12 * A12
        p12 = m10 * A20 + m11 * A21 + m12 * A22
        p22 = m20 * A20 + m21 * A21 + m22 * A22 + q33
        t = tn  # not clipped: the Gaussian prior of the angle before the stops (an angle
        r = rn  # measured off the stops is that one exactly; at a stop, see above)
        c = cn
        if not (math.isfinite(r) and math.isfinite(c) and math.isfinite(p11)) or abs(r) > 1e9:
            # a trial parameter set that blows up: restart from the measurements
            r = 0.0
            c = math.sqrt(max(y[k], 0.0))
            p00, p01, p02, p11, p12, p22 = r_th, 0.0, 0.0, RHO_PRIOR_VAR, 0.0, 1.0


@kernel
def free_run(P, b1, b2, u, th0, i0, out_th, out_i):
    """Eq. (3) with w = 0 from (th0, rho = 0, i0): the paper's simulated trajectory (Fig. 2)."""
    n = u.size
    t = th0
    r = 0.0
    c = i0
    for k in range(n):
        out_th[k] = t
        out_i[k] = c
        tn, r, c = eq3_step(P, b1, b2, t, r, c, u[k])
        t = clip_theta(tn)
