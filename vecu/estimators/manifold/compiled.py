"""The manifold filters' compiled events (numba backend): one event per kernel call
(kernels.sdkf_event / ekf_event, bit-identical to the numpy path), runs of events per call
(block_kernels.filter_events) and the ECU manifold function's usual event with its CAC and
6-event prediction in one call (event_cac: event_kernel.ecu_event). A mixin of
filters._ManifoldKF; the python backend never uses it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from vecu.estimators.manifold.block_kernels import filter_events, limits
from vecu.estimators.manifold.event_kernel import (
    NOT_TAKEN,
    ecu_event,
    kernel_kind,
    pack_constants,
)
from vecu.estimators.manifold.event_kernel import prepare as prepare_ecu_event
from vecu.estimators.manifold.kernels import (
    DIVERGED,
    FALLBACK,
    filter_constants,
    numba_tables,
    sdkf_event,
)
from vecu.estimators.manifold.kernels import prepare as prepare_kernels
from vecu.estimators.manifold.model import ALPHA_SDC_MIN, FD_ALPHA, FD_REL, N_X
from vecu.kernels import backend
from vecu.models.manifold_params import EngineInput

_SDKF_EVENT_PY = sdkf_event.py
KINDS = {"sdkf": 0, "ekf": 1, "adaptive": 2}  # block_kernels.filter_events' kind
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

    _kernel_args: tuple | None = None  # filter constants, Q, FD steps and tables, on first use
    _kernel_args_ready = False

    def _call_kernel(self, args: tuple, xo: np.ndarray, Po: np.ndarray, u: EngineInput,
                     ts: float, mask: int) -> int:
        """The subclass's compiled event (kernels.sdkf_event / ekf_event); its status word."""
        raise NotImplementedError

    def _compiled_event(self, u: EngineInput, ts: float, chans: list[int]) -> bool:
        """The event after the input checks as one compiled call under the numba backend
        (bit-identical to the Python path). False: run the Python path instead (python backend,
        a parameter set the kernels do not take, or the rare event the kernel hands back: S not
        positive definite or not finite, where the Python path decides as it always did)."""
        if sdkf_event.impl() is _SDKF_EVENT_PY:
            return False
        args = self._kernel_args
        if args is None:
            if self._kernel_args_ready:
                return False
            args = self._prepare_kernel()
            if args is None:
                return False
        mask = 0
        for i in chans:
            mask |= 1 << i
        xo = np.empty((3, N_X))
        Po = np.empty((2, N_X, N_X))
        try:
            code = self._call_kernel(args, xo, Po, u, ts, mask)
        except (FloatingPointError, ValueError, np.linalg.LinAlgError):
            self._reset_in_step()
            return True
        if code & FALLBACK:
            return False
        self._count_gated(code, chans)
        if code & DIVERGED:
            self._reset_in_step()
            return True
        self._commit_event(xo, Po, u)
        return True

    def event_cac(self, y0: float, y1: float, y2: float, u: EngineInput, horizon: int
                  ) -> tuple[float, float] | None:
        """step((y0, y1, y2), u), then (CAC at the posterior, cac_predict.predict_cac of the
        event map's output over horizon - 1 more events with u held), as one compiled call
        (event_kernel.ecu_event) under the numba backend: the same state, counters and numbers
        as those calls. None (nothing changed): make them instead (python backend, the adaptive
        filter, the first event, an input or reading the filter refuses, an event its kernel
        hands back or resets on)."""
        if backend() != "numba" or not self._initialised:
            return None
        run = self._ecu_run
        if run is None:
            if self._ecu_checked or not self._prepare_ecu_event():
                return None
            run = self._ecu_run
        gr = self._gated_run
        xo = np.empty((3, len(self.x)))
        Po = np.empty((2, len(self.x), len(self.x)))
        try:
            code, cac, cac6 = run(self._ecu_kind, self.x, self.P, self.P_post, xo, Po,
                                  self._ecu_consts, u.ta_sp, u.n_rpm, u.p_a, u.t_a, u.t_cool,
                                  y0, y1, y2, gr[0], gr[1], gr[2], self.events >= 1, horizon)
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

    _ecu_run: Any = None  # event_kernel.ecu_event's dispatcher once prepared
    _ecu_kind: int | None = None
    _ecu_checked = False
    _ecu_consts: np.ndarray

    def _prepare_ecu_event(self) -> bool:
        """First use of event_cac: the kernel's kind and packed constants (False: none)."""
        self._ecu_checked = True
        kind = kernel_kind(self)
        if kind is None:
            return False
        tables = numba_tables(self.params)
        if tables is None:
            return False
        self._ecu_consts = pack_constants(
            filter_constants(self.config, ALPHA_SDC_MIN), self.Q, np.array([FD_ALPHA, FD_REL]),
            tables, limits(self.config))
        prepare_ecu_event(self._ecu_consts)
        self._ecu_kind = kind
        self._ecu_run = ecu_event.compiled
        return True

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

    def _prepare_kernel(self) -> tuple | None:
        self._kernel_args_ready = True
        tables = numba_tables(self.params)
        if tables is None:
            return None
        prepare_kernels()
        fd = np.array([FD_ALPHA, FD_REL])
        self._kernel_args = (filter_constants(self.config, ALPHA_SDC_MIN), self.Q, fd, *tables)
        return self._kernel_args

    def _block_ready(self) -> bool:
        """Whole runs of events may go through block_kernels.filter_events."""
        if getattr(self.config, "riccati", "iterate") != "iterate" or not self._initialised:
            return False
        if sdkf_event.impl() is _SDKF_EVENT_PY:
            return False
        if self._kernel_args is not None:
            return True
        return not self._kernel_args_ready and self._prepare_kernel() is not None

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
        while n < n_ev:
            if self._block_ready():
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
        args = self._kernel_args
        assert args is not None
        lim = limits(self.config)
        x, P, P_post = self.x.copy(), self.P.copy(), self.P_post.copy()
        gr = np.array(self._gated_run, dtype=np.int64)
        gated = np.zeros(3, dtype=np.int64)
        last_pred = np.empty(len(x))
        kind = KINDS[self.name]
        ac = args[3] if kind == 2 else _NO_AC
        stop = filter_events.compiled(kind, x, P, P_post, ys, us, start, self.events, gr, gated,
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
