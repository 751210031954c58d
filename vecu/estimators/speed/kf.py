"""ECU speed/acceleration filter at 500 Hz: Kalman filter on [v, a, b] in plain floats.

The paper (Hernández 2005) fuses a wheel-speed sensor and an accelerometer with the steady-state
observer of eq. 25 on [speed, acceleration, jerk] (continuous V = I: a ~1 Hz observer, see
docs/models.md). This is the practical 500 Hz version of the same fusion:

  x = [v, a, b]: speed (m/s), longitudinal acceleration (m/s^2, random walk driven by white jerk
  of intensity q_jerk), accelerometer offset b (slow random walk; the paper cancels it "by
  software techniques", Section 4).
  Predict (dt = 2 ms): v += a dt;  P = F P F^T + Q  (Q: integrated white jerk on [v, a]).
  Wheel speed z_w = v + n_w, std scheduled: sigma_w * max(1, v_ref / v_hat), raised during hard
  braking with the wheel persistently below the car (ABS slip: then readings below v_hat get a
  huge std, i.e. the filter follows the upper envelope); readings are used only while
  v_hat >= min_wheel_kmh (dropouts read 0, the sensor is useless below 5 km/h, Section 2.2.2)
  or when far above it (reacquire_kmh, REACQUIRE_SAMPLES in a row). The first reading in range
  initialises v (its variance the sensor's at that speed); until then the filter is not
  initialised (speed 0 with the prior's variance, no standstill: validity init on the bus).
  Accelerometer z_a = a + b + n_a.
  Standstill: the car does not reverse, so v < 0 is corrected by a pseudo-measurement v = 0
  and clipped. With no usable wheel reading, the filter enters standstill when v_hat would cross
  0 this step, or is below still_enter_kmh with |a_hat| small; there it applies v = 0 and a = 0
  every step (zero-velocity update: the accelerometer then teaches b, the paper's offset
  cancelling, and the 1-2 Hz pitch ringing is not taken for acceleration). It leaves on a usable
  wheel reading or when the 50 ms mean accelerometer innovation exceeds still_exit_mps2.

Inputs: None = missing (predict only, counted); non-finite or outside the plausible range =
rejected (counted); wheel innovations beyond gate_sigma are gated out, at most MAX_GATED_IN_ROW
in a row. Divergence (vecu.estimators.common.covariance.diverged_scalars) resets to the prior and
counts. One step is one kernel, kf_kernel.kf_step (compiled under numba, plain Python otherwise).
Nothing the inputs contain can make the outputs NaN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from vecu.estimators.common.covariance import DivergenceBounds
from vecu.estimators.speed import kf_kernel as K
from vecu.estimators.speed.kf_kernel import (  # noqa: F401 (this module's names)
    MAX_GATED_IN_ROW,
    REACQUIRE_SAMPLES,
    kf_reset,
    kf_step,
    scalar_update3,
)
from vecu.kernels import backend
from vecu.units import MPS_PER_KMH

DT_S = 0.002
SPEED_BOUNDS = DivergenceBounds(max_trace=1e4, max_abs_state=1e3)


@dataclass(frozen=True)
class SpeedFilterConfig:
    """Tuning (docs/models.md, 'Vehicle speed and acceleration'). Sensor figures are the
    datasheet-like values the plant also uses: a matched model."""

    dt_s: float = DT_S
    q_jerk: float = 10.0  # white-jerk intensity, (m/s^3)^2 / Hz
    q_offset: float = 1e-4  # accelerometer-offset random walk, (m/s^2)^2 / s
    sigma_wheel_mps: float = 0.35
    wheel_ref_kmh: float = 10.0  # std grows as 1/v below this
    sigma_wheel_max_mps: float = 2.0
    min_wheel_kmh: float = 6.0  # wheel speed used only while v_hat >= this ...
    reacquire_kmh: float = 15.0  # ... or the reading is >= this (recovers a v_hat stuck low)
    sigma_accel_mps2: float = 0.6
    abs_decel_mps2: float = 6.5  # a_hat below -abs_decel: hard braking, ABS slip possible
    abs_slip_std: float = 1.0  # ABS mode: extra std (fraction of v_hat) of readings below v_hat
    abs_above_factor: float = 1.5  # ABS mode: std factor for readings above v_hat
    abs_innov_mps: float = 0.2  # ABS mode: hard braking and mean wheel innovation below -this
    abs_tau_s: float = 0.1  # time constant of that mean
    still_enter_kmh: float = 1.0  # standstill entered below this with no usable wheel reading
    zero_speed_std_mps: float = 0.01  # pseudo-measurement v = 0 when v_hat < 0 / at standstill
    still_exit_mps2: float = 0.6  # leave standstill when the 50 ms mean accel innovation exceeds
    still_tau_s: float = 0.05
    still_accel_std_mps2: float = 0.05  # pseudo-measurement a = 0 at standstill
    still_enter_accel_mps2: float = 0.5  # ... entered below still_enter_kmh only if |a_hat| <
    gate_sigma: float = 6.0  # wheel innovation gate, in innovation std
    max_wheel_mps: float = 100.0  # plausible-input ranges
    max_accel_mps2: float = 25.0
    p0_speed: float = 100.0  # prior variances (x0 = [0, 0, 0], or the first wheel reading)
    p0_accel: float = 4.0
    p0_offset: float = 0.25
    # Floors of the *reported* std (speed_std_mps, accel_std_mps2, reported_va_cov; the filter's
    # own P and gains are untouched), for what the model leaves out (docs/models.md, "Consistency"):
    still_speed_floor_mps: float = 0.1  # at rest the car may still be creeping / finishing its stop
    still_accel_floor_mps2: float = 1.5  # ... or braking its last centimetres, or moving off
    coast_speed_floor_mps: float = 0.1  # below min_wheel_kmh, wheel unused: v from the accelerometer
    abs_speed_floor_mps: float = 0.25  # ABS mode: the envelope rule's bias (slip model) ...
    abs_accel_floor_mps2: float = 1.5  # ... and the deceleration it follows


_numba_ready = False


def _fix_numba_signature() -> None:
    """kf_step's one signature, compiled or loaded from numba's cache, then no further
    compilation: an int or numpy-scalar reading is converted to float64."""
    global _numba_ready
    if not _numba_ready:
        from numba import types

        f8, b1 = types.float64, types.boolean
        kf_step.fix_signature((f8[::1], f8[::1], f8, b1, f8, b1))
        _numba_ready = True


class SpeedKalmanFilter:
    """step(wheel_speed_mps | None, accel_mps2 | None) every 2 ms; see the module docstring. A
    speed.base.SpeedEstimator.

    Outputs: speed_mps, accel_mps2 (offset-corrected), offset_mps2 and their std. Counters:
    steps, missing_wheel, missing_accel, rejected_wheel, rejected_accel (NaN / out of range),
    gated_wheel (innovation gate), ignored_wheel (not used at low speed), resets.
    standstill: True while the filter holds the car at rest (zero-velocity updates).
    abs_mode: True while hard braking with a wheel persistently below the car (ABS slip).
    """

    def __init__(self, config: SpeedFilterConfig = SpeedFilterConfig()) -> None:
        c = self.config = config
        dt = c.dt_s
        q = c.q_jerk
        prm = [0.0] * K.N_PARAMS
        for i, val in (
                (K.DT, dt), (K.Q00, q * dt ** 3 / 3.0), (K.Q01, q * dt * dt / 2.0),
                (K.Q11, q * dt), (K.Q22, c.q_offset * dt), (K.R_A, c.sigma_accel_mps2 ** 2),
                (K.SW2, c.sigma_wheel_mps ** 2), (K.SWMAX2, c.sigma_wheel_max_mps ** 2),
                (K.VREF, c.wheel_ref_kmh * MPS_PER_KMH), (K.VMIN, c.min_wheel_kmh * MPS_PER_KMH),
                (K.VREACQ, c.reacquire_kmh * MPS_PER_KMH), (K.STILL_ALPHA, dt / c.still_tau_s),
                (K.ABOVE2, c.abs_above_factor ** 2), (K.ABS_ALPHA, dt / c.abs_tau_s),
                (K.VSTILL, c.still_enter_kmh * MPS_PER_KMH),
                (K.A_STILL, c.still_enter_accel_mps2), (K.EXIT_P11, c.p0_accel),
                (K.R_ZERO, c.zero_speed_std_mps ** 2),
                (K.R_STILL_A, c.still_accel_std_mps2 ** 2), (K.GATE2, c.gate_sigma ** 2),
                (K.MAX_ACCEL, c.max_accel_mps2), (K.MAX_WHEEL, c.max_wheel_mps),
                (K.ABS_DECEL, c.abs_decel_mps2), (K.ABS_INNOV, c.abs_innov_mps),
                (K.ABS_SLIP_STD, c.abs_slip_std), (K.STILL_EXIT, c.still_exit_mps2),
                (K.P0_SPEED, c.p0_speed), (K.P0_ACCEL, c.p0_accel), (K.P0_OFFSET, c.p0_offset),
                (K.MAX_TRACE, SPEED_BOUNDS.max_trace),
                (K.MAX_ABS_STATE, SPEED_BOUNDS.max_abs_state), (K.SQUARE, 2.0)):
            prm[i] = float(val)
        self._vmin = prm[K.VMIN]
        # the backend at construction: numpy arrays for the compiled step, lists of Python
        # floats for the plain-Python one (same kernel source, same bits)
        self._step: Any = kf_step.impl()
        if backend() == "numba":
            _fix_numba_signature()
            self._s: Any = np.zeros(K.N_STATE)
            self._prm: Any = np.array(prm)
        else:
            self._s = [0.0] * K.N_STATE
            self._prm = prm
        self.reset()

    def reset(self) -> None:
        """Back to the prior (not counted as a divergence); the next usable wheel reading
        initialises the speed."""
        kf_reset.py(self._s, self._prm)
        self._out()

    def _out(self) -> None:
        s = self._s
        self.v, self.a, self.b = float(s[K.V]), float(s[K.A]), float(s[K.B])
        self._p00, self._p01, self._p11 = float(s[K.P00]), float(s[K.P01]), float(s[K.P11])
        self._initialised = s[K.INIT] != 0.0
        self.standstill = bool(s[K.STILL] != 0.0)
        self.abs_mode = bool(s[K.ABS] != 0.0)

    @property
    def p(self) -> list[float]:
        """P's upper triangle (p00, p01, p02, p11, p12, p22)."""
        s = self._s
        return [float(s[i]) for i in (K.P00, K.P01, K.P02, K.P11, K.P12, K.P22)]

    @property
    def wheel_nis(self) -> float | None:
        """e^2 / s of this step's wheel update (None: none)."""
        return float(self._s[K.NIS]) if self._s[K.HAS_NIS] != 0.0 else None

    def _count(self, i: int) -> int:
        return int(self._s[i])

    steps = property(lambda self: self._count(K.STEPS))
    missing_wheel = property(lambda self: self._count(K.MISSING_WHEEL))
    missing_accel = property(lambda self: self._count(K.MISSING_ACCEL))
    rejected_wheel = property(lambda self: self._count(K.REJECTED_WHEEL))
    rejected_accel = property(lambda self: self._count(K.REJECTED_ACCEL))
    gated_wheel = property(lambda self: self._count(K.GATED_WHEEL))
    ignored_wheel = property(lambda self: self._count(K.IGNORED_WHEEL))
    resets = property(lambda self: self._count(K.RESETS))

    # ------------------------------------------------------------------ outputs
    @property
    def speed_mps(self) -> float:
        return self.v

    @property
    def accel_mps2(self) -> float:
        return self.a

    @property
    def offset_mps2(self) -> float:
        return self.b

    def reported_va_cov(self) -> tuple[float, float, float]:
        """(var v, cov(v, a), var a) as reported: P's (v, a) block with the std floors of the
        mode the filter is in (standstill, coasting below the wheel threshold, ABS), the
        correlation kept."""
        p00, p01, p11 = self._p00, self._p01, self._p11
        c = self.config
        fv = fa = 0.0
        if self.standstill:
            fv, fa = c.still_speed_floor_mps, c.still_accel_floor_mps2
        elif self.abs_mode:
            fv, fa = c.abs_speed_floor_mps, c.abs_accel_floor_mps2
        elif self.v < self._vmin:
            fv = c.coast_speed_floor_mps
        sv = math.sqrt(max(p00, fv * fv) / p00) if p00 > 0.0 else 1.0
        sa = math.sqrt(max(p11, fa * fa) / p11) if p11 > 0.0 else 1.0
        return p00 * sv * sv, p01 * sv * sa, p11 * sa * sa

    @property
    def initialised(self) -> bool:
        """The first wheel-speed reading has initialised the speed (before: validity init)."""
        return self._initialised

    @property
    def speed_std_mps(self) -> float:
        return math.sqrt(self.reported_va_cov()[0])

    @property
    def accel_std_mps2(self) -> float:
        return math.sqrt(self.reported_va_cov()[2])

    # ------------------------------------------------------------------ step
    def step(self, wheel_speed: float | None, accel: float | None) -> None:
        """Predict 2 ms, then update with the accelerometer and the wheel speed (kf_step)."""
        (self.v, self.a, self.b, self._p00, self._p01, self._p11, self._initialised,
         self.standstill, self.abs_mode) = self._step(
            self._s, self._prm, 0.0 if wheel_speed is None else wheel_speed,
            wheel_speed is not None, 0.0 if accel is None else accel, accel is not None)
