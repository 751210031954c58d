"""Runs of manifold filter events in one compiled call, and the ECU's whole event (numba).

- `filter_events`: the filters' event loop over many events (ManifoldKF.run_events): the "iterate"
  SDKF, the EKF or the adaptive EKF, each event the one-event kernel the per-event path calls
  (event.sdkf_event, event.ekf_event, adaptive_event.adaptive_event), so a block gives bit for bit
  what stepping gives (tests/estimators/manifold/test_runs.py). It runs only the events
  the kernels decide alone: it stops at the first event with an implausible input, a rejected
  reading, a fallback or a divergence, the filter's step() takes that event, the next block starts.
- `ecu_event`: what ManifoldFunction.run asks of the filter and the CAC prediction for an event,
  bit for bit: the filter's event kernel, the cylinder air charge at the posterior
  (models.manifold.air_charge_of) and the CAC HORIZON events ahead with the input held
  (cac_predict.predict_events), for the usual event only (a plausible input, three readings in
  range); anything else returns NOT_TAKEN, FALLBACK or DIVERGED with nothing changed and the
  caller makes the separate calls. Its constants travel packed in one float64 array
  (pack_constants).
- `CompiledEvents`: the Python side (a mixin of filters._ManifoldKF): run_events, event_cac.
The python backend never runs these loops (the per-event path is the reference).
"""


from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from vecu.estimators.manifold.adaptive_event import adaptive_event
from vecu.estimators.manifold.cac_predict import predict_cac, predict_events
from vecu.estimators.manifold.event import (
    DIVERGED,
    F_NCYL,
    F_VCYL,
    FALLBACK,
    INPUT_OK,
    ekf_event,
    input_fault,
    sdkf_event,
    signature_types,
)
from vecu.kernels import kernel
from vecu.models.manifold import air_charge_of, cylinder_air_charge
from vecu.models.manifold_params import EngineInput

# plausibility limits vector of filter_events (filters.input_problem, ManifoldFilterConfig.y_ranges)
(L_N_LO, L_N_HI, L_Y0_LO, L_Y0_HI, L_Y1_LO, L_Y1_HI, L_Y2_LO, L_Y2_HI) = range(8)


def limits(config: Any) -> np.ndarray:
    """The plausibility limits vector (L_* layout) of a ManifoldFilterConfig."""
    c = config
    return np.array([c.n_range[0], c.n_range[1], *c.y_ranges[0], *c.y_ranges[1],
                     *c.y_ranges[2]], dtype=np.float64)


@kernel
def plausible(sp, n_rpm, p_a, t_a, t_cool, y0, y1, y2, lim):
    """An event the filter takes as it comes: its input is plausible (event.input_fault) and
    all three readings are inside their y_ranges (NaN fails)."""
    return (input_fault(sp, n_rpm, p_a, t_a, t_cool, lim[L_N_LO], lim[L_N_HI]) == INPUT_OK
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
    cac = air_charge_of(n_rpm, xo[1, 3], xo[1, 4], c, fc[F_VCYL], eta_rpm, eta_val)
    x6 = np.empty(6)
    for i in range(6):
        x6[i] = xo[2, i]
    u = np.empty((1, 5))
    u[0, 0], u[0, 1], u[0, 2], u[0, 3], u[0, 4] = sp, n_rpm, p_a, t_a, t_cool
    out = np.empty(6)
    cac6 = predict_events(x6, u, horizon - 1, out, fc, c, cd_alpha, cd_table, prs, eta_rpm,
                          eta_val)
    return code, cac, cac6


def _ecu_signature() -> tuple:
    """ecu_event's one signature (kc: a filter's packed constants, 6 states)."""
    types, f8, i8, v, m, _ = signature_types()
    return (i8, v, m, m, m, f8[:, :, ::1], v) + (f8,) * 8 + (i8,) * 3 + (types.boolean, i8)


ecu_event.fix_signature(_ecu_signature)


def unpack_constants(kc: np.ndarray) -> tuple:
    """(fc, Q, fd, tables, lim) of pack_constants' array (views), as ecu_event reads them."""
    o = [int(v) for v in kc[:N_PARTS + 1]]
    nq, rows, cols = (int(v) for v in kc[N_PARTS + 1:HEADER])
    p = [kc[o[i]:o[i + 1]] for i in range(N_PARTS)]
    tables = (p[3], p[4], p[5].reshape((rows, cols)), p[6], p[7], p[8])
    return p[0], p[1].reshape((nq, nq)), p[2], tables, p[9]


_NO_AC = np.zeros(3)
_ALL = [0, 1, 2]


class CompiledEvents:
    """Needs the filter's state (x, P, P_post, x_post, _last_y, _last_u, _gated_run, gated,
    events, config, params, Q) and its step() / _reset_in_step()."""

    x: np.ndarray
    P: np.ndarray
    P_post: np.ndarray
    x_post: np.ndarray
    Q: np.ndarray
    config: Any
    params: Any
    events: int
    gated: list[int]
    _gated_run: list[int]
    _last_y: list[float]
    _last_u: EngineInput | None
    last_prediction: tuple[EngineInput, np.ndarray] | None
    _initialised: bool
    name: str

    def step(self, y: Any, u: EngineInput) -> np.ndarray:
        """The filter's own step (filters._ManifoldKF.step)."""
        raise NotImplementedError

    _kargs: tuple  # filter constants, Q, FD steps (, the adaptive constants), tables
    _KIND: int  # filter_events' kind

    def estimate(self, y0: float, y1: float, y2: float, u: EngineInput, horizon: int,
                 lap: Callable[[], float]) -> tuple[list[float], float, float, float, float,
                                                    float]:
        """The ECU's event: step((y0, y1, y2), u), the CAC at the posterior and predicted
        `horizon` events ahead with u held (the adaptive filter's eta correction applied):
        (posterior, CAC, CAC+horizon, the eta scale used, seconds in the filter, seconds in
        the prediction made apart). The usual event is one kernel call (event_cac: the
        prediction's time counted in the filter's); lap: the caller's Stopwatch.lap."""
        done = self.event_cac(y0, y1, y2, u, horizon)
        if done is not None:
            return self.x_post.tolist(), done[0], done[1], 1.0, lap(), 0.0
        x = self.step((y0, y1, y2), u).tolist()
        filter_s = lap()
        scale = 1.0
        if len(x) > 6:  # the adaptive filter's eta correction as the CAC uses it
            scale = float(self.eta_used(x[6], float(self.P_post[6, 6])))
        cac = scale * cylinder_air_charge(x[3], x[4], u.n_rpm, self.params)
        first = self.last_prediction  # the filter already ran event n+1 from x
        if first is not None and first[0] is u:
            cac6 = predict_cac(first[1], [u] * (horizon - 1), self.params, scale)
        else:
            cac6 = predict_cac(self.x_post, [u] * horizon, self.params, scale)
        return x, cac, cac6, scale, filter_s, lap()

    def eta_used(self, c: Any, var: Any) -> Any:
        """The eta correction the CAC uses (the adaptive filter's)."""
        raise NotImplementedError

    def event_cac(self, y0: float, y1: float, y2: float, u: EngineInput, horizon: int
                  ) -> tuple[float, float] | None:
        """step((y0, y1, y2), u), then (CAC at the posterior, cac_predict.predict_cac of the
        event map's output over horizon - 1 more events with u held), as one kernel call
        (ecu_event): the same state, counters and numbers as those calls. None (nothing
        changed): make them instead (the adaptive filter, an SDKF that solves the DARE, the
        first event, an input or reading the filter refuses, an event its kernel hands back or
        resets on)."""
        kind = self._ecu_kind
        if kind is None or not self._initialised:
            return None
        gr = self._gated_run
        xo = np.empty((3, len(self.x)))
        Po = np.empty((2, len(self.x), len(self.x)))
        try:
            code, cac, cac6 = ecu_event(kind, self.x, self.P, self.P_post, xo, Po,
                                        self._ecu_consts, u.ta_sp, u.n_rpm, u.p_a, u.t_a,
                                        u.t_cool, y0, y1, y2, gr[0], gr[1], gr[2],
                                        self.events >= 1, horizon)
        except (FloatingPointError, ValueError, ZeroDivisionError, np.linalg.LinAlgError):
            return None  # step() runs the event again and decides (a reset)
        if code & (FALLBACK | DIVERGED | NOT_TAKEN):
            return None
        # what step() does around the kernel for this event (input and readings all valid)
        self.events += 1
        self._last_u = u
        ly = self._last_y
        ly[0], ly[1], ly[2] = float(y0), float(y1), float(y2)
        self._count_gated(code, _ALL)
        self._commit_event(xo, Po, u)
        return cac, cac6

    _ecu_kind: int | None = None  # ecu_event's kind for this filter (None: it has none)
    _kc: np.ndarray | None = None

    @property
    def _ecu_consts(self) -> np.ndarray:
        """ecu_event's packed constants (computed on first use)."""
        if self._kc is None:
            fc, Q, fd, *tables = self._kargs
            self._kc = pack_constants(fc, Q, fd, tuple(tables), limits(self.config))
        return self._kc

    def _count_gated(self, code: int, chans: list[int]) -> None:
        """The gated / gated-in-a-row counters of the channels used, from a kernel's code."""
        gr = self._gated_run
        for i in chans:
            if code >> i & 1:
                self.gated[i] += 1
                gr[i] += 1
            else:
                gr[i] = 0

    def _commit_event(self, xo: np.ndarray, Po: np.ndarray, u: EngineInput) -> None:
        """Take a kernel's output: next prior (xo[0], Po[0]), posterior (xo[1], Po[1]) and the
        event map's output xo[2]."""
        self.x, self.x_post = xo[0], xo[1]
        self.P, self.P_post = Po[0], Po[1]
        self.last_prediction = (u, xo[2])

    def run_events(self, ys: np.ndarray, us: np.ndarray) -> np.ndarray:
        """step(ys[n], EngineInput(*us[n])) for every event n; the posteriors (events x states;
        their variances, the diagonal of P_post, in `self.run_variances` afterwards).
        ys: (events, 3) readings, us: (events, 5) inputs (TA_SP, N, P_a, T_a, T_cool). Under the
        numba backend runs of events go through one compiled call each (the same kernels, so
        the same numbers and counters as stepping); the events the kernels hand back (bad
        inputs, rejected readings, fallbacks, divergence) go through step()."""
        ys = np.ascontiguousarray(ys, dtype=np.float64)
        us = np.ascontiguousarray(us, dtype=np.float64)
        n_ev = len(ys)
        xs = np.empty((n_ev, len(self.x)))
        vs = np.empty((n_ev, len(self.x)))
        n = 0
        block = getattr(self.config, "riccati", "iterate") == "iterate"
        while n < n_ev:
            if block and self._initialised:
                n = self._run_block(ys, us, n, xs, vs)
                if n >= n_ev:
                    break
            xs[n] = self.step(ys[n].tolist(), EngineInput(*us[n].tolist()))
            vs[n] = np.diag(self.P_post)
            n += 1
        self.run_variances = vs
        return xs

    def _run_block(self, ys: np.ndarray, us: np.ndarray, start: int, xs: np.ndarray,
                   vs: np.ndarray) -> int:
        args = self._kargs
        lim = limits(self.config)
        x, P, P_post = self.x.copy(), self.P.copy(), self.P_post.copy()
        gr = np.array(self._gated_run, dtype=np.int64)
        gated = np.zeros(3, dtype=np.int64)
        last_pred = np.empty(len(x))
        kind = self._KIND
        ac = args[3] if kind == 2 else _NO_AC
        stop = filter_events(kind, x, P, P_post, ys, us, start, self.events, gr, gated,
                                      xs, vs, last_pred, lim, args[0], args[1], args[2], ac,
                                      *args[-6:])
        if stop == start:
            return start
        self.events += stop - start
        self.x, self.P, self.P_post = x, P, P_post
        self.x_post = xs[stop - 1].copy()
        self._gated_run = [int(v) for v in gr]
        for i in range(3):
            self.gated[i] += int(gated[i])
        self._last_y = ys[stop - 1].tolist()
        u = EngineInput(*us[stop - 1].tolist())
        self._last_u = u
        self.last_prediction = (u, last_pred)
        return stop
