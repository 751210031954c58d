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
in a row. Divergence (vecu.estimators.common.covariance.diverged_floats) resets to the prior and counts.
Nothing the inputs contain can make the outputs NaN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from vecu.estimators.common.covariance import DivergenceBounds, diverged_floats
from vecu.units import MPS_PER_KMH

DT_S = 0.002
REACQUIRE_SAMPLES = 10  # 20 ms of readings >= reacquire_kmh before they are believed
MAX_GATED_IN_ROW = 25  # 50 ms of consecutive gated wheel readings, then believe the sensor
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
        self._dt = dt
        q = c.q_jerk
        self._q00, self._q01, self._q11 = q * dt ** 3 / 3.0, q * dt * dt / 2.0, q * dt
        self._q22 = c.q_offset * dt
        self._r_a = c.sigma_accel_mps2 ** 2
        self._sw2 = c.sigma_wheel_mps ** 2
        self._swmax2 = c.sigma_wheel_max_mps ** 2
        self._vref = c.wheel_ref_kmh * MPS_PER_KMH
        self._vmin = c.min_wheel_kmh * MPS_PER_KMH
        self._vreacq = c.reacquire_kmh * MPS_PER_KMH
        self._still_alpha = dt / c.still_tau_s
        self._above2 = c.abs_above_factor ** 2
        self._abs_alpha = dt / c.abs_tau_s
        self._vstill = c.still_enter_kmh * MPS_PER_KMH
        self._a_still = c.still_enter_accel_mps2
        self._exit_p11 = c.p0_accel
        self._r_zero = c.zero_speed_std_mps ** 2
        self._r_still_a = c.still_accel_std_mps2 ** 2
        self._gate2 = c.gate_sigma ** 2
        self.steps = self.missing_wheel = self.missing_accel = 0
        self.rejected_wheel = self.rejected_accel = self.gated_wheel = self.ignored_wheel = 0
        self.resets = 0
        self.reset()

    def reset(self) -> None:
        """Back to the prior (not counted as a divergence); the next usable wheel reading
        initialises the speed."""
        c = self.config
        self.v = self.a = self.b = 0.0
        self.p = [c.p0_speed, 0.0, 0.0, c.p0_accel, 0.0, c.p0_offset]  # p00 p01 p02 p11 p12 p22
        self._initialised = False
        self._gated_run = 0
        self._reacq_run = 0
        self.standstill = False
        self.abs_mode = False
        self._innov_mean = 0.0
        self._wheel_innov_mean = 0.0
        self.wheel_nis: float | None = None  # e^2 / s of this step's wheel update (None: none)

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
        p00, p01, p11 = self.p[0], self.p[1], self.p[3]
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
        """Predict 2 ms, then update with the accelerometer and the wheel speed."""
        self.steps += 1
        c = self.config
        dt = self._dt
        p00, p01, p02, p11, p12, p22 = self.p
        # Predict: F = [[1, dt, 0], [0, 1, 0], [0, 0, 1]].
        v = self.v + self.a * dt
        a = self.a
        b = self.b
        p00 = p00 + dt * (2.0 * p01 + dt * p11) + self._q00
        p01 = p01 + dt * p11 + self._q01
        p02 = p02 + dt * p12
        p11 = p11 + self._q11
        p22 = p22 + self._q22

        # Accelerometer: H = [0, 1, 1].
        if accel is None:
            self.missing_accel += 1
        elif not -c.max_accel_mps2 <= accel <= c.max_accel_mps2:  # NaN fails too
            self.rejected_accel += 1
        else:
            e = accel - a - b
            self._innov_mean += self._still_alpha * (e - self._innov_mean)
            (v, a, b), (p00, p01, p02, p11, p12, p22) = scalar_update3(
                (v, a, b), (p00, p01, p02, p11, p12, p22), (0.0, 1.0, 1.0), e, self._r_a)

        # Wheel speed: H = [1, 0, 0].
        used = False
        self.wheel_nis = None
        if wheel_speed is None:
            self.missing_wheel += 1
        elif not 0.0 <= wheel_speed <= c.max_wheel_mps:
            self.rejected_wheel += 1
        elif not self._initialised:
            # the first reading initialises the filter (issue 30): v = reading, its variance the
            # sensor's at that speed (a 0 reading: at rest or below ~5 km/h, sigma_wheel_max)
            v = wheel_speed
            p00 = min(self._sw2 * (self._vref / wheel_speed) ** 2 if wheel_speed < self._vref
                      else self._sw2, self._swmax2) if wheel_speed > 0.0 else self._swmax2
            p01 = p02 = 0.0
            self._initialised = True
            self.standstill = False
            used = True
        elif not ((wheel_speed >= self._vreacq and self._reacq_run >= REACQUIRE_SAMPLES)
                  or (v >= self._vmin and wheel_speed > 0.0)):
            # Gate on the estimate, not the reading: dropping readings below a threshold would
            # bias the accepted ones upwards near it. Reacquisition (and the first reading) needs
            # REACQUIRE_SAMPLES high readings in a row: at 2 km/h the noise alone reaches 15 km/h.
            self._reacq_run = self._reacq_run + 1 if wheel_speed >= self._vreacq else 0
            self.ignored_wheel += 1
        else:
            self.standstill = False
            used = True
            vh = max(0.001, v)
            r = self._sw2 * (self._vref / vh) ** 2 if vh < self._vref else self._sw2
            r = min(r, self._swmax2)
            e = wheel_speed - v
            self._wheel_innov_mean += self._abs_alpha * (e - self._wheel_innov_mean)
            self.abs_mode = (a < -c.abs_decel_mps2
                             and self._wheel_innov_mean < -c.abs_innov_mps)
            if self.abs_mode:  # ABS slip pulls the wheel below the car: trust the upper envelope
                if e < 0.0:
                    ds = c.abs_slip_std * vh
                    r += ds * ds
                else:
                    r *= self._above2
            s = p00 + r
            if e * e > self._gate2 * s and self._gated_run < MAX_GATED_IN_ROW:
                self._gated_run += 1
                self.gated_wheel += 1
            else:
                self._gated_run = 0
                self.wheel_nis = e * e / s
                (v, a, b), (p00, p01, p02, p11, p12, p22) = scalar_update3(
                    (v, a, b), (p00, p01, p02, p11, p12, p22), (1.0, 0.0, 0.0), e, r)

        # Before the first wheel reading the speed means nothing (validity init): no standstill,
        # no v = 0 pseudo-measurement (it would make the prior's sigma look tiny).
        if not self._initialised:
            v = 0.0
        # Standstill: entered when v_hat would go negative with no usable wheel reading; left on
        # a usable wheel reading or a sustained accelerometer innovation (the car moves off).
        elif self.standstill and self._innov_mean > c.still_exit_mps2:
            self.standstill = False  # moving off: let a find the accelerometer quickly
            a = self._innov_mean
            p11 += self._exit_p11
        elif not used and not self.standstill and (
                v + a * dt <= 0.0 or (v < self._vstill and -self._a_still < a < self._a_still)):
            self.standstill = True
            self._innov_mean = 0.0
            self.abs_mode = False
        # Constraint v >= 0 / zero-velocity update: pseudo-measurement v = 0, then clip.
        if self._initialised and (v < 0.0 or self.standstill):
            (_, a, b), (p00, p01, p02, p11, p12, p22) = scalar_update3(
                (v, a, b), (p00, p01, p02, p11, p12, p22), (1.0, 0.0, 0.0), -v, self._r_zero)
            v = 0.0
            if self.standstill:  # at rest a = 0 too: accelerometer readings go to b
                (_, _, b), (p00, p01, p02, p11, p12, p22) = scalar_update3(
                    (v, a, b), (p00, p01, p02, p11, p12, p22), (0.0, 1.0, 0.0), -a,
                    self._r_still_a)
                a = 0.0
                v = 0.0  # both pinned at rest (the update moves v by ~1e-5 m/s)

        if (diverged_floats((v, a, b), p00 + p11 + p22, p01 + p02 + p12, SPEED_BOUNDS)
                or p00 <= 0.0 or p11 <= 0.0 or p22 <= 0.0):
            self.resets += 1
            self.reset()
            return
        self.v, self.a, self.b = v, a, b
        self.p = [p00, p01, p02, p11, p12, p22]
