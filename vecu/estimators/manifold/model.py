"""Filter-side augmented intake-manifold model (Dutka 2006, eq. 10-14 notation).

Built on the model's functions (vecu/models/manifold.py) and the filters' event pieces
(vecu/estimators/manifold/event.py: the SDC factorisation of eq. 7/10 and the Jacobian are
written there once, for the kernels); no equation is restated here.

State x = (u_prev, alpha, alpha_prev, P_im, T_im, T_im.meas) (eq. 10), output y = C x =
(TA, P_im, T_im.out) with C a row selection (indices 1, 3, 5). Units as the plant: rad, kPa, K.

- `f`, `h`: the plant's noise-free event map and output (the corrected, sub-stepped eq. 1, 5-6, 9).
- `f_and_jacobian`: f and F = df/dx. Actuator and IAT rows are analytic (linear, eq. 1 and 9);
  the manifold rows (d(P, T)_{n+1}/d(alpha, P, T)_n) are one-sided finite differences of the
  plant's event integrator, three extra calls, with the step direction flipped when a perturbation
  would change the integrator's sub-step count (so the difference never straddles a switch).
- `sdc_matrices`: A(x), B(x) of eq. 10 with the paper's A_IM, B_IM (eq. 7) built from eq. 5-6 with
  the corrected per-event pumping volume V_cyl; A(x) x + B(x) u is eq. 5-6 as printed (one Euler
  step) for the manifold rows and exactly eq. 1/9 for the others. The SDKF uses A(x) for its
  Riccati equation only (the throttle flow sits in the alpha column, so A_IM is stable at any
  opening); its mean goes through `f`.
- `q_matrix`, `r_matrix`: Section IV's Q and R (manifold_params.PAPER_NOISE).
"""

from __future__ import annotations

import numpy as np

from vecu.estimators.manifold.event import (
    ALPHA_SDC_MIN,  # noqa: F401 (re-exported)
    F_ALPHA_MIN,
    FD_ALPHA,
    FD_REL,
    coefficients,
    integrate_event,
    jacobian,
    kernel_tables,
    model_constants,
    sdc_matrix,
)
from vecu.models.manifold import N_STATE, sample_time
from vecu.models.manifold import f as plant_f
from vecu.models.manifold import h as plant_h
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


def event_dt(u: EngineInput, params: ManifoldParams = V8_5L7) -> float:
    """T_s = 120 / (8 N) for this event's engine speed."""
    return sample_time(u.n_rpm, params.n_cyl)


def f(x: np.ndarray, u: EngineInput, params: ManifoldParams = V8_5L7,
      dt: float | None = None) -> np.ndarray:
    """Noise-free event map of eq. 10 (the plant's `f`)."""
    return plant_f(x, u, params, dt)


def h(x: np.ndarray) -> np.ndarray:
    """y = C x = (TA, P_im, T_im.out) without noise (the plant's `h`)."""
    return plant_h(x)


def f_and_jacobian(x: np.ndarray, u: EngineInput, params: ManifoldParams = V8_5L7,
                   dt: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(f(x), df/dx) as the EKF's event computes them (event.jacobian: analytic actuator/IAT
    rows, finite-difference manifold block, see module)."""
    ts = event_dt(u, params) if dt is None else dt
    xp = np.array([float(v) for v in x])
    fc = model_constants(params)
    c, cd_alpha, cd_table, prs, eta_rpm, eta_val = tables(params)
    F = np.zeros((N_X, N_X))
    p_n, t_n, m = integrate_event(float(xp[3]), float(xp[4]), float(xp[1]), u.p_a, u.t_a,
                                  u.t_cool, u.n_rpm, ts, c, cd_alpha, cd_table, prs, eta_rpm,
                                  eta_val)
    jacobian(F, xp, p_n, t_n, m, coefficients(ts, fc), np.array([FD_ALPHA, FD_REL]), 0.0, 3,
             u.p_a, u.t_a, u.t_cool, u.n_rpm, ts, c, cd_alpha, cd_table, prs, eta_rpm, eta_val,
             cd_table, eta_val)
    return f(x, u, params, ts), F


def numerical_jacobian(x: np.ndarray, u: EngineInput, params: ManifoldParams = V8_5L7,
                       dt: float | None = None, rel: float = 1e-5) -> np.ndarray:
    """Central-difference df/dx over all six states (reference for tests; 12 calls of f)."""
    x = np.asarray(x, dtype=float)
    J = np.zeros((N_X, N_X))
    for j in range(N_X):
        d = rel * max(abs(x[j]), 1.0) if j in (3, 4, 5) else rel
        xp = x.copy()
        xm = x.copy()
        xp[j] += d
        xm[j] -= d
        J[:, j] = (f(xp, u, params, dt) - f(xm, u, params, dt)) / (2.0 * d)
    return J


def sdc_matrices(x: np.ndarray, u: EngineInput, params: ManifoldParams = V8_5L7,
                 dt: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(A(x), B(x)) of eq. 10 with the paper's SDC factorisation (eq. 7), per event.

    A_IM = [[1 - pi, (kappa-1) T_s Q_ext / (T_im V_im)],
            [0, 1 - (kappa-1)/kappa pi + (kappa-1) T_s Q_ext / (V_im P_im)]],
    B_IM = T_s mdot_at / alpha * [kappa R T_a / V_im, T_im (kappa R T_a - R T_im) / (V_im P_im)],
    pi = kappa eta N V_d T_s / (120 V_im) (= kappa V_cyl eta / V_im at T_s = 120/(8N)).
    B_IM C_ET goes into the alpha column of A (eq. 10); alpha >= ALPHA_SDC_MIN in the division.
    """
    ts = event_dt(u, params) if dt is None else dt
    fc = model_constants(params)
    A = np.zeros((N_X, N_X))
    co = coefficients(ts, fc)
    sdc_matrix(A, np.array([float(v) for v in x]), u.n_rpm, u.p_a, u.t_a, u.t_cool, ts, co,
               fc[F_ALPHA_MIN], *kernel_tables(params))
    return A, np.array([1.0, co[2], 0.0, 0.0, 0.0, 0.0])
