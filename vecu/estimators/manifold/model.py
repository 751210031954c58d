"""Filter-side augmented intake-manifold model (Dutka 2006, eq. 10-14 notation).

Built on the model's pure functions (vecu/models/manifold.py); no equation is restated here except
the paper's own state-dependent-coefficient (SDC) factorisation of eq. 7/10, which the SDKF needs.

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

from vecu.models.manifold import (
    N_STATE,
    actuator_coeffs,
    heat_flow,
    iat_coeffs,
    integrate_manifold,
    sample_time,
    throttle_flow,
    volumetric_efficiency,
)
from vecu.models.manifold import f as plant_f
from vecu.models.manifold import h as plant_h
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

ALPHA_SDC_MIN = 1e-3  # rad: B_IM divides by alpha (eq. 7); below this the flow term is ~0 anyway

# Finite-difference steps for the manifold block of F (relative for P and T).
FD_ALPHA = 1e-6  # rad
FD_REL = 1e-6


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


def _manifold(p: float, t: float, alpha: float, u: EngineInput, ts: float,
              params: ManifoldParams) -> tuple[float, float, int]:
    return integrate_manifold(p, t, alpha, u, ts, params)


def f_and_jacobian(x: np.ndarray, u: EngineInput, params: ManifoldParams = V8_5L7,
                   dt: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(f(x), df/dx): analytic actuator/IAT rows, finite-difference manifold block (see module)."""
    ts = event_dt(u, params) if dt is None else dt
    u_prev, alpha, alpha_prev, p, t, tm = (float(v) for v in x)
    a1, a2, b1, b2 = actuator_coeffs(ts, params)
    a_t, b_t = iat_coeffs(ts, params)
    p_n, t_n, m = _manifold(p, t, alpha, u, ts, params)
    F = np.zeros((N_X, N_X))
    F[1, 0], F[1, 1], F[1, 2] = b2, a1, a2
    F[2, 1] = 1.0
    F[5, 4], F[5, 5] = b_t, a_t
    steps = (FD_ALPHA, FD_REL * max(abs(p), 1.0), FD_REL * max(abs(t), 1.0))
    for col, j in ((1, 0), (3, 1), (4, 2)):
        d = steps[j]
        for sign in (1.0, -1.0):
            args = [alpha, p, t]
            args[j] += sign * d
            pp, tt, mm = _manifold(args[1], args[2], args[0], u, ts, params)
            if mm == m:
                break
        F[3, col] = (pp - p_n) / (sign * d)
        F[4, col] = (tt - t_n) / (sign * d)
    x_n = np.array([
        u.ta_sp, a1 * alpha + a2 * alpha_prev + b1 * u.ta_sp + b2 * u_prev, alpha,
        p_n, t_n, a_t * tm + b_t * t,
    ])
    return x_n, F


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
    prm = params
    ts = event_dt(u, prm) if dt is None else dt
    _, alpha, _, p, t, _ = (float(v) for v in x)
    k, r, v = prm.kappa, prm.r_air, prm.v_im_dm3
    a1, a2, b1, b2 = actuator_coeffs(ts, prm)
    a_t, b_t = iat_coeffs(ts, prm)
    eta, _ = volumetric_efficiency(u.n_rpm, p, prm)
    mdot, _ = throttle_flow(alpha, p, u.p_a, u.t_a, prm)
    q = heat_flow(t, u.t_a, u.t_cool, prm)
    ps = max(p, 1e-3)
    ts_ = max(t, 1.0)
    pump = k * eta * u.n_rpm * prm.v_d_dm3 * ts / (120.0 * v)
    flow = ts * mdot / max(alpha, ALPHA_SDC_MIN)
    A = np.zeros((N_X, N_X))
    A[1, 0], A[1, 1], A[1, 2] = b2, a1, a2
    A[2, 1] = 1.0
    A[3, 1] = k * r * u.t_a * flow / v
    A[4, 1] = ts_ * (k * r * u.t_a - r * ts_) * flow / (v * ps)
    A[3, 3] = 1.0 - pump
    A[3, 4] = (k - 1.0) * ts * q / (ts_ * v)
    A[4, 4] = 1.0 - (k - 1.0) / k * pump + (k - 1.0) * ts * q / (v * ps)
    A[5, 4], A[5, 5] = b_t, a_t
    B = np.array([1.0, b1, 0.0, 0.0, 0.0, 0.0])
    return A, B
