"""The paper's LQG/LTR design (Hernández 2005): eq. 24, eq. 25, eqs. 31/33 and the 2.41 dB peak."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from vecu.estimators.speed.lqg_design import (
    A_PAPER,
    AR_PAPER,
    B1_PAPER,
    BR_PAPER,
    C_PAPER,
    LoopStateSpace,
    controller_gain,
    kalman_continuous,
    kalman_discrete,
    lqr_continuous,
    lqr_discrete,
    paper_design,
    paper_lqr,
    paper_observer,
    sensitivity_peak,
)

K_LQR_EQ24 = np.array([[31.6188, 0.4999], [0.4999, 31.6346]])
KO_EQ25 = np.array([[1.0, 0.9913], [0.9913, 14.1071], [0.8687, 99.9962]])
A1_EQ33_ROWS = np.array([
    [-32.6188, -0.4912, -1.0, 1.0, 0.9913, 0.0],
    [-1.4912, -45.7417, 0.0, 0.9913, 14.1071, 0.0],
    [-0.8687, -99.9962, 0.0, 0.8687, 99.9962, 0.0],
])


def _sig4(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal to 4 significant digits (relative 5e-4 of each printed entry)."""
    return bool(np.all(np.abs(a - b) <= 5e-4 * np.abs(b) + 1e-12))


def test_eq24_lqr_gain() -> None:
    assert _sig4(paper_lqr(), K_LQR_EQ24)
    assert np.array_equal(controller_gain(paper_lqr())[:, 2], [1.0, 1.0])


def test_eq25_observer_gain_b2_reading() -> None:
    ko = paper_observer(100.0, "B2")
    assert _sig4(ko, KO_EQ25)  # max abs error 3.8e-5
    assert np.abs(ko - KO_EQ25).max() < 1e-4


def test_eq25_literal_reading_does_not_reproduce() -> None:
    ko = paper_observer(100.0, "B1")  # the textbook LTR: ~100 on the diagonal
    assert ko[0, 0] == pytest.approx(100.0, rel=1e-3) and ko[1, 1] == pytest.approx(100.0, rel=1e-3)
    assert not _sig4(ko, KO_EQ25)


def test_loop_matrix_eq33_and_denominator_eq31() -> None:
    d = paper_design()
    assert np.abs(d.loop.A[:3] - A1_EQ33_ROWS).max() < 1e-3
    # eq. 31 printed without its leading s^6: den = s^6 + 78.36 s^5 + 1490.44 s^4 + 109.38 s^3
    _, den = signal.ss2tf(d.loop.A, d.loop.B, d.loop.C, np.zeros((2, 2)), input=0)
    assert np.allclose(den[:4], [1.0, 78.36, 1490.44, 109.38], rtol=2e-4)
    assert np.allclose(den[4:], 0.0, atol=1e-6)


def test_sensitivity_peak_241_db() -> None:
    p = paper_design().peak
    assert p.db == pytest.approx(2.41, abs=0.005)
    assert p.value == pytest.approx(1.32, abs=0.005)
    assert 17.0 < p.w_rad_s < 20.0


def test_recovery_direction() -> None:
    # Literal LTR (noise at the plant input) recovers the LQR loop's 0 dB as q grows; the printed
    # (B2) reading does not: its peak rises with q beyond ~10.
    lit = [paper_design(q, "B1").peak.db for q in (10.0, 100.0, 1000.0)]
    b2 = [paper_design(q, "B2").peak.db for q in (10.0, 100.0, 1000.0)]
    assert lit[0] > lit[1] > lit[2] and lit[2] < 0.3
    assert b2[0] < b2[1] < b2[2]


def test_lqr_target_loop_has_unit_sensitivity() -> None:
    # Kalman inequality: an LQR loop has sigma_max(S) <= 1 (0 dB).
    p = sensitivity_peak(LoopStateSpace(AR_PAPER, BR_PAPER, paper_lqr()))
    assert p.db < 1e-3


def test_discrete_gains_match_continuous_limit() -> None:
    dt = 1e-5
    A, B = np.array([[0.0, 1.0], [0.0, 0.0]]), np.eye(2)
    Kd = lqr_discrete(np.eye(2) + dt * A, dt * B, dt * 1000.0 * np.eye(2), dt * np.eye(2))
    assert np.allclose(Kd, lqr_continuous(A, B, 1000.0 * np.eye(2), np.eye(2)), rtol=5e-3)
    W = 1e4 * np.diag([0.0, 0.0, 1.0])
    F = np.eye(3) + dt * A_PAPER + 0.5 * dt * dt * A_PAPER @ A_PAPER
    kd = kalman_discrete(F, C_PAPER, dt * W, np.eye(2) / dt)  # K_d / dt -> Ko as dt -> 0
    assert np.allclose(kd.gain / dt, kalman_continuous(A_PAPER, C_PAPER, W, np.eye(2)), rtol=1e-3)
    assert np.all(np.linalg.eigvalsh(kd.p_post) > 0.0)
    assert B1_PAPER.shape == (3, 2)
