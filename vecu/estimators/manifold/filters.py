"""Event-rate intake-manifold filters (Dutka 2006) on the augmented model of eq. 10: `ManifoldEKF`
(F = df/dx) and `ManifoldSDKF` (eq. 12-14; `riccati` "iterate", "doubling" or "scipy"), Q and R
of Section IV. step(y_n, u_n) updates, keeps x_n|n, predicts x_n+1|n; the event is one kernel
call (manifold.event). Guards and Riccati modes: docs/models.md, "Manifold estimators and CAC
prediction".
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import scipy.linalg

from vecu.estimators.common.covariance import (
    cholesky_lower,
    symmetrise,
)
from vecu.estimators.manifold.cac_predict import predict_cac
from vecu.estimators.manifold.event import (
    DIVERGED,
    FALLBACK,
    FD_ALPHA,
    FD_REL,
    apply_gain,
    ekf_event,
    ekf_finish,
    filter_constants,
    sdkf_event,
    sdkf_finish,
)
from vecu.estimators.manifold.model import (  # noqa: F401 (RICCATI_MODES, dare_doubling re-exported)
    C_MATRIX,
    MANIFOLD_BOUNDS,
    RICCATI_MODES,
    Y_INDEX,
    ManifoldFilterConfig,
    dare_doubling,
    input_problem,
    q_matrix,
    r_matrix,
    sdc_matrices,
)
from vecu.estimators.manifold.sequences import event_constants, filter_events
from vecu.models.manifold import (
    cylinder_air_charge,
    nominal_input,
    sample_time,
    steady_state_vector,
)
from vecu.models.manifold_integrator import tables
from vecu.models.manifold_params import (
    EngineInput,
)

_NO_AC = np.zeros(3)  # filter_events' adaptive constants for the other kinds
_NO_CAC = np.empty((0, 2))  # ... its CAC outputs without a horizon


class _ManifoldKF:
    """Shared guards, counters and the event's orchestration (subclasses: their event kernel);
    a manifold.base.ManifoldEstimator."""

    name = "base"

    def __init__(self, config: ManifoldFilterConfig = ManifoldFilterConfig(),
                 x0: np.ndarray | None = None) -> None:
        self.config = config
        c = config
        self.params = c.params
        self.Q = q_matrix(c.noise)
        self.R = r_matrix(c.noise)
        self._kargs = (filter_constants(c), self.Q, np.array([FD_ALPHA, FD_REL]),
                       *tables(self.params))
        self._P0 = np.diag(np.array(c.p0_diag, dtype=float))
        # a given x0 is the state; else the idle steady state until the first complete reading
        self._x_given = x0 is not None
        if x0 is None:
            u0 = nominal_input(self.params.throttle_floor_rad(self.params.n_idle_rpm),
                               self.params.n_idle_rpm, self.params)
            x0 = steady_state_vector(u0, self.params)
        self._x_default = np.asarray(x0, dtype=float).copy()
        self.events = self.missing = self.resets = self.bad_inputs = 0
        self.rejected = [0, 0, 0]  # per channel: NaN / out of range
        self.gated = [0, 0, 0]
        self._gated_run = [0, 0, 0]
        self._last_u: EngineInput | None = None
        self._last_y = [math.nan, math.nan, math.nan]
        self.last_prediction: tuple[EngineInput, np.ndarray] | None = None
        self.run_variances = np.empty((0, 0))  # run_events: the posterior variances per event
        self.reset(count=False)

    # ---------------------------------------------------------------- state handling
    def reset(self, count: bool = True) -> None:
        """Back to the prior: the last valid readings where there are any, P = P0."""
        if count:
            self.resets += 1
        x = self._x_default.copy()
        ta, p, tm = self._last_y
        if math.isfinite(ta):
            x[0] = x[1] = x[2] = ta
        if math.isfinite(p):
            x[3] = p
        if math.isfinite(tm):
            x[4] = x[5] = tm
        self.x = x  # prior x_n|n-1
        self.P = self._P0.copy()  # prior P_n|n-1 (EKF, SDKF "iterate")
        self.x_post = x.copy()
        self.P_post = self._P0.copy()
        self._initialised = self._x_given

    def _check_input(self, u: EngineInput) -> EngineInput:
        if input_problem(u, self.config) is None:
            self._last_u = u
            return u
        self.bad_inputs += 1
        if self._last_u is not None:
            return self._last_u
        prm = self.params
        return nominal_input(prm.throttle_floor_rad(prm.n_idle_rpm), prm.n_idle_rpm, prm)

    def _valid_channels(self, y) -> list[int]:
        if y is None:
            self.missing += 1
            return []
        out = []
        for i in range(3):
            try:
                v = float(y[i])
            except (TypeError, ValueError, IndexError):
                v = math.nan
            lo, hi = self.config.y_ranges[i]
            if lo <= v <= hi:  # NaN fails
                out.append(i)
                self._last_y[i] = v
            else:
                self.rejected[i] += 1
        if not out:
            self.missing += 1
        return out

    def _initialise(self, y, chans: list[int]) -> None:
        """First complete reading: state from the readings (u_prev from the setpoint)."""
        if self._initialised or len(chans) < 3:
            return
        ta, p, tm = (float(y[i]) for i in range(3))
        x = self._x_default.copy()  # parameter states beyond the sixth (adaptive) as at start
        x[:6] = (ta, ta, ta, p, tm, tm)
        self.x = x
        if self._last_u is not None:
            self.x[0] = self._last_u.ta_sp
        self.P = self._P0.copy()
        self._initialised = True

    # ---------------------------------------------------------------- the event
    _KERNELS: tuple[Any, Any] = (None, None)  # (event kernel, finish kernel) of the subclass
    _KIND = 0  # filter_events' kind
    _count_gated_on_reset = True  # the gated counters of an event that diverged still count
    _kargs: tuple  # the kernels' constants: filter constants, Q, FD steps (, ...), tables
    # what a failing event raises (the filter resets): non-finite or implausible numbers
    _EVENT_ERRORS: tuple[type[Exception], ...] = (FloatingPointError, ValueError,
                                                  np.linalg.LinAlgError)

    def _call_event(self, run: Any, args: tuple, xo: np.ndarray, Po: np.ndarray,
                    u: EngineInput, ts: float, mask: int) -> int:
        """The event kernel on the filter's prior (x, P); its status word."""
        ly = self._last_y
        gr = self._gated_run
        return run(self.x, self.P, xo, Po, u.ta_sp, u.n_rpm, u.p_a, u.t_a, u.t_cool, ts, ly[0],
                   ly[1], ly[2], mask, gr[0], gr[1], gr[2], *args)

    def _call_finish(self, run: Any, args: tuple, xo: np.ndarray, Po: np.ndarray,
                     u: EngineInput, ts: float, gated: int) -> int:
        """The subclass's finish kernel (after a fallback update); its status word."""
        raise NotImplementedError

    def _event(self, y, u: EngineInput, ts: float, chans: list[int]) -> None:
        """The event after the input checks: the subclass's event kernel, the fallback update
        when S needs jitter, then the counters, a reset or the new state."""
        run, finish = self._KERNELS
        args = self._kargs
        mask = 0
        for i in chans:
            mask |= 1 << i
        n = len(self.x)
        xo = np.empty((3, n))
        Po = np.empty((2, n, n))
        try:
            code = self._run_event(run, finish, args, xo, Po, u, ts, mask)
        except self._EVENT_ERRORS:
            self._reset_in_step()
            return
        if self._count_gated_on_reset or not code & DIVERGED:
            self._count_gated(code, chans)
        if code & DIVERGED:
            self._reset_in_step()
            return
        self._commit_event(xo, Po, u)

    def _run_event(self, run: Any, finish: Any, args: tuple, xo: np.ndarray, Po: np.ndarray,
                   u: EngineInput, ts: float, mask: int) -> int:
        code = self._call_event(run, args, xo, Po, u, ts, mask)
        if code & FALLBACK:
            code = self._fallback(finish, args, xo, Po, u, ts, mask, code)
        return code

    def _fallback(self, finish: Any, args: tuple, xo: np.ndarray, Po: np.ndarray,
                  u: EngineInput, ts: float, mask: int, code: int) -> int:
        """S = C P C^T + R was not positive definite for the kernel: factor it with
        covariance.cholesky_lower, then the same gain and the rest of the event."""
        gated = code & 7
        ch = [i for i in range(3) if mask >> i & 1 and not gated >> i & 1]
        prior = self._prior_of(Po)
        idx = [Y_INDEX[i] for i in ch]
        L = cholesky_lower(prior[np.ix_(idx, idx)] + self.R[np.ix_(ch, ch)])
        Linv = np.linalg.inv(L)
        ly = self._last_y
        apply_gain(self.x, prior, xo[1], Po[1], np.array(ly, dtype=np.float64),
                          np.array(ch, dtype=np.int64), len(ch), Linv.T @ Linv)
        return self._call_finish(finish, args, xo, Po, u, ts, gated)

    def _prior_of(self, Po: np.ndarray) -> np.ndarray:
        """The prior covariance the event's update used."""
        return self.P

    # ---------------------------------------------------------------- runs of events
    def estimate(self, y0: float, y1: float, y2: float, u: EngineInput, horizon: int,
                 lap: Callable[[], float]) -> tuple[list[float], float, float, float, float,
                                                    float]:
        """The ECU's event: step((y0, y1, y2), u) and the CAC now and `horizon` events ahead
        with u held (eta correction applied): (posterior, CAC, CAC+horizon, eta scale, seconds
        in the filter, seconds in the prediction). One filter_events call where it can, else
        step() and predict_cac, with the same numbers; lap: the caller's Stopwatch.lap."""
        if self._KIND != 2 and self._initialised and self._runs:
            ys, us, xs, vs, cacs = self._buffers
            ys[0, 0], ys[0, 1], ys[0, 2] = y0, y1, y2
            us[0, 0], us[0, 1], us[0, 2], us[0, 3], us[0, 4] = (u.ta_sp, u.n_rpm, u.p_a, u.t_a,
                                                                u.t_cool)
            try:
                done = self._run_block(ys, us, 0, xs, vs, horizon, cacs, u)
            except (FloatingPointError, ValueError, ZeroDivisionError, np.linalg.LinAlgError):
                done = 0  # step() runs the event again and decides (a reset)
            if done:
                c = cacs[0].tolist()
                return self.x_post.tolist(), c[0], c[1], 1.0, lap(), 0.0
        x = self.step((y0, y1, y2), u).tolist()
        filter_s = lap()
        scale = 1.0
        if len(x) > 6:  # the adaptive filter's eta correction as the CAC uses it
            scale = float(self.eta_used(x[6], float(self.P_post[6, 6])))  # type: ignore[attr-defined]  # ManifoldAdaptive's
        cac = scale * cylinder_air_charge(x[3], x[4], u.n_rpm, self.params)
        first = self.last_prediction  # the filter already ran event n+1 from x
        if first is not None and first[0] is u:
            cac6 = predict_cac(first[1], [u] * (horizon - 1), self.params, scale)
        else:
            cac6 = predict_cac(self.x_post, [u] * horizon, self.params, scale)
        return x, cac, cac6, scale, filter_s, lap()

    _runs = True  # whole runs of events go through filter_events (not the DARE modes)
    _consts: Any = None  # filter_events' constants (event_constants), on first use
    _counts: np.ndarray
    _bufs: tuple | None = None

    @property
    def _buffers(self) -> tuple:
        """estimate's arrays for filter_events over one event: ys, us, xs, vs, cacs."""
        if self._bufs is None:
            nx = len(self.x)
            self._bufs = (np.empty((1, 3)), np.empty((1, 5)), np.empty((1, nx)),
                          np.empty((1, nx)), np.empty((1, 2)))
        return self._bufs

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
        """Take a kernel's output: prior xo[0]/Po[0], posterior xo[1]/Po[1], event map xo[2]."""
        self.x, self.x_post = xo[0], xo[1]
        self.P, self.P_post = Po[0], Po[1]
        self.last_prediction = (u, xo[2])

    def run_events(self, ys: np.ndarray, us: np.ndarray) -> np.ndarray:
        """step(ys[n], EngineInput(*us[n])) for every event n: the posteriors (their variances
        in `run_variances`). Runs of events go through filter_events, the events it hands back
        through step(); same numbers and counters as stepping."""
        ys = np.ascontiguousarray(ys, dtype=np.float64)
        us = np.ascontiguousarray(us, dtype=np.float64)
        n_ev = len(ys)
        xs = np.empty((n_ev, len(self.x)))
        vs = np.empty((n_ev, len(self.x)))
        n = 0
        while n < n_ev:
            if self._runs and self._initialised:
                n = self._run_block(ys, us, n, xs, vs, 0, _NO_CAC)
                if n >= n_ev:
                    break
            xs[n] = self.step(ys[n].tolist(), EngineInput(*us[n].tolist()))
            vs[n] = np.diag(self.P_post)
            n += 1
        self.run_variances = vs
        return xs

    def _run_block(self, ys: np.ndarray, us: np.ndarray, start: int, xs: np.ndarray,
                   vs: np.ndarray, horizon: int, cacs: np.ndarray,
                   u: EngineInput | None = None) -> int:
        """filter_events from event start; the state, counters and last inputs (u: the last
        event's, as given) taken from the events it ran. Returns the first event not run."""
        kind = self._KIND
        if self._consts is None:
            args = self._kargs
            self._consts = event_constants(self.config, args[0], args[1], args[2],
                                           args[3] if kind == 2 else _NO_AC, args[-6:])
            self._counts = np.zeros((2, 3), dtype=np.int64)  # gated in a row, gated
        counts = self._counts
        gr, gated = counts
        gr[0], gr[1], gr[2] = self._gated_run
        gated[0] = gated[1] = gated[2] = 0
        x, P, P_post = self.x.copy(), self.P.copy(), self.P_post.copy()
        last_pred = np.empty(len(x))
        stop = filter_events(kind, x, P, P_post, ys, us, start, self.events, counts, xs, vs,
                             last_pred, self._consts, horizon, cacs)
        if stop == start:
            return start
        self.events += stop - start
        self.x, self.P, self.P_post = x, P, P_post
        self.x_post = xs[stop - 1].copy()
        self._gated_run = gr.tolist()
        g = self.gated
        g[0], g[1], g[2] = g[0] + int(gated[0]), g[1] + int(gated[1]), g[2] + int(gated[2])
        self._last_y = ys[stop - 1].tolist()
        self._last_u = u = EngineInput(*us[stop - 1].tolist()) if u is None else u
        self.last_prediction = (u, last_pred)
        return stop

    # ---------------------------------------------------------------- public
    def step(self, y: Sequence[Any] | None, u: EngineInput) -> np.ndarray:
        """One engine event: update with y_n (None: predict only), predict with u_n; the
        posterior x_n|n (a copy). `last_prediction`: (u, f(x_n|n, u)) before clamping, None
        after a reset."""
        self.events += 1
        self.last_prediction = None
        u = self._check_input(u)
        ts = sample_time(u.n_rpm, self.params.n_cyl)
        chans = self._valid_channels(y)
        self._initialise(y, chans)
        self._event(y, u, ts, chans)
        return self.x_post.copy()

    def _reset_in_step(self) -> None:
        self.reset(count=True)
        self._initialised = True
        self.last_prediction = None

    def reported_cov(self) -> np.ndarray:
        """The posterior covariance as reported: P_post x config.report_var_scale."""
        return self.P_post * self.config.report_var_scale

    @property
    def initialised(self) -> bool:
        """The state comes from measurements (a complete first reading, or the x0 given)."""
        return self._initialised

    @property
    def p_im(self) -> float:
        return float(self.x_post[3])

    @property
    def t_im(self) -> float:
        return float(self.x_post[4])

    @property
    def alpha(self) -> float:
        return float(self.x_post[1])


class ManifoldEKF(_ManifoldKF):
    """Recursive EKF on eq. 10 (see module docstring): event.ekf_event."""

    name = "ekf"
    _KERNELS = (ekf_event, ekf_finish)
    _KIND = 1

    def _call_finish(self, run: Any, args: tuple, xo: np.ndarray, Po: np.ndarray,
                     u: EngineInput, ts: float, gated: int) -> int:
        return run(xo, Po, u.ta_sp, u.n_rpm, u.p_a, u.t_a, u.t_cool, ts, gated, *args)


class ManifoldSDKF(_ManifoldKF):
    """State-dependent Kalman filter, eq. 12-14 (see module docstring for `riccati`):
    event.sdkf_event, the prior covariance of the DARE modes solved here."""

    name = "sdkf"
    _KERNELS = (sdkf_event, sdkf_finish)

    def __init__(self, config: ManifoldFilterConfig = ManifoldFilterConfig(),
                 x0: np.ndarray | None = None) -> None:
        if config.riccati not in RICCATI_MODES:
            raise ValueError(f"riccati must be one of {RICCATI_MODES}, got {config.riccati!r}")
        self.dare_failures = 0
        self.doublings = 0
        self._runs = config.riccati == "iterate"  # the DARE modes step event by event
        super().__init__(config, x0)

    def _dare_prior(self, u: EngineInput, ts: float) -> None:
        """self.P = the DARE solution of eq. 14 for A(x_n|n-1) ("doubling" or "scipy")."""
        A, _ = sdc_matrices(self.x, u, self.params, ts)
        if self.config.riccati == "scipy":
            try:
                P = scipy.linalg.solve_discrete_are(A.T, C_MATRIX.T, self.Q, self.R)
                if np.all(np.isfinite(P)):
                    self.P = symmetrise(P)
                    return
            except (np.linalg.LinAlgError, ValueError):
                pass
            self.dare_failures += 1
        self.P, k = dare_doubling(A, C_MATRIX, self.Q, self.R, self.config.doubling_tol,
                                  self.config.doubling_max_iter)
        self.doublings += k

    def _call_event(self, run: Any, args: tuple, xo: np.ndarray, Po: np.ndarray,
                    u: EngineInput, ts: float, mask: int) -> int:
        iterate = self.config.riccati == "iterate"
        if not iterate:
            self._dare_prior(u, ts)
        ly = self._last_y
        gr = self._gated_run
        return run(self.x, self.P, self.P_post, xo, Po, u.ta_sp, u.n_rpm, u.p_a, u.t_a,
                   u.t_cool, ts, ly[0], ly[1], ly[2], mask, gr[0], gr[1], gr[2],
                   iterate and self.events > 1, args[0], args[1], *args[3:])

    def _call_finish(self, run: Any, args: tuple, xo: np.ndarray, Po: np.ndarray,
                     u: EngineInput, ts: float, gated: int) -> int:
        return run(xo, Po, u.ta_sp, u.n_rpm, u.p_a, u.t_a, u.t_cool, ts, gated, args[0],
                   *args[3:])

    def _prior_of(self, Po: np.ndarray) -> np.ndarray:
        return Po[0]
