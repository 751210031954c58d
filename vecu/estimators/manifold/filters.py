"""Event-rate intake-manifold filters (Dutka 2006): EKF and the state-dependent Kalman filter.

Both run once per engine event (T_s = 120/(8N)) on the augmented model of eq. 10
(vecu/estimators/manifold_model.py): x = (u_prev, alpha, alpha_prev, P_im, T_im, T_im.meas),
y = (TA, P_im, T_im.out), Q and R of Section IV.

step(y, u) at event n: update with y_n (the measurement of x_n), store the posterior x_n|n
(returned), then predict x_n+1|n with the event's input u_n (setpoint TA_SP,n, N_n, P_a, T_a, T_cool).

- `ManifoldEKF`: recursive EKF; mean through the plant's sub-stepped event map f, F = df/dx at the
  posterior (manifold_model.f_and_jacobian), P = F P F^T + Q.
- `ManifoldSDKF`: eq. 12-14. Gain K_n = P_n C^T (C P_n C^T + R)^-1 with P_n from the Riccati
  equation of the SDC matrix A_n = A(x_n|n-1) (manifold_model.sdc_matrices). `riccati` selects
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

Under the numba backend (vecu.kernels) an "iterate" SDKF event after the input checks is one
compiled call (vecu.estimators.manifold.kernels.sdkf_event, bit-identical to this code here).
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
    diverged_floats,
    symmetrise,
)
from vecu.estimators.common.small_linalg import chol3, inverse_from_chol3
from vecu.estimators.manifold.compiled import CompiledEvents
from vecu.estimators.manifold.kernels import ekf_event, sdkf_event
from vecu.estimators.manifold.model import (
    N_X,
    Y_INDEX,
    event_dt,
    f,
    f_and_jacobian,
    q_matrix,
    r_matrix,
    sdc_matrices,
)
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
    if not lo <= u.n_rpm <= hi:
        return f"engine speed {u.n_rpm:g} rpm outside {lo:g}..{hi:g} rpm"
    if not -0.2 <= u.ta_sp <= 1.9:
        return f"throttle setpoint {u.ta_sp:g} rad outside -0.2..1.9 rad"
    if not (50.0 <= u.p_a <= 120.0 and 200.0 <= u.t_a <= 450.0 and 200.0 <= u.t_cool <= 450.0):
        return (f"ambient {u.p_a:g} kPa / {u.t_a:g} K or coolant {u.t_cool:g} K outside "
                "50..120 kPa / 200..450 K")
    return None


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
    """Shared measurement update, guards and counters (subclasses: prior covariance, predict);
    a manifold.base.ManifoldEstimator."""

    name = "base"

    def __init__(self, config: ManifoldFilterConfig = ManifoldFilterConfig(),
                 x0: np.ndarray | None = None) -> None:
        self.config = config
        c = config
        self.params = c.params
        self.Q = q_matrix(c.noise)
        self.R = r_matrix(c.noise)
        self._r_diag = np.diag(self.R).copy()
        self._r_diag_l = self._r_diag.tolist()
        self._P0 = np.diag(np.array(c.p0_diag, dtype=float))
        self._y_idx = np.array(Y_INDEX)
        self._full = np.array([0, 1, 2])
        if x0 is None:
            u0 = nominal_input(self.params.throttle_floor_rad(self.params.n_idle_rpm),
                               self.params.n_idle_rpm, self.params)
            x0 = steady_state_vector(u0, self.params)
        self._x_default = np.asarray(x0, dtype=float).copy()
        self._x_given = x0 is not None
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

    def _clamp(self, x: np.ndarray) -> None:
        c = self.config
        for i in (0, 1, 2):
            x[i] = min(max(x[i], c.alpha_box[0]), c.alpha_box[1])
        x[3] = min(max(x[3], c.p_box[0]), c.p_box[1])
        for i in (4, 5):
            x[i] = min(max(x[i], c.t_box[0]), c.t_box[1])

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
        self.x = np.array([ta, ta, ta, p, tm, tm])
        if self._last_u is not None:
            self.x[0] = self._last_u.ta_sp
        self.P = self._P0.copy()
        self._initialised = True

    def _update(self, P: np.ndarray, y, chans: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """Measurement update of the prior (self.x, P): (x_post, P_post). Gated channels dropped."""
        x = self.x.copy()
        if not chans:
            return x, P.copy()
        c = self.config
        yi = Y_INDEX
        xl = x.tolist()
        yl = [float(y[i]) for i in range(3)]
        gate2 = c.gate_sigma * c.gate_sigma
        use = []
        for i in chans:
            j = yi[i]
            e = yl[i] - xl[j]
            s = float(P[j, j]) + self._r_diag_l[i]
            if e * e > gate2 * s and self._gated_run[i] < c.max_gated_in_row:
                self.gated[i] += 1
                self._gated_run[i] += 1
            else:
                self._gated_run[i] = 0
                use.append(i)
        if not use:
            return x, P.copy()
        if len(use) == 3 and yi == (1, 3, 5):
            gain = self._gain_all(P)
            if gain is not None:  # the usual case: all three channels, S positive definite
                K, PCt = gain
                e3 = np.array([yl[0] - xl[1], yl[1] - xl[3], yl[2] - xl[5]])
                P_post = P - K @ PCt.T
                return x + K @ e3, 0.5 * (P_post + P_post.T)
        ch = self._full if len(use) == 3 else np.array(use)
        idx = self._y_idx[ch]
        PCt = P[:, idx]
        S = PCt[idx] + self.R[np.ix_(ch, ch)]
        L = cholesky_lower(S)
        Linv = np.linalg.inv(L)
        K = PCt @ (Linv.T @ Linv)
        e = np.array([yl[i] for i in ch]) - x[idx]
        x = x + K @ e
        P_post = symmetrise(P - K @ PCt.T)
        return x, P_post

    def _gain_all(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """(K, P C^T) for all three channels with S^-1 = L^-T L^-1 from an unrolled 3x3 Cholesky
        in plain floats (common.small_linalg: what cholesky_lower + inv do, without their per-call
        overhead); None when S is not finite or not positive definite (the general path then
        decides)."""
        PCt = P[:, 1::2]  # columns (1, 3, 5) = Y_INDEX
        (s00, _, _), (s10, s11, _), (s20, s21, s22) = (PCt[1::2] + self.R).tolist()
        if not math.isfinite(s00 + s10 + s11 + s20 + s21 + s22):
            return None
        ok, low = chol3.py((s00, s10, s20, s11, s21, s22))
        if not ok:
            return None
        i00, i01, i02, i11, i12, i22 = inverse_from_chol3.py(low)
        s_inv = np.array([[i00, i01, i02], [i01, i11, i12], [i02, i12, i22]])
        return PCt @ s_inv, PCt

    def _diverged(self, x: np.ndarray, P: np.ndarray) -> bool:
        """covariance.diverged's criterion, via diverged_floats (cheaper on a 6x6)."""
        return diverged_floats(x.tolist(), float(P.trace()), float(P.sum()), self.config.bounds)

    # ---------------------------------------------------------------- subclass hooks
    def _prior_cov(self, u: EngineInput, ts: float) -> np.ndarray:
        return self.P

    def _predict(self, x_post: np.ndarray, P_post: np.ndarray, u: EngineInput, ts: float) -> None:
        raise NotImplementedError

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

    def _event(self, y, u: EngineInput, ts: float, chans: list[int]) -> None:
        """The event after the input checks: prior covariance, update, guards, prediction."""
        try:
            P = self._prior_cov(u, ts)
            x_post, P_post = self._update(P, y, chans)
            self._clamp(x_post)
            if self._diverged(x_post, P_post):
                raise FloatingPointError("diverged")
            self.x_post, self.P_post = x_post, P_post
            self._predict(x_post, P_post, u, ts)
            if self._diverged(self.x, self.P):
                raise FloatingPointError("diverged")
        except (FloatingPointError, ValueError, np.linalg.LinAlgError):
            self._reset_in_step()

    def _reset_in_step(self) -> None:
        self.reset(count=True)
        self._initialised = True
        self.last_prediction = None

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
    """Recursive EKF on eq. 10 (see module docstring)."""

    name = "ekf"

    def _event(self, y, u: EngineInput, ts: float, chans: list[int]) -> None:
        """Under the numba backend one compiled call (kernels.ekf_event), see _compiled_event."""
        if not self._compiled_event(u, ts, chans):
            super()._event(y, u, ts, chans)

    def _call_kernel(self, args: tuple, xo: np.ndarray, Po: np.ndarray, u: EngineInput,
                     ts: float, mask: int) -> int:
        ly = self._last_y
        gr = self._gated_run
        return ekf_event.compiled(self.x, self.P, xo, Po, u.ta_sp, u.n_rpm, u.p_a, u.t_a,
                                  u.t_cool, ts, ly[0], ly[1], ly[2], mask, gr[0], gr[1], gr[2],
                                  args[0], args[1], args[2], *args[3:])

    def _predict(self, x_post: np.ndarray, P_post: np.ndarray, u: EngineInput, ts: float) -> None:
        x_n, F = f_and_jacobian(x_post, u, self.params, ts)
        self.last_prediction = (u, x_n.copy())
        self._clamp(x_n)
        self.x = x_n
        self.P = symmetrise(F @ P_post @ F.T + self.Q)


class ManifoldSDKF(_ManifoldKF):
    """State-dependent Kalman filter, eq. 12-14 (see module docstring for `riccati`)."""

    name = "sdkf"

    def __init__(self, config: ManifoldFilterConfig = ManifoldFilterConfig(),
                 x0: np.ndarray | None = None) -> None:
        if config.riccati not in RICCATI_MODES:
            raise ValueError(f"riccati must be one of {RICCATI_MODES}, got {config.riccati!r}")
        self.dare_failures = 0
        self.doublings = 0
        super().__init__(config, x0)
        self._C = np.zeros((3, N_X))
        for i, j in enumerate(Y_INDEX):
            self._C[i, j] = 1.0

    def _prior_cov(self, u: EngineInput, ts: float) -> np.ndarray:
        A, _ = sdc_matrices(self.x, u, self.params, ts)
        mode = self.config.riccati
        if mode == "iterate":
            if self.events > 1:  # one Riccati iteration from the previous event's posterior P
                self.P = symmetrise(A @ self.P_post @ A.T + self.Q)
            return self.P
        if mode == "scipy":
            try:
                P = scipy.linalg.solve_discrete_are(A.T, self._C.T, self.Q, self.R)
                if np.all(np.isfinite(P)):
                    self.P = symmetrise(P)
                    return self.P
            except (np.linalg.LinAlgError, ValueError):
                pass
            self.dare_failures += 1
        P, k = dare_doubling(A, self._C, self.Q, self.R, self.config.doubling_tol,
                             self.config.doubling_max_iter)
        self.doublings += k
        self.P = P
        return P

    def _event(self, y, u: EngineInput, ts: float, chans: list[int]) -> None:
        """Under the numba backend ("iterate" only) the whole event is one compiled call
        (vecu.estimators.manifold.kernels.sdkf_event), see _ManifoldKF._compiled_event."""
        if self.config.riccati != "iterate" or not self._compiled_event(u, ts, chans):
            super()._event(y, u, ts, chans)

    def _call_kernel(self, args: tuple, xo: np.ndarray, Po: np.ndarray, u: EngineInput,
                     ts: float, mask: int) -> int:
        ly = self._last_y
        gr = self._gated_run
        return sdkf_event.compiled(
            self.x, self.P, self.P_post, xo, Po, u.ta_sp, u.n_rpm, u.p_a, u.t_a, u.t_cool, ts,
            ly[0], ly[1], ly[2], mask, gr[0], gr[1], gr[2], self.events > 1, args[0], args[1],
            *args[3:])

    def _predict(self, x_post: np.ndarray, P_post: np.ndarray, u: EngineInput, ts: float) -> None:
        x_n = f(x_post, u, self.params, ts)
        self.last_prediction = (u, x_n.copy())
        self._clamp(x_n)
        self.x = x_n
