"""The speed KF's 2 ms step as one kernel (vecu.kernels: compiled under numba, plain Python under
the python backend; one source). The model and its rules are in vecu.estimators.speed.kf's
docstring (Hernández 2005, eq. 25's fusion of wheel speed and accelerometer at 500 Hz).

State: one flat float sequence `s` (a numpy float64 array under numba, a list of Python floats
under the python backend), indexed by the constants below; tuning: `prm`, indexed likewise.
Counters are held as floats (exact integers). Squares of ratios are `x ** prm[SQUARE]` with
SQUARE = 2.0 read at run time: Python's x ** 2 is libm's pow, which numba would fold into x * x
(a different rounding in about one case in a thousand); min/max are written as the ternaries
Python's min/max evaluate. Only scalar IEEE arithmetic and libm pow: both backends give the same
bits.
"""

# ruff: noqa: FURB136 (x if c else y mirrors min()/max() exactly, NaN included, without a call)

from __future__ import annotations

from typing import Any

from vecu.estimators.common.covariance import diverged_scalars
from vecu.kernels import kernel

REACQUIRE_SAMPLES = 10  # 20 ms of readings >= reacquire_kmh before they are believed
MAX_GATED_IN_ROW = 25  # 50 ms of consecutive gated wheel readings, then believe the sensor

# s: state [v, a, b], P's upper triangle, mode flags and runs, counters
(V, A, B, P00, P01, P02, P11, P12, P22, INNOV_MEAN, WHEEL_INNOV_MEAN, NIS, HAS_NIS, INIT,
 GATED_RUN, REACQ_RUN, STILL, ABS, STEPS, MISSING_WHEEL, MISSING_ACCEL, REJECTED_WHEEL,
 REJECTED_ACCEL, GATED_WHEEL, IGNORED_WHEEL, RESETS) = range(26)
N_STATE = 26
# prm: tuning derived from SpeedFilterConfig (kf.SpeedKalmanFilter builds it)
(DT, Q00, Q01, Q11, Q22, R_A, SW2, SWMAX2, VREF, VMIN, VREACQ, STILL_ALPHA, ABOVE2, ABS_ALPHA,
 VSTILL, A_STILL, EXIT_P11, R_ZERO, R_STILL_A, GATE2, MAX_ACCEL, MAX_WHEEL, ABS_DECEL, ABS_INNOV,
 ABS_SLIP_STD, STILL_EXIT, P0_SPEED, P0_ACCEL, P0_OFFSET, MAX_TRACE, MAX_ABS_STATE, SQUARE
 ) = range(32)
N_PARAMS = 32


@kernel
def scalar_update3(x: tuple[float, float, float], p: tuple[float, ...],
                   h: tuple[float, float, float], e: float, r: float
                   ) -> tuple[tuple[float, float, float], tuple[float, ...]]:
    """Kalman update of a 3-state filter with one scalar measurement (plain floats).

    x: state, p: upper triangle (p00, p01, p02, p11, p12, p22) of P, h: the measurement row H,
    e: residual z - H x, r: measurement variance. c = P H^T, s = H c + r, x += c e / s,
    P -= c c^T / s.
    """
    p00, p01, p02, p11, p12, p22 = p
    h0, h1, h2 = h
    c0 = p00 * h0 + p01 * h1 + p02 * h2
    c1 = p01 * h0 + p11 * h1 + p12 * h2
    c2 = p02 * h0 + p12 * h1 + p22 * h2
    s = h0 * c0 + h1 * c1 + h2 * c2 + r
    y = e / s
    return ((x[0] + c0 * y, x[1] + c1 * y, x[2] + c2 * y),
            (p00 - c0 * c0 / s, p01 - c0 * c1 / s, p02 - c0 * c2 / s,
             p11 - c1 * c1 / s, p12 - c1 * c2 / s, p22 - c2 * c2 / s))


@kernel
def kf_reset(s: Any, prm: Any) -> None:
    """Back to the prior (counters kept; not counted as a divergence)."""
    s[V] = 0.0
    s[A] = 0.0
    s[B] = 0.0
    s[P00] = prm[P0_SPEED]
    s[P01] = 0.0
    s[P02] = 0.0
    s[P11] = prm[P0_ACCEL]
    s[P12] = 0.0
    s[P22] = prm[P0_OFFSET]
    s[INIT] = 0.0
    s[GATED_RUN] = 0.0
    s[REACQ_RUN] = 0.0
    s[STILL] = 0.0
    s[ABS] = 0.0
    s[INNOV_MEAN] = 0.0
    s[WHEEL_INNOV_MEAN] = 0.0
    s[NIS] = 0.0
    s[HAS_NIS] = 0.0


@kernel
def kf_step(s: Any, prm: Any, wheel_speed: float, has_wheel: bool, accel: float,
            has_accel: bool) -> tuple[float, float, float, float, float, float, bool, bool, bool]:
    """Predict 2 ms, then update with the accelerometer and the wheel speed (kf's docstring);
    a missing reading: has_* False. Returns (v, a, b, p00, p01, p11, initialised, standstill,
    abs_mode) after the step."""
    s[STEPS] += 1.0
    dt = prm[DT]
    p00, p01, p02, p11, p12, p22 = s[P00], s[P01], s[P02], s[P11], s[P12], s[P22]
    # Predict: F = [[1, dt, 0], [0, 1, 0], [0, 0, 1]].
    v = s[V] + s[A] * dt
    a = s[A]
    b = s[B]
    p00 = p00 + dt * (2.0 * p01 + dt * p11) + prm[Q00]
    p01 = p01 + dt * p11 + prm[Q01]
    p02 = p02 + dt * p12
    p11 = p11 + prm[Q11]
    p22 = p22 + prm[Q22]
    initialised = s[INIT] != 0.0
    standstill = s[STILL] != 0.0
    abs_mode = s[ABS] != 0.0

    # Accelerometer: H = [0, 1, 1].
    if not has_accel:
        s[MISSING_ACCEL] += 1.0
    elif not -prm[MAX_ACCEL] <= accel <= prm[MAX_ACCEL]:  # NaN fails too
        s[REJECTED_ACCEL] += 1.0
    else:
        e = accel - a - b
        s[INNOV_MEAN] += prm[STILL_ALPHA] * (e - s[INNOV_MEAN])
        (v, a, b), (p00, p01, p02, p11, p12, p22) = scalar_update3(
            (v, a, b), (p00, p01, p02, p11, p12, p22), (0.0, 1.0, 1.0), e, prm[R_A])

    # Wheel speed: H = [1, 0, 0].
    used = False
    s[HAS_NIS] = 0.0
    sw2, swmax2, vref = prm[SW2], prm[SWMAX2], prm[VREF]
    if not has_wheel:
        s[MISSING_WHEEL] += 1.0
    elif not 0.0 <= wheel_speed <= prm[MAX_WHEEL]:
        s[REJECTED_WHEEL] += 1.0
    elif not initialised:
        # the first reading initialises the filter (issue 30): v = reading, its variance the
        # sensor's at that speed (a 0 reading: at rest or below ~5 km/h, sigma_wheel_max)
        v = wheel_speed
        if wheel_speed > 0.0:
            r = sw2 * (vref / wheel_speed) ** prm[SQUARE] if wheel_speed < vref else sw2
            p00 = swmax2 if swmax2 < r else r  # min(r, swmax2)
        else:
            p00 = swmax2
        p01 = p02 = 0.0
        initialised = True
        standstill = False
        used = True
    elif not ((wheel_speed >= prm[VREACQ] and s[REACQ_RUN] >= REACQUIRE_SAMPLES)
              or (v >= prm[VMIN] and wheel_speed > 0.0)):
        # Gate on the estimate, not the reading: dropping readings below a threshold would
        # bias the accepted ones upwards near it. Reacquisition (and the first reading) needs
        # REACQUIRE_SAMPLES high readings in a row: at 2 km/h the noise alone reaches 15 km/h.
        s[REACQ_RUN] = s[REACQ_RUN] + 1.0 if wheel_speed >= prm[VREACQ] else 0.0
        s[IGNORED_WHEEL] += 1.0
    else:
        standstill = False
        used = True
        vh = v if v > 0.001 else 0.001  # max(0.001, v)
        r = sw2 * (vref / vh) ** prm[SQUARE] if vh < vref else sw2
        r = swmax2 if swmax2 < r else r  # min(r, swmax2)
        e = wheel_speed - v
        s[WHEEL_INNOV_MEAN] += prm[ABS_ALPHA] * (e - s[WHEEL_INNOV_MEAN])
        abs_mode = a < -prm[ABS_DECEL] and s[WHEEL_INNOV_MEAN] < -prm[ABS_INNOV]
        if abs_mode:  # ABS slip pulls the wheel below the car: trust the upper envelope
            if e < 0.0:
                ds = prm[ABS_SLIP_STD] * vh
                r += ds * ds
            else:
                r *= prm[ABOVE2]
        sv = p00 + r
        if e * e > prm[GATE2] * sv and s[GATED_RUN] < MAX_GATED_IN_ROW:
            s[GATED_RUN] += 1.0
            s[GATED_WHEEL] += 1.0
        else:
            s[GATED_RUN] = 0.0
            s[NIS] = e * e / sv
            s[HAS_NIS] = 1.0
            (v, a, b), (p00, p01, p02, p11, p12, p22) = scalar_update3(
                (v, a, b), (p00, p01, p02, p11, p12, p22), (1.0, 0.0, 0.0), e, r)

    # Before the first wheel reading the speed means nothing (validity init): no standstill,
    # no v = 0 pseudo-measurement (it would make the prior's sigma look tiny).
    if not initialised:
        v = 0.0
    # Standstill: entered when v_hat would go negative with no usable wheel reading; left on
    # a usable wheel reading or a sustained accelerometer innovation (the car moves off).
    elif standstill and s[INNOV_MEAN] > prm[STILL_EXIT]:
        standstill = False  # moving off: let a find the accelerometer quickly
        a = s[INNOV_MEAN]
        p11 += prm[EXIT_P11]
    elif not used and not standstill and (
            v + a * dt <= 0.0 or (v < prm[VSTILL] and -prm[A_STILL] < a < prm[A_STILL])):
        standstill = True
        s[INNOV_MEAN] = 0.0
        abs_mode = False
    # Constraint v >= 0 / zero-velocity update: pseudo-measurement v = 0, then clip.
    if initialised and (v < 0.0 or standstill):
        (_, a, b), (p00, p01, p02, p11, p12, p22) = scalar_update3(
            (v, a, b), (p00, p01, p02, p11, p12, p22), (1.0, 0.0, 0.0), -v, prm[R_ZERO])
        v = 0.0
        if standstill:  # at rest a = 0 too: accelerometer readings go to b
            (_, _, b), (p00, p01, p02, p11, p12, p22) = scalar_update3(
                (v, a, b), (p00, p01, p02, p11, p12, p22), (0.0, 1.0, 0.0), -a,
                prm[R_STILL_A])
            a = 0.0
            v = 0.0  # both pinned at rest (the update moves v by ~1e-5 m/s)
    s[INIT] = 1.0 if initialised else 0.0
    s[STILL] = 1.0 if standstill else 0.0
    s[ABS] = 1.0 if abs_mode else 0.0

    if (diverged_scalars((v, a, b), p00 + p11 + p22, p01 + p02 + p12, prm[MAX_TRACE],
                         prm[MAX_ABS_STATE])
            or p00 <= 0.0 or p11 <= 0.0 or p22 <= 0.0):
        s[RESETS] += 1.0
        kf_reset(s, prm)
    else:
        s[V], s[A], s[B] = v, a, b
        s[P00], s[P01], s[P02], s[P11], s[P12], s[P22] = p00, p01, p02, p11, p12, p22
    return (s[V], s[A], s[B], s[P00], s[P01], s[P11], s[INIT] != 0.0, s[STILL] != 0.0,
            s[ABS] != 0.0)
