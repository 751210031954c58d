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
from vecu.kernels import kernel, rebuild_if_stale

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


def prepare(kc: np.ndarray) -> None:
    """kernels.prepare (the kernels this one calls), then its one signature (compile off),
    checked against its parts with a filter's packed constants kc (6 states)."""
    global _ready
    if _ready:
        return
    K.prepare()
    types, f8, i8, v, m, _ = K.signature_types()
    sig = (i8, v, m, m, m, f8[:, :, ::1], v) + (f8,) * 8 + (i8,) * 3 + (types.boolean, i8)
    ecu_event.fix_signature(sig)
    rebuild_if_stale((ecu_event,), lambda: _agrees_with_its_parts(kc),
                     lambda: ecu_event.fix_signature(sig), "ecu_event")
    _ready = True


def unpack_constants(kc: np.ndarray) -> tuple:
    """(fc, Q, fd, tables, lim) of pack_constants' array (views), as ecu_event reads them."""
    o = [int(v) for v in kc[:N_PARTS + 1]]
    nq, rows, cols = (int(v) for v in kc[N_PARTS + 1:HEADER])
    p = [kc[o[i]:o[i + 1]] for i in range(N_PARTS)]
    tables = (p[3], p[4], p[5].reshape((rows, cols)), p[6], p[7], p[8])
    return p[0], p[1].reshape((nq, nq)), p[2], tables, p[9]


def _agrees_with_its_parts(kc: np.ndarray) -> bool:
    """ecu_event on a sample event with the constants kc gives what its kernels give called
    one by one (numba's cache links the kernels it calls into its own entry and does not see
    them change); the first call of each, all compiled already."""
    fc, Q, fd, tables, _ = unpack_constants(kc)
    kc = pack_constants(fc, Q, fd, tables, np.array([-np.inf, np.inf] * 4))  # any reading
    x = np.array([0.31, 0.3, 0.29, 61.0, 321.0, 318.0])
    P = np.diag([1e-4, 1e-3, 1e-3, 4.0, 100.0, 1.0])
    sp, n, p_a, t_a, t_cool, y = 0.35, 2345.0, 99.0, 297.0, 361.0, (0.305, 60.0, 318.5)
    xo, Po, xo2, Po2 = np.empty((3, 6)), np.empty((2, 6, 6)), np.empty((3, 6)), np.empty((2, 6, 6))
    code, cac, cac6 = ecu_event.compiled(KIND_SDKF, x, P, P, xo, Po, kc, sp, n, p_a, t_a, t_cool,
                                         *y, 0, 0, 0, True, 6)
    ts = 120.0 / (fc[F_NCYL] * n)
    code2 = sdkf_event.compiled(x, P, P, xo2, Po2, sp, n, p_a, t_a, t_cool, ts, *y, 7, 0, 0, 0,
                                True, fc, Q, *tables)
    out = np.empty(6)
    cac6_2 = predict_events.compiled(xo2[2].copy(), np.array([[sp, n, p_a, t_a, t_cool]]), 5,
                                     out, fc, *tables)
    # (the CAC at the posterior: eta_N and the integrator's constants, checked through these)
    return ((code, cac6) == (code2, cac6_2) and cac > 0.0 and np.array_equal(xo, xo2)
            and np.array_equal(Po, Po2))


def kernel_kind(flt: Any) -> int | None:
    """ecu_event's kind for a filter, None when it has none (the adaptive filter, an SDKF
    that solves the DARE per event)."""
    name = getattr(flt, "name", "")
    if name == "ekf":
        return KIND_EKF
    if name == "sdkf" and flt.config.riccati == "iterate":
        return KIND_SDKF
    return None
