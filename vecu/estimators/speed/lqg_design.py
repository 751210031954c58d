"""LQR / Kalman / LQG-LTR design, written once with scipy (Hernández 2005, eqs. 12-25, 32-37).

- `lqr_continuous`, `lqr_discrete`: state-feedback gains from the control AREs (eqs. 14-15).
- `kalman_continuous`, `kalman_discrete`: steady-state observer gains from the filter AREs
  (eqs. 16-17); the discrete one is the *a-priori*-covariance form with its posterior gain.
- `paper_lqr`, `paper_observer`, `paper_design`: the paper's numbers. K_LQR (eq. 24) from eq. 14
  with Ar, Br, Q, R of eqs. 18-23; K_C = [K_LQR, 1]. Ko (eq. 25) only reproduces with the
  fictitious noise q^2 B2 B2^T alone (`recovery="B2"`, the default); the literal eq. 16
  (B2 W1 B2^T + q^2 B1 W2 B1^T, `recovery="B1"`) is the textbook LTR at the plant input and gives
  Ko ~ 100 on the diagonal instead (docs/models.md).
- `loop_state_space`: L(s) of eqs. 32-36, the loop broken at the plant input.
- `sensitivity_peak`: max over w of sigma_max(S(jw)), S = (I + L)^-1 (eq. 37), in dB.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_continuous_are, solve_discrete_are
from scipy.optimize import minimize_scalar

# Eqs. 6-11, 18-23.
A_PAPER = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])
B1_PAPER = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])
B2_PAPER = np.array([[0.0], [0.0], [1.0]])
C_PAPER = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
AR_PAPER = np.array([[0.0, 1.0], [0.0, 0.0]])
BR_PAPER = np.eye(2)
Q_PAPER = 1000.0 * np.eye(2)
R_PAPER = np.eye(2)
V_PAPER = np.eye(2)
Q_LTR_PAPER = 100.0  # the recovery parameter q of eq. 25


def lqr_continuous(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray) -> np.ndarray:
    """K = R^-1 B^T Pi with A^T Pi + Pi A + Q - Pi B R^-1 B^T Pi = 0 (eqs. 14-15)."""
    Pi = solve_continuous_are(A, B, Q, R)
    return np.linalg.solve(R, B.T @ Pi)


def lqr_discrete(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray) -> np.ndarray:
    """K = (R + B^T P B)^-1 B^T P A for u_k = -K x_k, P from the discrete control ARE."""
    P = solve_discrete_are(A, B, Q, R)
    return np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)


def kalman_continuous(A: np.ndarray, C: np.ndarray, W: np.ndarray, V: np.ndarray) -> np.ndarray:
    """Ko = Theta C^T V^-1 with A Theta + Theta A^T + W - Theta C^T V^-1 C Theta = 0 (16-17).

    W is the whole process-noise intensity as it enters the state (e.g. B2 W1 B2^T + ...).
    """
    Theta = solve_continuous_are(A.T, C.T, W, V)
    return Theta @ C.T @ np.linalg.inv(V)


@dataclass(frozen=True)
class DiscreteKalman:
    """Steady-state discrete Kalman filter: gain K (posterior), a-priori / a-posteriori P."""

    gain: np.ndarray
    p_prior: np.ndarray
    p_post: np.ndarray


def kalman_discrete(F: np.ndarray, H: np.ndarray, Qd: np.ndarray, Rd: np.ndarray) -> DiscreteKalman:
    """x_{k+1} = F x_k + w (cov Qd), z_k = H x_k + v (cov Rd): steady-state K = P H^T S^-1."""
    P = solve_discrete_are(F.T, H.T, Qd, Rd)
    S = H @ P @ H.T + Rd
    K = P @ H.T @ np.linalg.inv(S)
    Pp = (np.eye(F.shape[0]) - K @ H) @ P
    return DiscreteKalman(gain=K, p_prior=0.5 * (P + P.T), p_post=0.5 * (Pp + Pp.T))


def paper_lqr() -> np.ndarray:
    """K_LQR of eq. 24 (2 x 2): eq. 14 with Ar, Br (18-19), Q, R (22-23)."""
    return lqr_continuous(AR_PAPER, BR_PAPER, Q_PAPER, R_PAPER)


def controller_gain(k_lqr: np.ndarray) -> np.ndarray:
    """K_C = [K_LQR, (1, 1)^T] (2 x 3): the LQR plus the unit gain vector (text after eq. 23)."""
    return np.hstack([k_lqr, np.ones((k_lqr.shape[0], 1))])


def paper_observer(q: float = Q_LTR_PAPER, recovery: str = "B2") -> np.ndarray:
    """Ko (3 x 2) from eq. 16 with V = I.

    recovery="B2": process noise q^2 B2 B2^T alone; reproduces the printed eq. 25 at q = 100.
    recovery="B1": literal eq. 16, B2 B2^T + q^2 B1 B1^T (W1, W2 = identities of the sizes that
    make eq. 16 conform; the printed W = I3 does not), i.e. fictitious noise at the plant input.
    """
    if recovery == "B2":
        W = q * q * (B2_PAPER @ B2_PAPER.T)
    elif recovery == "B1":
        W = B2_PAPER @ B2_PAPER.T + q * q * (B1_PAPER @ B1_PAPER.T)
    else:
        raise ValueError("recovery must be 'B2' or 'B1'")
    return kalman_continuous(A_PAPER, C_PAPER, W, V_PAPER)


@dataclass(frozen=True)
class LoopStateSpace:
    """L(s) = C (sI - A)^-1 B (D = 0), eqs. 32-36."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray


def loop_state_space(
    k_c: np.ndarray, k_o: np.ndarray, A: np.ndarray = A_PAPER, B1: np.ndarray = B1_PAPER,
    C: np.ndarray = C_PAPER,
) -> LoopStateSpace:
    """Loop broken at the plant input: compensator K_C (sI - A + B1 K_C + Ko C)^-1 Ko after the
    plant C (sI - A)^-1 B1. Compensator states first (eq. 33's order)."""
    n = A.shape[0]
    m = B1.shape[1]
    a_comp = A - B1 @ k_c - k_o @ C
    AL = np.block([[a_comp, k_o @ C], [np.zeros((n, n)), A]])
    BL = np.vstack([np.zeros((n, m)), B1])
    CL = np.hstack([k_c, np.zeros((k_c.shape[0], n))])
    return LoopStateSpace(AL, BL, CL)


def sigma_max_sensitivity(loop: LoopStateSpace, w: float) -> float:
    """sigma_max(S(jw)), S = (I + L(jw))^-1 (eq. 37)."""
    n = loop.A.shape[0]
    L = loop.C @ np.linalg.solve(1j * w * np.eye(n) - loop.A, loop.B)
    S = np.linalg.inv(np.eye(L.shape[0]) + L)
    return float(np.linalg.svd(S, compute_uv=False)[0])


@dataclass(frozen=True)
class SensitivityPeak:
    """Peak of sigma_max(S(jw)): value, in dB (20 log10), and where (rad/s)."""

    value: float
    db: float
    w_rad_s: float


def sensitivity_peak(
    loop: LoopStateSpace, w_min: float = 1e-3, w_max: float = 1e4, points: int = 2000,
) -> SensitivityPeak:
    """Grid search on a log grid, then a bounded refinement around the best grid point."""
    ws = np.logspace(math.log10(w_min), math.log10(w_max), points)
    vals = [sigma_max_sensitivity(loop, float(w)) for w in ws]
    i = int(np.argmax(vals))
    lo = math.log10(ws[max(i - 1, 0)])
    hi = math.log10(ws[min(i + 1, points - 1)])
    best_w, best = float(ws[i]), float(vals[i])
    if hi > lo:
        res = minimize_scalar(
            lambda lw: -sigma_max_sensitivity(loop, 10.0 ** lw), bounds=(lo, hi),
            method="bounded", options={"xatol": 1e-6},
        )
        if -res.fun > best:
            best, best_w = float(-res.fun), float(10.0 ** res.x)
    return SensitivityPeak(value=best, db=20.0 * math.log10(best), w_rad_s=best_w)


@dataclass(frozen=True)
class PaperDesign:
    """The paper's LQG/LTR design: K_LQR (24), K_C, Ko (25), the loop (32-36), its peak (37)."""

    k_lqr: np.ndarray
    k_c: np.ndarray
    k_o: np.ndarray
    loop: LoopStateSpace
    peak: SensitivityPeak


def paper_design(q: float = Q_LTR_PAPER, recovery: str = "B2") -> PaperDesign:
    """Whole design at recovery parameter q (q = 100, "B2": the printed numbers)."""
    k_lqr = paper_lqr()
    k_c = controller_gain(k_lqr)
    k_o = paper_observer(q, recovery)
    loop = loop_state_space(k_c, k_o)
    return PaperDesign(k_lqr, k_c, k_o, loop, sensitivity_peak(loop))
