"""Many manifold events in one compiled call (numba backend): the filters' event loop, the
open-loop temperature observer and the 6-event CAC prediction at a run of events.

Each loop calls the one-event kernels (kernels.sdkf_event, kernels.ekf_event,
kernels.predict_events, the integrator) that the per-event Python path calls, so a block gives
bit for bit what stepping event by event gives (tests/estimators/manifold/test_block_kernels.py).
`filter_events` runs only the events the kernels decide alone: it stops at the first event with
an implausible input, a rejected reading, a kernel fallback or a divergence, and the filter's
Python step() takes that event (ManifoldKF.run_events), then the next block starts.
"""

# ruff: noqa: FURB136 (x if c else y mirrors min() exactly, as the Python path computes it)
from __future__ import annotations

import math
from typing import Any

import numpy as np

from vecu.estimators.manifold.adaptive_kernel import adaptive_event
from vecu.estimators.manifold.kernels import (
    DIVERGED,
    FALLBACK,
    ekf_event,
    predict_events,
    sdkf_event,
)
from vecu.kernels import kernel
from vecu.models.manifold_integrator import _integrate_event

# plausibility limits vector of filter_events (filters.input_problem, ManifoldFilterConfig.y_ranges)
(L_N_LO, L_N_HI, L_Y0_LO, L_Y0_HI, L_Y1_LO, L_Y1_HI, L_Y2_LO, L_Y2_HI) = range(8)


def limits(config: Any) -> np.ndarray:
    """The plausibility limits vector (L_* layout) of a ManifoldFilterConfig."""
    c = config
    return np.array([c.n_range[0], c.n_range[1], *c.y_ranges[0], *c.y_ranges[1],
                     *c.y_ranges[2]], dtype=np.float64)


@kernel
def plausible(sp, n_rpm, p_a, t_a, t_cool, y0, y1, y2, lim):
    """An event the filter takes as it comes: its input is plausible (filters.input_problem
    is None) and all three readings are inside their y_ranges (NaN fails)."""
    return (lim[L_N_LO] <= n_rpm <= lim[L_N_HI] and -0.2 <= sp <= 1.9 and 50.0 <= p_a <= 120.0
            and 200.0 <= t_a <= 450.0 and 200.0 <= t_cool <= 450.0
            and lim[L_Y0_LO] <= y0 <= lim[L_Y0_HI] and lim[L_Y1_LO] <= y1 <= lim[L_Y1_HI]
            and lim[L_Y2_LO] <= y2 <= lim[L_Y2_HI])


@kernel
def filter_events(kind, x, P, P_post, ys, us, start, events_before, gated_run, gated, xs_out,
                  var_out, last_pred, lim, fc, Q, fd, ac, c, cd_alpha, cd_table, prs, eta_rpm, eta_val):
    """Events start.. of the "iterate" ManifoldSDKF (kind 0), ManifoldEKF (1) or
    adaptive.ManifoldAdaptive (2, ac its constants, 11 states) from the state
    (x, P, P_post; gated_run, gated counters), updated in place; xs_out[n] the posterior,
    var_out[n] its variances (the diagonal of P_post),
    last_pred the last event map output. Returns the index of the first event not run."""
    nx = x.shape[0]
    xo = np.empty((3, nx))
    Po = np.empty((2, nx, nx))
    n_ev = ys.shape[0]
    for n in range(start, n_ev):
        sp, n_rpm, p_a, t_a, t_cool = us[n, 0], us[n, 1], us[n, 2], us[n, 3], us[n, 4]
        y0, y1, y2 = ys[n, 0], ys[n, 1], ys[n, 2]
        if not plausible(sp, n_rpm, p_a, t_a, t_cool, y0, y1, y2, lim):
            return n
        ts = 120.0 / (fc[17] * n_rpm)  # F_NCYL
        if kind == 2:
            code = adaptive_event(x, P, xo, Po, sp, n_rpm, p_a, t_a, t_cool, ts, y0, y1, y2, 7,
                                  gated_run[0], gated_run[1], gated_run[2], fc, Q, fd, ac, c,
                                  cd_alpha, cd_table, prs, eta_rpm, eta_val)
        elif kind == 1:
            code = ekf_event(x, P, xo, Po, sp, n_rpm, p_a, t_a, t_cool, ts, y0, y1, y2, 7,
                             gated_run[0], gated_run[1], gated_run[2], fc, Q, fd, c, cd_alpha,
                             cd_table, prs, eta_rpm, eta_val)
        else:
            iterate = events_before + (n - start) + 1 > 1
            code = sdkf_event(x, P, P_post, xo, Po, sp, n_rpm, p_a, t_a, t_cool, ts, y0, y1, y2,
                              7, gated_run[0], gated_run[1], gated_run[2], iterate, fc, Q, c,
                              cd_alpha, cd_table, prs, eta_rpm, eta_val)
        if code & (FALLBACK | DIVERGED):
            return n
        for i in range(3):
            if code >> i & 1:
                gated[i] += 1
                gated_run[i] += 1
            else:
                gated_run[i] = 0
        x[:] = xo[0]
        P[:, :] = Po[0]
        P_post[:, :] = Po[1]
        xs_out[n] = xo[1]
        for i in range(nx):
            var_out[n, i] = Po[1, i, i]
        last_pred[:] = xo[2]
    return n_ev


@kernel
def open_loop_temperatures(ta_meas, n_rpm, p0, t0, u_amb, ncyl, cst, cd_alpha, cd_table, prs,
                           eta_rpm, eta_val, out):
    """cac_predict.OpenLoopTemperature stepped over the events: out[n] = T_im,n."""
    p, t = p0, t0
    alpha = math.nan
    for n in range(len(ta_meas)):
        out[n] = t
        a = ta_meas[n] if math.isfinite(ta_meas[n]) else alpha
        if not math.isfinite(a):
            continue
        alpha = a
        ts = 120.0 / (ncyl * n_rpm[n])
        p, t, _ = _integrate_event(p, t, a, u_amb[0], u_amb[1], u_amb[2], n_rpm[n], ts, cst,
                                   cd_alpha, cd_table, prs, eta_rpm, eta_val)


@kernel
def predict_at_events(states, idx, ta_sp, n_rpm, horizon, known_setpoint, u_amb, eta_scale,
                      pred, fc, c, cd_alpha, cd_table, prs, eta_rpm, eta_val):
    """cac_predict.prediction_errors' predictions: pred[j] = CAC_pred(idx[j]) (kg) from
    states[idx[j]] over the horizon (horizon_inputs: known or held setpoints, N held), the
    eta_N table scaled by eta_scale[idx[j]] (1: the calibration as it is)."""
    last = len(ta_sp) - 1
    u = np.empty((horizon, 5))
    out = np.empty(6)
    for j in range(len(idx)):
        n = idx[j]
        for k in range(horizon):
            m = n + k if n + k < last else last
            u[k, 0] = ta_sp[m] if known_setpoint else ta_sp[n]
            u[k, 1] = n_rpm[n]
            u[k, 2], u[k, 3], u[k, 4] = u_amb[0], u_amb[1], u_amb[2]
        ev = eta_val if eta_scale[n] == 1.0 else eta_val * eta_scale[n]
        pred[j] = predict_events(states[n], u, horizon, out, fc, c, cd_alpha, cd_table, prs,
                                 eta_rpm, ev)
