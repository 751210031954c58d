"""Single-track vehicle simulator: a seeded 300 s steering manoeuvre and in-vehicle sensors.

The model (after Khalid, a sane single-track vehicle) is vecu.models.lateral; this module adds
the manoeuvre, RK4 stepping and the eq. (3) sensors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vecu.models.lateral import (
    DT_S,
    VehicleParams,
    h,
    rk4_step,
    steady_state,
    tyre_consts,
)
from vecu.rng import rng_streams
from vecu.units import RAD_PER_DEG

SIM_SUBSTEPS = 2  # RK4 substeps per sample (5 ms)
STREAMS = ("steer.manoeuvre", "steer.sensors")
SEGMENTS = ("sine", "lane_change", "steady_turn", "sweep")


# --------------------------------------------------------------------------- sensors (eq. 3)
@dataclass(frozen=True)
class SensorModel:
    """Paper eq. (3): Y = G Y0 + nu, nu ~ N(bias, sigma^2); 0 <= gain <= 1 (0: a dead sensor)."""

    sigma: float
    gain: float = 1.0
    bias: float = 0.0

    def __post_init__(self) -> None:
        if not 0.0 <= self.gain <= 1.0:
            raise ValueError("sensor gain G must lie in [0, 1] (eq. 3)")
        if not self.sigma >= 0.0:
            raise ValueError("sensor noise sigma must be >= 0")

    def measure(self, true: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """G * true + bias + sigma * N(0, 1), vectorised."""
        return self.gain * true + self.bias + self.sigma * rng.standard_normal(np.shape(true))


@dataclass(frozen=True)
class LateralSensors:
    """In-vehicle sensors at 100 Hz (design note): gyro 0.2 deg/s, accelerometer 0.1 m/s^2,
    wheel-speed based v_x 0.05 m/s, steering-wheel angle 0.1 deg (a good optical SWA sensor)."""

    yaw_rate: SensorModel = SensorModel(sigma=0.2 * RAD_PER_DEG)
    lat_accel: SensorModel = SensorModel(sigma=0.1)
    speed: SensorModel = SensorModel(sigma=0.05)
    steering_wheel: SensorModel = SensorModel(sigma=0.1 * RAD_PER_DEG)


# --------------------------------------------------------------------------- manoeuvre
@dataclass(frozen=True)
class ManoeuvreConfig:
    """Randomised 300 s manoeuvre (uniform draws from the 'steer.manoeuvre' stream).

    Segments in random order, repeated until `duration_s`, separated by straight driving with
    small corrections: sine steers (0.2-0.8 Hz), double lane changes, steady turns and a
    0.2-1.5 Hz sweep. Amplitudes are set from a target steady-state lateral acceleration
    (`ay_range`) at the current speed, so mu = 1 is never exceeded but the tyres are visibly
    nonlinear at the top. The run starts in a steady curve (the plant starts at its steady state).
    """

    duration_s: float = 300.0
    speed_range_mps: tuple[float, float] = (20.0, 30.0)
    ay_range_mps2: tuple[float, float] = (2.0, 6.0)
    sweep_hz: tuple[float, float] = (0.2, 1.5)
    column_hz: float = 5.0  # steering column / driver low-pass (critically damped, 2nd order)
    segments: tuple[str, ...] = SEGMENTS


@dataclass(frozen=True)
class LateralTrace:
    """One simulated run; arrays of length n, sample k at time k * DT_S. Angles in rad."""

    t: np.ndarray
    v_x: np.ndarray  # true longitudinal speed, m/s
    delta: np.ndarray  # true road-wheel angle
    swa: np.ndarray  # true steering-wheel angle = i_s * delta
    v_y: np.ndarray
    r: np.ndarray  # true yaw rate, rad/s
    beta: np.ndarray  # true side-slip atan(v_y / v_x)
    a_y: np.ndarray  # true lateral acceleration, m/s^2
    meas_r: np.ndarray  # sensor readings (eq. 3)
    meas_ay: np.ndarray
    meas_vx: np.ndarray
    meas_swa: np.ndarray
    params: VehicleParams = field(default_factory=VehicleParams)


def _swa_for_ay(ay: float, v: float, p: VehicleParams) -> float:
    """Steering-wheel angle (rad) of a steady turn with lateral acceleration ay at speed v."""
    return p.steering_ratio * ay * (p.wheelbase_m + p.understeer_rad_per_mps2 * v * v) / (v * v)


def _speed_profile(n: int, dt: float, cfg: ManoeuvreConfig, rng: np.random.Generator) -> np.ndarray:
    """Smooth speed: new targets in speed_range every 15-40 s, reached at <= 0.8 m/s^2."""
    lo, hi = cfg.speed_range_mps
    v = np.empty(n)
    cur = rng.uniform(lo, hi)
    k = 0
    while k < n:
        target = rng.uniform(lo, hi)
        acc = rng.uniform(0.3, 0.8)
        hold = int(rng.uniform(15.0, 40.0) / dt)
        for j in range(k, min(n, k + hold)):
            step = acc * dt
            cur = min(cur + step, target) if target > cur else max(cur - step, target)
            v[j] = cur
        k += hold
    return v


def _segment(kind: str, v: float, cfg: ManoeuvreConfig, p: VehicleParams, dt: float,
             rng: np.random.Generator) -> np.ndarray:
    """Steering-wheel command (rad) of one segment, starting and ending at 0."""
    u = rng.uniform
    amp = _swa_for_ay(u(*cfg.ay_range_mps2), v, p) * (1.0 if u() < 0.5 else -1.0)
    if kind == "sine":
        fr = u(0.2, 0.8)
        cycles = int(rng.integers(2, 5))
        t = np.arange(int(cycles / fr / dt)) * dt
        return amp * np.sin(2.0 * math.pi * fr * t)
    if kind == "lane_change":  # ISO 3888-like: one full sine out, a pause, one back
        period = u(2.0, 3.5)
        t = np.arange(int(period / dt)) * dt
        pulse = amp * np.sin(2.0 * math.pi * t / period)
        return np.concatenate([pulse, np.zeros(int(u(0.5, 1.5) / dt)), -pulse])
    if kind == "steady_turn":
        ramp = np.linspace(0.0, 1.0, int(u(1.0, 2.5) / dt))
        return amp * np.concatenate([ramp, np.ones(int(u(5.0, 12.0) / dt)), ramp[::-1]])
    if kind == "sweep":  # linear chirp, amplitude 1/2 of the steady-turn one (transient gain)
        f0, f1 = cfg.sweep_hz
        dur = u(20.0, 30.0)
        t = np.arange(int(dur / dt)) * dt
        phase = 2.0 * math.pi * (f0 * t + 0.5 * (f1 - f0) / dur * t * t)
        return 0.5 * amp * np.sin(phase)
    raise ValueError(f"unknown segment {kind!r}; choose from {', '.join(SEGMENTS)}")


def _low_pass2(x: np.ndarray, hz: float, dt: float) -> np.ndarray:
    """Critically damped 2nd-order low-pass (two cascaded exact first-order sections)."""
    a = math.exp(-2.0 * math.pi * hz * dt)
    y = np.empty_like(x)
    s1 = s2 = float(x[0])
    for k, xk in enumerate(x.tolist()):
        s1 = a * s1 + (1.0 - a) * xk
        s2 = a * s2 + (1.0 - a) * s1
        y[k] = s2
    return y


def steering_profile(cfg: ManoeuvreConfig, p: VehicleParams, rng: np.random.Generator,
                     dt: float = DT_S) -> tuple[np.ndarray, np.ndarray]:
    """(v_x, true steering-wheel angle) on the dt grid, both drawn from `rng`."""
    n = round(cfg.duration_s / dt) + 1
    v = _speed_profile(n, dt, cfg, rng)
    # Start in a steady curve (ay 1.5-3 m/s^2), held 3-6 s, released over 1.5 s.
    amp0 = _swa_for_ay(rng.uniform(1.5, 3.0), float(v[0]), p) * (1.0 if rng.uniform() < 0.5 else -1.0)
    ramp = np.linspace(1.0, 0.0, int(1.5 / dt))
    parts = [amp0 * np.concatenate([np.ones(int(rng.uniform(3.0, 6.0) / dt)), ramp])]
    k = sum(len(q) for q in parts)
    order: list[str] = []
    while k < n:
        if not order:
            order = list(cfg.segments)
            rng.shuffle(order)
        straight = int(rng.uniform(2.0, 5.0) / dt)
        # Straight driving: small corrections, low-passed noise of ~1 deg at the wheel.
        parts.append(np.convolve(rng.normal(0.0, 1.0 * RAD_PER_DEG, straight), np.ones(50) / 50 ** 0.5,
                                 mode="same"))
        seg = _segment(order.pop(), float(v[min(k + straight, n - 1)]), cfg, p, dt, rng)
        parts.append(seg)
        k += straight + len(seg)
    swa = np.concatenate(parts)[:n]
    return v, _low_pass2(swa, cfg.column_hz, dt)


def simulate_lateral(
    seed: int = 1, cfg: ManoeuvreConfig = ManoeuvreConfig(),
    params: VehicleParams = VehicleParams(), sensors: LateralSensors = LateralSensors(),
) -> LateralTrace:
    """Simulate the manoeuvre: truth by RK4 (SIM_SUBSTEPS per 10 ms sample, inputs linear
    within a sample), sensors sampled at every 10 ms with eq. (3)."""
    rngs = rng_streams(seed, STREAMS)
    v_x, swa = steering_profile(cfg, params, rngs["steer.manoeuvre"])
    n = v_x.size
    delta = swa / params.steering_ratio
    tc = tyre_consts(params)
    x = steady_state(float(delta[0]), float(v_x[0]), params)
    vy = np.empty(n)
    r = np.empty(n)
    ay = np.empty(n)
    d_l, v_l = delta.tolist(), v_x.tolist()
    hsub = DT_S / SIM_SUBSTEPS
    for k in range(n):
        vy[k], r[k] = x
        ay[k] = h(x, (d_l[k], v_l[k]), params, tc)[1]
        if k + 1 < n:
            for s in range(SIM_SUBSTEPS):
                a0, a1 = s / SIM_SUBSTEPS, (s + 1) / SIM_SUBSTEPS
                u0 = (d_l[k] + a0 * (d_l[k + 1] - d_l[k]), v_l[k] + a0 * (v_l[k + 1] - v_l[k]))
                u1 = (d_l[k] + a1 * (d_l[k + 1] - d_l[k]), v_l[k] + a1 * (v_l[k + 1] - v_l[k]))
                x = rk4_step(x, u0, u1, hsub, params, tc)
    rs = rngs["steer.sensors"]
    # One stream, drawn in a fixed order: yaw rate, a_y, speed, steering wheel.
    m_r = sensors.yaw_rate.measure(r, rs)
    m_ay = sensors.lat_accel.measure(ay, rs)
    m_vx = sensors.speed.measure(v_x, rs)
    m_swa = sensors.steering_wheel.measure(swa, rs)
    return LateralTrace(
        t=np.arange(n) * DT_S, v_x=v_x, delta=delta, swa=swa, v_y=vy, r=r,
        beta=np.arctan2(vy, v_x), a_y=ay, meas_r=m_r, meas_ay=m_ay, meas_vx=m_vx,
        meas_swa=m_swa, params=params,
    )
