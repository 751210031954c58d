"""Filter-side augmented intake-manifold model (Dutka 2006, eq. 10-14 notation).

x = (u_prev, alpha, alpha_prev, P_im, T_im, T_im.meas) (eq. 10), y = C x = (TA, P_im, T_im.out),
C selects 1, 3, 5; rad, kPa, K. f and h are the plant's (vecu.models.manifold), F is
event.jacobian. `sdc_matrices`: A(x), B(x) of eq. 10 with the paper's A_IM, B_IM (eq. 7), for the
SDKF's Riccati equation only (its mean goes through f). `q_matrix`, `r_matrix`: Section IV's Q, R.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vecu.estimators.common.covariance import DivergenceBounds, symmetrise
from vecu.estimators.manifold.event import (
    ALPHA_SDC_MIN,  # noqa: F401 (re-exported)
    F_ALPHA_MIN,
    INPUT_OK,
    INPUT_SETPOINT,
    INPUT_SPEED,
    coefficients,
    input_fault,
    model_constants,
    sdc_matrix,
)
from vecu.models.manifold import N_STATE, sample_time
from vecu.models.manifold_integrator import tables
from vecu.models.manifold_params import (
    PAPER_NOISE,
    V8_5L7,
    EngineInput,
    ManifoldNoise,
    ManifoldParams,
)

N_X = N_STATE
N_Y = 3
Y_INDEX = (1, 3, 5)  # TA -> alpha, P_im -> P_im, T_im.out -> T_im.meas
C_MATRIX = np.zeros((N_Y, N_X))
for _i, _j in enumerate(Y_INDEX):
    C_MATRIX[_i, _j] = 1.0
C_MATRIX.setflags(write=False)


def q_matrix(noise: ManifoldNoise = PAPER_NOISE) -> np.ndarray:
    """Q = diag(cov w_ET, cov w_IM, cov w_im.meas) of Section IV (6x6)."""
    return np.diag(np.array(noise.q_diag(), dtype=float))


def r_matrix(noise: ManifoldNoise = PAPER_NOISE) -> np.ndarray:
    """R = diag(cov v_ET, cov v_IM, cov v_im.meas) of Section IV (3x3)."""
    return np.diag(np.array(noise.r_diag(), dtype=float))


def sdc_matrices(x: np.ndarray, u: EngineInput, params: ManifoldParams = V8_5L7,
                 dt: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(A(x), B(x)) of eq. 10 with the paper's SDC factorisation (eq. 7): event.sdc_matrix."""
    ts = sample_time(u.n_rpm, params.n_cyl) if dt is None else dt
    fc = model_constants(params)
    A = np.zeros((N_X, N_X))
    co = coefficients(ts, fc)
    sdc_matrix(A, np.array([float(v) for v in x]), u.n_rpm, u.p_a, u.t_a, u.t_cool, ts, co,
               fc[F_ALPHA_MIN], *tables(params))
    return A, np.array([1.0, co[2], 0.0, 0.0, 0.0, 0.0])


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
