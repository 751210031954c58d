"""Event-rate intake-manifold filters (Dutka 2006): EKF and the state-dependent Kalman filter.

Both run once per engine event (T_s = 120/(8N)) on the augmented model of eq. 10
(vecu/estimators/manifold/model.py): x = (u_prev, alpha, alpha_prev, P_im, T_im, T_im.meas),
y = (TA, P_im, T_im.out), Q and R of Section IV.

step(y, u) at event n: update with y_n (the measurement of x_n), store the posterior x_n|n
(returned), then predict x_n+1|n with the event's input u_n (setpoint TA_SP,n, N_n, P_a, T_a, T_cool).

- `ManifoldEKF`: recursive EKF; mean through the plant's sub-stepped event map f, F = df/dx at the
  posterior (model.f_and_jacobian; event.ekf_event), P = F P F^T + Q.
- `ManifoldSDKF`: eq. 12-14. Gain K_n = P_n C^T (C P_n C^T + R)^-1 with P_n from the Riccati
  equation of the SDC matrix A_n = A(x_n|n-1) (event.sdc_matrix). `riccati` selects
  how P_n is obtained:
    "iterate"  (default, live): ONE Riccati iteration per event, warm-started from the previous
               event: P_n = A_n (P_n-1 - K_n-1 S_n-1 K_n-1^T) A_n^T + Q. For a frozen A it
               converges to the DARE solution; A(x) moves slowly against that convergence, so the
               gain is the same (docs/models.md, "Manifold estimators").
    "doubling" the DARE of eq. 14 solved per event to convergence by the structure-preserving
               doubling algorithm (quadratic convergence, 5-10 doublings; equals scipy to ~1e-12).
    "scipy"    the DARE per event by scipy.linalg.solve_discrete_are (the paper's way; ms/event).
  The mean goes through the same f as the EKF, not A x + B u (eq. 12 as printed is one explicit
  Euler step of eq. 5-6, which diverges at large openings: docs/models.md, "Intake manifold").

Guards (shared): y=None (or an all-invalid y) -> predict only; each channel that is NaN or outside
its plausible range is rejected and counted, the others are used; innovations beyond gate_sigma are
gated (at most max_gated_in_row in a row per channel); bad inputs u (NaN, absurd N) are replaced by
the last good input and counted; the posterior state is clamped to a physical box; P is
symmetrised and S = C P C^T + R factored with vecu.estimators.common.covariance.cholesky_lower; a
non-finite or exploding state/covariance (covariance.diverged) resets the filter and is counted.
No input can make the outputs NaN.

The event after the input checks is one call of a kernel written once in
vecu.estimators.manifold.event (sdkf_event, ekf_event): compiled under the numba backend, its
Python function under the python backend; the classes here keep the orchestration (input checks,
counters, resets, the DARE of the "doubling" / "scipy" modes, the jittered fallback update).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.linalg

from vecu.estimators.common.covariance import (
    DivergenceBounds,
    cholesky_lower,
    symmetrise,
)
from vecu.estimators.manifold.event import (
    DIVERGED,
    FALLBACK,
    FD_ALPHA,
    FD_REL,
    INPUT_OK,
    INPUT_SETPOINT,
    INPUT_SPEED,
    apply_gain,
    ekf_event,
    ekf_finish,
    filter_constants,
    input_fault,
    kernel_tables,
    sdkf_event,
    sdkf_finish,
)
from vecu.estimators.manifold.model import (
    C_MATRIX,
    Y_INDEX,
    event_dt,
    q_matrix,
    r_matrix,
    sdc_matrices,
)
from vecu.estimators.manifold.runs import CompiledEvents
from vecu.models.manifold import nominal_input, steady_state_vector
from vecu.models.manifold_params import (
    PAPER_NOISE,
    V8_5L7,
    EngineInput,
    ManifoldNoise,
    ManifoldParams,
)

RICCATI_MODES = ("iterate", "doubling", "scipy")
MANIFOLD_BOUNDS = DivergenceBounds(max_trace=1e5, max_abs_state=1e4)


@dataclass(frozen=True)
class ManifoldFilterConfig:
    """Model, noise, guards. Ranges are (lo, hi) in the model's units (rad, kPa, K, rpm)."""

    params: ManifoldParams = V8_5L7
    noise: ManifoldNoise = PAPER_NOISE
    riccati: str = "iterate"  # SDKF only, see RICCATI_MODES
    # Prior variances (u_prev, alpha, alpha_prev, P_im, T_im, T_im.meas) at start and after a reset.
    p0_diag: tuple[float, ...] = (1e-4, 1e-3, 1e-3, 4.0, 100.0, 1.0)
    # Plausible measurement ranges (TA, P_im, T_im.out): readings outside are rejected.
    y_ranges: tuple[tuple[float, float], ...] = ((-0.2, 1.9), (1.0, 200.0), (200.0, 450.0))
    # State box (alpha and u_prev, P_im, T_im and T_im.meas) applied to the posterior.
    alpha_box: tuple[float, float] = (-0.1, 1.9)
    p_box: tuple[float, float] = (1.0, 200.0)
    t_box: tuple[float, float] = (200.0, 500.0)
    n_range: tuple[float, float] = (300.0, 9000.0)  # plausible engine speed for an input
    gate_sigma: float = 10.0  # per-channel innovation gate (normalised)
    # the reported covariance (reported_cov: sigmas for the bus, NEES) is P_post x this: model
    # error the matched Q leaves out (calibration errors, docs/models.md "Consistency")
    report_var_scale: float = field(default=1.3, metadata={"bounds": (1.0, 100.0)})
    max_gated_in_row: int = 20  # then the channel is believed again (a real step, not a spike)
    doubling_tol: float = 1e-12
    doubling_max_iter: int = 40
    bounds: DivergenceBounds = field(default_factory=lambda: MANIFOLD_BOUNDS)
    # adaptive filter only: corrections c (eta) and c_th (throttle flow), random walks
    eta_q: float = 1e-9  # variance of c's and c_th's step per event
    eta_p0: float = 2.5e-3  # prior variance of c and c_th (sigma 5 %)
    eta_box: tuple[float, float] = (0.7, 1.3)  # c and c_th are clamped here
    eta_pr_freeze: float = 0.9  # c, c_th not learned above this P_im / P_a
    eta_alpha_gate: float = 2.0  # nor while |TA innovation| exceeds this many sigma
    # ... and the angle sensor's gain g (TA = g alpha) and the actuator's k_zeta, k_omega
    ta_gain_p0: float = 4e-4  # prior variance of g (sigma 2 %)
    ta_gain_box: tuple[float, float] = (0.9, 1.1)
    act_p0: float = 2.5e-3  # prior variance of k_zeta and k_omega (sigma 5 %)
    act_box: tuple[float, float] = (0.85, 1.15)
    act_q: float = 0.0  # variance of g's, k_zeta's and k_omega's step per event
    # the eta correction the CAC uses: c averaged with "calibrated engine" (spike and slab):
    # the prior probability that eta differs from the calibration, and by how much (sd of c)
    eta_drift_prior: float = field(default=0.1, metadata={"bounds": (0.0, 1.0)})
    eta_slab_sd: float = field(default=0.02, metadata={"bounds": (1e-4, 0.5)})  # sd of c then


def input_problem(u: EngineInput, config: ManifoldFilterConfig) -> str | None:
    """Why an event's input is implausible (None: plausible): engine speed outside `n_range`,
    setpoint outside [-0.2, 1.9] rad, ambient or coolant conditions outside physical bounds.
    The filter holds its last plausible input instead; the ECU refuses the event (NaN fails)."""
    lo, hi = config.n_range
    fault = input_fault(u.ta_sp, u.n_rpm, u.p_a, u.t_a, u.t_cool, lo, hi)
    if fault == INPUT_OK:
        return None
    if fault == INPUT_SPEED:
        return f"engine speed {u.n_rpm:g} rpm outside {lo:g}..{hi:g} rpm"
    if fault == INPUT_SETPOINT:
        return f"throttle setpoint {u.ta_sp:g} rad outside -0.2..1.9 rad"
    return (f"ambient {u.p_a:g} kPa / {u.t_a:g} K or coolant {u.t_cool:g} K outside "
            "50..120 kPa / 200..450 K")


def dare_doubling(A: np.ndarray, C: np.ndarray, Q: np.ndarray, R: np.ndarray,
                  tol: float = 1e-12, max_iter: int = 40) -> tuple[np.ndarray, int]:
    """Prior covariance P of the filter DARE P = A P A^T - A P C^T (C P C^T + R)^-1 C P A^T + Q
    (eq. 14) by the structure-preserving doubling algorithm (Chu, Fan, Lin 2005) on the dual
    (control) form: A_0 = A^T, G_0 = C^T R^-1 C, H_0 = Q;
    W = I + G H, A' = A W^-1 A, G' = G + A W^-1 G A^T, H' = H + A^T H W^-1 A; H -> P.
    Returns (P, doublings)."""
    n = A.shape[0]
    eye = np.eye(n)
    a = A.T.copy()
    g = C.T @ np.linalg.solve(R, C)
    hh = Q.copy()
    for k in range(1, max_iter + 1):
        w = eye + g @ hh
        wa = np.linalg.solve(w, a)  # W^-1 A
        wg = np.linalg.solve(w, g)  # W^-1 G
        h_new = hh + a.T @ hh @ wa
        g = g + a @ wg @ a.T
        a = a @ wa
        if np.abs(h_new - hh).max() <= tol * max(np.abs(h_new).max(), 1e-300):
            return symmetrise(h_new), k
        hh = h_new
    return symmetrise(hh), max_iter


class _ManifoldKF(CompiledEvents):
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
                       *kernel_tables(self.params))
        self._P0 = np.diag(np.array(c.p0_diag, dtype=float))
        # a given x0 is the state; else the idle steady state until the first complete reading
        # initialises it (_initialise; before issue 30 x0 was always "given": 25 kPa at start)
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
    _KIND = 0  # filter_events' kind (runs.KINDS)
    _count_gated_on_reset = True  # the gated counters of an event that diverged still count
    _kargs: tuple  # the kernels' constants: filter constants, Q, FD steps (, ...), tables
    # what a failing event raises (the filter resets): non-finite or implausible numbers
    _EVENT_ERRORS: tuple[type[Exception], ...] = (FloatingPointError, ValueError,
                                                  np.linalg.LinAlgError)

    def _call_event(self, run: Any, args: tuple, xo: np.ndarray, Po: np.ndarray,
                    u: EngineInput, ts: float, mask: int) -> int:
        """The event kernel on the filter's prior (x, P) (ekf_event's and adaptive_event's
        arguments; the SDKF's differ); its status word."""
        ly = self._last_y
        gr = self._gated_run
        return run(self.x, self.P, xo, Po, u.ta_sp, u.n_rpm, u.p_a, u.t_a, u.t_cool, ts, ly[0],
                   ly[1], ly[2], mask, gr[0], gr[1], gr[2], *args)

    def _call_finish(self, run: Any, args: tuple, xo: np.ndarray, Po: np.ndarray,
                     u: EngineInput, ts: float, gated: int) -> int:
        """The subclass's finish kernel (after a fallback update); its status word."""
        raise NotImplementedError

    def _event(self, y, u: EngineInput, ts: float, chans: list[int]) -> None:
        """The event after the input checks: one call of the subclass's event kernel (prior
        covariance, update, guards, prediction), a fallback update when S needs jitter, then
        the counters, a reset or the new state."""
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
        """S = C P C^T + R of the channels used was not positive definite (or not finite) for
        the kernel: factor it with covariance.cholesky_lower (jitter, then eigenvalue clipping;
        ValueError when not finite), then the same gain and the rest of the event."""
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

    # ---------------------------------------------------------------- public
    def step(self, y: Sequence[Any] | None, u: EngineInput) -> np.ndarray:
        """One engine event: update with y_n (None: predict only), predict with u_n.
        Returns the posterior x_n|n (a copy). Afterwards `last_prediction` is (u, f(x_n|n, u))
        with the event map's output before clamping, or None when the step reset the filter
        (lets a caller that runs the same model ahead from x_n|n skip that first event)."""
        self.events += 1
        self.last_prediction = None
        u = self._check_input(u)
        ts = event_dt(u, self.params)
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
    _ecu_kind = 1  # runs.KIND_EKF

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
        self._ecu_kind = 0 if config.riccati == "iterate" else None  # runs.KIND_SDKF
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
