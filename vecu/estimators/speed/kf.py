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
counts. Nothing the inputs contain can make the outputs NaN.

One step is one kernel, `kf_step` (vecu.kernels: compiled under numba, plain Python otherwise;
one driver). Its state and tuning are numpy records with named fields (STATE, TUNING); counters
are integers, modes booleans. Squares of ratios are `x ** c["square"]` with square = 2.0 read at
run time: Python's x ** 2 is libm's pow, which numba would fold into x * x (a different rounding
in about one case in a thousand: the golden log's bits would change); min/max are written as
the ternaries Python's min/max evaluate. Only scalar IEEE arithmetic and libm pow: both backends
give the same bits.
"""

# ruff: noqa: FURB136 (x if c else y mirrors min()/max() exactly, NaN included, without a call)

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from vecu.estimators.common.covariance import DivergenceBounds, diverged_scalars
from vecu.kernels import kernel, record
from vecu.units import MPS_PER_KMH

DT_S = 0.002
SPEED_BOUNDS = DivergenceBounds(max_trace=1e4, max_abs_state=1e3)
REACQUIRE_SAMPLES = 10  # 20 ms of readings >= reacquire_kmh before they are believed
MAX_GATED_IN_ROW = 25  # 50 ms of consecutive gated wheel readings, then believe the sensor


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


# The filter's state: [v, a, b], P's upper triangle, the mode means and runs, counters
STATE = np.dtype([(f, "f8") for f in (
    "v", "a", "b", "p00", "p01", "p02", "p11", "p12", "p22", "innov_mean", "wheel_innov_mean",
    "nis")] + [(f, "?") for f in ("has_nis", "init", "still", "abs")] + [(f, "i8") for f in (
        "gated_run", "reacq_run", "steps", "missing_wheel", "missing_accel", "rejected_wheel",
        "rejected_accel", "gated_wheel", "ignored_wheel", "resets")])


def _tuning_fields(c: SpeedFilterConfig) -> dict[str, float]:
    """The step's tuning, derived from the configuration (SI, squared where it is a variance)."""
    dt, q = c.dt_s, c.q_jerk
    return {
        "dt": dt, "q00": q * dt ** 3 / 3.0, "q01": q * dt * dt / 2.0, "q11": q * dt,
        "q22": c.q_offset * dt, "r_a": c.sigma_accel_mps2 ** 2, "sw2": c.sigma_wheel_mps ** 2,
        "swmax2": c.sigma_wheel_max_mps ** 2, "vref": c.wheel_ref_kmh * MPS_PER_KMH,
        "vmin": c.min_wheel_kmh * MPS_PER_KMH, "vreacq": c.reacquire_kmh * MPS_PER_KMH,
        "still_alpha": dt / c.still_tau_s, "above2": c.abs_above_factor ** 2,
        "abs_alpha": dt / c.abs_tau_s, "vstill": c.still_enter_kmh * MPS_PER_KMH,
        "a_still": c.still_enter_accel_mps2, "exit_p11": c.p0_accel,
        "r_zero": c.zero_speed_std_mps ** 2, "r_still_a": c.still_accel_std_mps2 ** 2,
        "gate2": c.gate_sigma ** 2, "max_accel": c.max_accel_mps2, "max_wheel": c.max_wheel_mps,
        "abs_decel": c.abs_decel_mps2, "abs_innov": c.abs_innov_mps,
        "abs_slip_std": c.abs_slip_std, "still_exit": c.still_exit_mps2,
        "p0_speed": c.p0_speed, "p0_accel": c.p0_accel, "p0_offset": c.p0_offset,
        "max_trace": SPEED_BOUNDS.max_trace, "max_abs_state": SPEED_BOUNDS.max_abs_state,
        "square": 2.0}  # the exponent of squared ratios, read at run time (module docstring)


TUNING = np.dtype([(f, "f8") for f in _tuning_fields(SpeedFilterConfig())])


def tuning(config: SpeedFilterConfig) -> Any:
    """The TUNING record of a configuration (vecu.kernels.record)."""
    return record(TUNING, **_tuning_fields(config))


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
def kf_reset(st: Any, tuning: Any) -> None:
    """Back to the prior (counters kept; not counted as a divergence); st, tuning: STATE and TUNING records
    (vecu.kernels.record)."""
    s, c = st[0], tuning[0]
    s["v"] = 0.0
    s["a"] = 0.0
    s["b"] = 0.0
    s["p00"] = c["p0_speed"]
    s["p01"] = 0.0
    s["p02"] = 0.0
    s["p11"] = c["p0_accel"]
    s["p12"] = 0.0
    s["p22"] = c["p0_offset"]
    s["init"] = False
    s["gated_run"] = 0
    s["reacq_run"] = 0
    s["still"] = False
    s["abs"] = False
    s["innov_mean"] = 0.0
    s["wheel_innov_mean"] = 0.0
    s["nis"] = 0.0
    s["has_nis"] = False


@kernel
def kf_step(st: Any, tuning: Any, wheel_speed: float, has_wheel: bool, accel: float,
            has_accel: bool) -> tuple[float, float, float, float, float, float, bool, bool, bool]:
    """Predict 2 ms, then update with the accelerometer and the wheel speed (module docstring);
    a missing reading: has_* False; st, tuning: STATE and TUNING records (vecu.kernels.record). Returns
    (v, a, b, p00, p01, p11, initialised, standstill, abs_mode) after the step."""
    s, c = st[0], tuning[0]
    s["steps"] += 1
    dt = c["dt"]
    p00, p01, p02, p11, p12, p22 = s["p00"], s["p01"], s["p02"], s["p11"], s["p12"], s["p22"]
    # Predict: F = [[1, dt, 0], [0, 1, 0], [0, 0, 1]].
    v = s["v"] + s["a"] * dt
    a = s["a"]
    b = s["b"]
    p00 = p00 + dt * (2.0 * p01 + dt * p11) + c["q00"]
    p01 = p01 + dt * p11 + c["q01"]
    p02 = p02 + dt * p12
    p11 = p11 + c["q11"]
    p22 = p22 + c["q22"]
    initialised = s["init"]
    standstill = s["still"]
    abs_mode = s["abs"]

    # Accelerometer: H = [0, 1, 1].
    if not has_accel:
        s["missing_accel"] += 1
    elif not -c["max_accel"] <= accel <= c["max_accel"]:  # NaN fails too
        s["rejected_accel"] += 1
    else:
        e = accel - a - b
        s["innov_mean"] += c["still_alpha"] * (e - s["innov_mean"])
        (v, a, b), (p00, p01, p02, p11, p12, p22) = scalar_update3(
            (v, a, b), (p00, p01, p02, p11, p12, p22), (0.0, 1.0, 1.0), e, c["r_a"])

    # Wheel speed: H = [1, 0, 0].
    used = False
    s["has_nis"] = False
    sw2, swmax2, vref = c["sw2"], c["swmax2"], c["vref"]
    if not has_wheel:
        s["missing_wheel"] += 1
    elif not 0.0 <= wheel_speed <= c["max_wheel"]:
        s["rejected_wheel"] += 1
    elif not initialised:
        # the first reading initialises the filter (issue 30): v = reading, its variance the
        # sensor's at that speed (a 0 reading: at rest or below ~5 km/h, sigma_wheel_max)
        v = wheel_speed
        if wheel_speed > 0.0:
            r = sw2 * (vref / wheel_speed) ** c["square"] if wheel_speed < vref else sw2
            p00 = swmax2 if swmax2 < r else r  # min(r, swmax2)
        else:
            p00 = swmax2
        p01 = p02 = 0.0
        initialised = True
        standstill = False
        used = True
    elif not ((wheel_speed >= c["vreacq"] and s["reacq_run"] >= REACQUIRE_SAMPLES)
              or (v >= c["vmin"] and wheel_speed > 0.0)):
        # Gate on the estimate, not the reading: dropping readings below a threshold would
        # bias the accepted ones upwards near it. Reacquisition (and the first reading) needs
        # REACQUIRE_SAMPLES high readings in a row: at 2 km/h the noise alone reaches 15 km/h.
        s["reacq_run"] = s["reacq_run"] + 1 if wheel_speed >= c["vreacq"] else 0
        s["ignored_wheel"] += 1
    else:
        standstill = False
        used = True
        vh = v if v > 0.001 else 0.001  # max(0.001, v)
        r = sw2 * (vref / vh) ** c["square"] if vh < vref else sw2
        r = swmax2 if swmax2 < r else r  # min(r, swmax2)
        e = wheel_speed - v
        s["wheel_innov_mean"] += c["abs_alpha"] * (e - s["wheel_innov_mean"])
        abs_mode = a < -c["abs_decel"] and s["wheel_innov_mean"] < -c["abs_innov"]
        if abs_mode:  # ABS slip pulls the wheel below the car: trust the upper envelope
            if e < 0.0:
                ds = c["abs_slip_std"] * vh
                r += ds * ds
            else:
                r *= c["above2"]
        sv = p00 + r
        if e * e > c["gate2"] * sv and s["gated_run"] < MAX_GATED_IN_ROW:
            s["gated_run"] += 1
            s["gated_wheel"] += 1
        else:
            s["gated_run"] = 0
            s["nis"] = e * e / sv
            s["has_nis"] = True
            (v, a, b), (p00, p01, p02, p11, p12, p22) = scalar_update3(
                (v, a, b), (p00, p01, p02, p11, p12, p22), (1.0, 0.0, 0.0), e, r)

    # Before the first wheel reading the speed means nothing (validity init): no standstill,
    # no v = 0 pseudo-measurement (it would make the prior's sigma look tiny).
    if not initialised:
        v = 0.0
    # Standstill: entered when v_hat would go negative with no usable wheel reading; left on
    # a usable wheel reading or a sustained accelerometer innovation (the car moves off).
    elif standstill and s["innov_mean"] > c["still_exit"]:
        standstill = False  # moving off: let a find the accelerometer quickly
        a = s["innov_mean"]
        p11 += c["exit_p11"]
    elif not used and not standstill and (
            v + a * dt <= 0.0 or (v < c["vstill"] and -c["a_still"] < a < c["a_still"])):
        standstill = True
        s["innov_mean"] = 0.0
        abs_mode = False
    # Constraint v >= 0 / zero-velocity update: pseudo-measurement v = 0, then clip.
    if initialised and (v < 0.0 or standstill):
        (_, a, b), (p00, p01, p02, p11, p12, p22) = scalar_update3(
            (v, a, b), (p00, p01, p02, p11, p12, p22), (1.0, 0.0, 0.0), -v, c["r_zero"])
        v = 0.0
        if standstill:  # at rest a = 0 too: accelerometer readings go to b
            (_, _, b), (p00, p01, p02, p11, p12, p22) = scalar_update3(
                (v, a, b), (p00, p01, p02, p11, p12, p22), (0.0, 1.0, 0.0), -a,
                c["r_still_a"])
            a = 0.0
            v = 0.0  # both pinned at rest (the update moves v by ~1e-5 m/s)
    s["init"] = initialised
    s["still"] = standstill
    s["abs"] = abs_mode

    if (diverged_scalars((v, a, b), p00 + p11 + p22, p01 + p02 + p12, c["max_trace"],
                         c["max_abs_state"])
            or p00 <= 0.0 or p11 <= 0.0 or p22 <= 0.0):
        s["resets"] += 1
        kf_reset(st, tuning)
    else:
        s["v"] = v
        s["a"] = a
        s["b"] = b
        s["p00"] = p00
        s["p01"] = p01
        s["p02"] = p02
        s["p11"] = p11
        s["p12"] = p12
        s["p22"] = p22
    return (s["v"], s["a"], s["b"], s["p00"], s["p01"], s["p11"], s["init"], s["still"],
            s["abs"])


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
        self.config = config
        self._tuning = tuning(config)
        self._st = record(STATE)
        self._vmin = float(self._tuning[0]["vmin"])
        kf_step.fix_types(self._st, self._tuning, 0.0, True, 0.0, True)
        self.reset()
    def reset(self) -> None:
        """Back to the prior (not counted as a divergence); the next usable wheel reading
        initialises the speed."""
        kf_reset(self._st, self._tuning)
        s = self._st[0]
        self.v, self.a, self.b = float(s["v"]), float(s["a"]), float(s["b"])
        self._p00, self._p01, self._p11 = float(s["p00"]), float(s["p01"]), float(s["p11"])
        self._initialised, self.standstill, self.abs_mode = (
            bool(s["init"]), bool(s["still"]), bool(s["abs"]))

    @property
    def p(self) -> list[float]:
        """P's upper triangle (p00, p01, p02, p11, p12, p22)."""
        s = self._st[0]
        return [float(s[f]) for f in ("p00", "p01", "p02", "p11", "p12", "p22")]

    @property
    def wheel_nis(self) -> float | None:
        """e^2 / s of this step's wheel update (None: none)."""
        s = self._st[0]
        return float(s["nis"]) if s["has_nis"] else None

    def _count(self, name: str) -> int:
        return int(self._st[0][name])

    steps = property(lambda self: self._count("steps"))
    missing_wheel = property(lambda self: self._count("missing_wheel"))
    missing_accel = property(lambda self: self._count("missing_accel"))
    rejected_wheel = property(lambda self: self._count("rejected_wheel"))
    rejected_accel = property(lambda self: self._count("rejected_accel"))
    gated_wheel = property(lambda self: self._count("gated_wheel"))
    ignored_wheel = property(lambda self: self._count("ignored_wheel"))
    resets = property(lambda self: self._count("resets"))

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
         self.standstill, self.abs_mode) = kf_step(
            self._st, self._tuning, 0.0 if wheel_speed is None else wheel_speed,
            wheel_speed is not None, 0.0 if accel is None else accel, accel is not None)
