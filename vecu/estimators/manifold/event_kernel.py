"""The ECU manifold function's whole engine event in one compiled call (numba backend).

`ecu_event` is what ManifoldFunction.run asks of the filter and the CAC prediction for an
event, bit for bit: ManifoldSDKF ("iterate") / ManifoldEKF .step(y, u) (the filter's own event
kernel, kernels.sdkf_event / ekf_event), the cylinder air charge at the posterior
(models.manifold.cylinder_air_charge, as kernels._air_charge) and the CAC predicted HORIZON
events ahead with the input held, from the event map's output (cac_predict.predict_cac as
kernels.predict_events). It takes only the usual event: a plausible input, three readings
inside their ranges (block_kernels.plausible) and an event the filter kernel decides alone.
Anything else returns NOT_TAKEN, FALLBACK or DIVERGED with nothing changed, and the caller
makes the separate calls, which decide as they always did. The math stays in those kernels;
this one only strings them together (CompiledEvents.event_cac is its Python side).

Its constants (filter constants, Q, FD steps, the integrator's tables, the plausibility limits)
travel packed in one float64 array (pack_constants): one argument instead of ten.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from vecu.estimators.manifold import kernels as K
from vecu.estimators.manifold.block_kernels import plausible
from vecu.estimators.manifold.kernels import (
    DIVERGED,
    F_NCYL,
    FALLBACK,
    ekf_event,
    predict_events,
    sdkf_event,
)
from vecu.kernels import kernel

NOT_TAKEN = 32  # the event is not the usual one: make the separate calls
KIND_SDKF, KIND_EKF = 0, 1
# header of the packed constants: offsets of fc, Q, fd, c, cd_alpha, cd_table, prs, eta_rpm,
# eta_val, lim and their end, then the shapes of Q (n) and of cd_table (rows, cols)
N_PARTS = 10
HEADER = N_PARTS + 1 + 3


def pack_constants(fc: np.ndarray, Q: np.ndarray, fd: np.ndarray, tables: tuple,
                   lim: np.ndarray) -> np.ndarray:
    """One float64 array: HEADER (offsets and shapes, exact small integers), then fc, Q, fd,
    the six integrator tables (c, cd_alpha, cd_table, prs, eta_rpm, eta_val) and lim."""
    parts = [np.ascontiguousarray(a, dtype=np.float64).ravel()
             for a in (fc, Q, fd, *tables, lim)]
    assert len(parts) == N_PARTS
    offsets = np.cumsum([HEADER] + [len(a) for a in parts])
    cd_table = np.asarray(tables[2])
    head = [*offsets, Q.shape[0], cd_table.shape[0], cd_table.shape[1]]
    return np.concatenate([np.array(head, dtype=np.float64), *parts])


@kernel
def ecu_event(kind, x, P, P_post, xo, Po, kc, sp, n_rpm, p_a, t_a, t_cool, y0, y1, y2, run0,
              run1, run2, iterate, horizon):
    """One event of the filter (kind KIND_SDKF: sdkf_event with `iterate`; KIND_EKF:
    ekf_event) from its prior (x, P; P_post the previous posterior) with the input (sp, n_rpm,
    p_a, t_a, t_cool) and the readings y (run_i: gated-in-a-row counts), writing xo, Po as
    those kernels do; then the CAC at the posterior xo[1] and the CAC after `horizon` events
    from xo[1] (horizon - 1 through the event map from its output xo[2], the input held).
    Returns (status word, CAC, CAC+horizon); the status word is the filter kernel's (gated
    channels | DIVERGED | FALLBACK) or NOT_TAKEN (nothing run); the CACs are 0 unless it is
    only the gated channels."""
    nq, rows, cols = int(kc[N_PARTS + 1]), int(kc[N_PARTS + 2]), int(kc[N_PARTS + 3])
    fc = kc[int(kc[0]):int(kc[1])]
    Q = kc[int(kc[1]):int(kc[2])].reshape((nq, nq))
    fd = kc[int(kc[2]):int(kc[3])]
    c = kc[int(kc[3]):int(kc[4])]
    cd_alpha = kc[int(kc[4]):int(kc[5])]
    cd_table = kc[int(kc[5]):int(kc[6])].reshape((rows, cols))
    prs, eta_rpm = kc[int(kc[6]):int(kc[7])], kc[int(kc[7]):int(kc[8])]
    eta_val, lim = kc[int(kc[8]):int(kc[9])], kc[int(kc[9]):int(kc[10])]
    if not plausible(sp, n_rpm, p_a, t_a, t_cool, y0, y1, y2, lim):
        return NOT_TAKEN, 0.0, 0.0
    ts = 120.0 / (fc[F_NCYL] * n_rpm)  # models.manifold.sample_time
    if kind == KIND_EKF:
        code = ekf_event(x, P, xo, Po, sp, n_rpm, p_a, t_a, t_cool, ts, y0, y1, y2, 7, run0,
                         run1, run2, fc, Q, fd, c, cd_alpha, cd_table, prs, eta_rpm, eta_val)
    else:
        code = sdkf_event(x, P, P_post, xo, Po, sp, n_rpm, p_a, t_a, t_cool, ts, y0, y1, y2, 7,
                          run0, run1, run2, iterate, fc, Q, c, cd_alpha, cd_table, prs, eta_rpm,
                          eta_val)
    if code & (FALLBACK | DIVERGED):
        return code, 0.0, 0.0
    cac = K._air_charge(n_rpm, xo[1, 3], xo[1, 4], fc, c, eta_rpm, eta_val)
    x6 = np.empty(6)
    for i in range(6):
        x6[i] = xo[2, i]
    u = np.empty((1, 5))
    u[0, 0], u[0, 1], u[0, 2], u[0, 3], u[0, 4] = sp, n_rpm, p_a, t_a, t_cool
    out = np.empty(6)
    cac6 = predict_events(x6, u, horizon - 1, out, fc, c, cd_alpha, cd_table, prs, eta_rpm,
                          eta_val)
    return code, cac, cac6


_ready = False


def prepare() -> None:
    """kernels.prepare (the kernels this one calls), then its one signature (compile off)."""
    global _ready
    if _ready:
        return
    K.prepare()
    from numba import types

    f8, i8 = types.float64, types.int64
    v, m = f8[::1], f8[:, ::1]
    disp = ecu_event.compiled
    disp.compile((i8, v, m, m, m, f8[:, :, ::1], v) + (f8,) * 8 + (i8,) * 3
                 + (types.boolean, i8))
    disp.disable_compile()
    _ready = True


def kernel_kind(flt: Any) -> int | None:
    """ecu_event's kind for a filter, None when it has none (the adaptive filter, an SDKF
    that solves the DARE per event)."""
    name = getattr(flt, "name", "")
    if name == "ekf":
        return KIND_EKF
    if name == "sdkf" and flt.config.riccati == "iterate":
        return KIND_SDKF
    return None
