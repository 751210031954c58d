"""Filtering a sequence of engine events (`filter_events`): the filters' `estimate` (the ECU's
event with its air charge and 6-event prediction) and `run_events` (a study's drive) call it.

Each event is the one-event kernel step() calls (event.sdkf_event, event.ekf_event,
adaptive_event.adaptive_event), so a run gives bit for bit what stepping gives
(tests/estimators/manifold/test_runs.py). It stops at the first event the kernels cannot decide
alone (an implausible input, a rejected reading, a fallback, a divergence): step() takes it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from vecu.estimators.manifold.adaptive_event import adaptive_event
from vecu.estimators.manifold.cac_predict import predict_events
from vecu.estimators.manifold.event import (
    DIVERGED,
    F_NCYL,
    F_VCYL,
    FALLBACK,
    INPUT_OK,
    ekf_event,
    input_fault,
    sdkf_event,
)
from vecu.kernels import kernel, numbers, pack, part, table
from vecu.models.manifold import air_charge_of
from vecu.models.manifold_integrator import N_CONSTS

# plausibility limits vector of filter_events (filters.input_problem, ManifoldFilterConfig.y_ranges)
(L_N_LO, L_N_HI, L_Y0_LO, L_Y0_HI, L_Y1_LO, L_Y1_HI, L_Y2_LO, L_Y2_HI) = range(8)


# the parts of filter_events' constants (event_constants: one vecu.kernels.pack)
(K_LIM, K_FC, K_Q, K_FD, K_AC, K_C, K_CD_ALPHA, K_CD_TABLE, K_PRS, K_ETA_RPM,
 K_ETA_VAL) = range(11)


def limits(config: Any) -> np.ndarray:
    """The plausibility limits vector (L_* layout) of a ManifoldFilterConfig."""
    c = config
    return np.array([c.n_range[0], c.n_range[1], *c.y_ranges[0], *c.y_ranges[1],
                     *c.y_ranges[2]], dtype=np.float64)


def event_constants(config: Any, fc: Any, Q: np.ndarray, fd: Any, ac: Any, tables: tuple) -> Any:
    """filter_events' constants as one argument (vecu.kernels.pack, parts K_*): the
    plausibility limits of a ManifoldFilterConfig, the filter constants, Q, the FD steps, the
    adaptive constants (any three numbers for the other kinds) and the integrator's tables."""
    return pack(limits(config), fc, Q, fd, ac, *tables)


@kernel
def plausible(sp, n_rpm, p_a, t_a, t_cool, y0, y1, y2, lim):
    """An event the filter takes as it comes: its input is plausible (event.input_fault) and
    all three readings are inside their y_ranges (NaN fails)."""
    return (input_fault(sp, n_rpm, p_a, t_a, t_cool, lim[L_N_LO], lim[L_N_HI]) == INPUT_OK
            and lim[L_Y0_LO] <= y0 <= lim[L_Y0_HI] and lim[L_Y1_LO] <= y1 <= lim[L_Y1_HI]
            and lim[L_Y2_LO] <= y2 <= lim[L_Y2_HI])


@kernel
def filter_events(kind, x, P, P_post, ys, us, start, events_before, counts, xs_out, var_out,
                  last_pred, k, horizon, cac_out):
    """Events start.. of the "iterate" ManifoldSDKF (kind 0), ManifoldEKF (1) or
    adaptive.ManifoldAdaptive (2, 11 states) from the state (x, P, P_post; counts: the gated
    in a row and gated counters per channel), updated in place, with the constants k
    (event_constants); xs_out[n] the posterior, var_out[n] its variances (the diagonal of
    P_post), last_pred the last event map output. With horizon > 0 also cac_out[n] = (the CAC
    at the posterior, models.manifold.air_charge_of; the CAC `horizon` events ahead with the
    input held, cac_predict.predict_events from the event map's output: predict_cac's
    numbers). Returns the index of the first event not run."""
    lim, fc, Q, fd, ac = part(k, K_LIM), part(k, K_FC), table(k, K_Q), part(k, K_FD), part(k, K_AC)
    c, cd_alpha, cd_table = numbers(k, K_C, N_CONSTS), part(k, K_CD_ALPHA), table(k, K_CD_TABLE)
    prs, eta_rpm, eta_val = part(k, K_PRS), part(k, K_ETA_RPM), part(k, K_ETA_VAL)
    gated_run, gated = counts[0], counts[1]
    nx = x.shape[0]
    xo = np.empty((3, nx))
    Po = np.empty((2, nx, nx))
    x6 = np.empty(6)
    out6 = np.empty(6)
    n_ev = ys.shape[0]
    for n in range(start, n_ev):
        sp, n_rpm, p_a, t_a, t_cool = us[n, 0], us[n, 1], us[n, 2], us[n, 3], us[n, 4]
        y0, y1, y2 = ys[n, 0], ys[n, 1], ys[n, 2]
        if not plausible(sp, n_rpm, p_a, t_a, t_cool, y0, y1, y2, lim):
            return n
        ts = 120.0 / (fc[F_NCYL] * n_rpm)
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
        if horizon > 0:
            cac_out[n, 0] = air_charge_of(n_rpm, xo[1, 3], xo[1, 4], c, fc[F_VCYL], eta_rpm,
                                          eta_val)
            for i in range(6):
                x6[i] = xo[2, i]
            cac_out[n, 1] = predict_events(x6, us[n:n + 1], horizon - 1, out6, fc, c, cd_alpha,
                                           cd_table, prs, eta_rpm, eta_val)
    return n_ev
