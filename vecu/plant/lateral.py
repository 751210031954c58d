"""Single-track vehicle simulator (vecu.models.lateral, after Khalid): a seeded steering
manoeuvre (`steering_commands`), RK4 stepping and the eq. (3) sensors. `simulate_lateral`: a
300 s run at its own 20-30 m/s (offline); `DrivenLateral`: sample by sample at the drive's speed;
`LateralPart`: the plant node's part that sends its sensor frames.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import can
import numpy as np

from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.codec import DbcCodec
from vecu.faults import FaultInjector, FaultTarget
from vecu.kernels import kernel
from vecu.models.lateral import (
    DT_S,
    VehicleParams,
    h,
    lateral_motion,
    motion_constants,
    rk4_motion,
    steady_state,
    tyre_consts,
)
from vecu.plant.drive import Drive
from vecu.rng import rng_streams
from vecu.units import DEG_PER_RAD, MPS_PER_KMH, RAD_PER_DEG

SIM_SUBSTEPS = 2  # RK4 substeps per sample (5 ms)
STREAMS = ("steer.manoeuvre", "steer.sensors")
Send = Callable[[can.Message], bool]
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

    def reading(self, true: float, z: float) -> float:
        """One reading, z a standard normal draw."""
        return self.gain * true + self.bias + self.sigma * z


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
    """Randomised 300 s manoeuvre (steering_commands): sine steers (0.2-0.8 Hz), double lane
    changes, steady turns and a 0.2-1.5 Hz sweep, amplitudes from a steady-state a_y in
    `ay_range` (mu = 1 never exceeded, the tyres visibly nonlinear at the top)."""

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


def steering_commands(cfg: ManoeuvreConfig, p: VehicleParams, rng: np.random.Generator, dt: float,
                      speed_at: Callable[[int], float]) -> Iterator[np.ndarray]:
    """The manoeuvre's raw steering-wheel command (rad), chunk by chunk from `rng`: a steady curve
    (a_y 1.5-3 m/s^2) held 3-6 s and released over 1.5 s, then (straight driving with small
    corrections, a segment) pairs, segments in random order; each amplitude set for
    speed_at(index of the chunk's first sample). The one manoeuvre of simulate_lateral and
    DrivenLateral."""
    amp0 = _swa_for_ay(rng.uniform(1.5, 3.0), speed_at(0), p) * (1.0 if rng.uniform() < 0.5 else -1.0)
    ramp = np.linspace(1.0, 0.0, int(1.5 / dt))
    chunk = amp0 * np.concatenate([np.ones(int(rng.uniform(3.0, 6.0) / dt)), ramp])
    k = chunk.size
    yield chunk
    order: list[str] = []
    while True:
        if not order:
            order = list(cfg.segments)
            rng.shuffle(order)
        # Straight driving: small corrections, low-passed noise of ~1 deg at the wheel.
        straight = np.convolve(rng.normal(0.0, 1.0 * RAD_PER_DEG, int(rng.uniform(2.0, 5.0) / dt)),
                               np.ones(50) / 50 ** 0.5, mode="same")
        seg = _segment(order.pop(), speed_at(k + straight.size), cfg, p, dt, rng)
        k += straight.size + seg.size
        yield np.concatenate([straight, seg])


def steering_profile(cfg: ManoeuvreConfig, p: VehicleParams, rng: np.random.Generator,
                     dt: float = DT_S) -> tuple[np.ndarray, np.ndarray]:
    """(v_x, true steering-wheel angle) on the dt grid, both drawn from `rng`."""
    n = round(cfg.duration_s / dt) + 1
    v = _speed_profile(n, dt, cfg, rng)
    parts, k = [], 0
    for chunk in steering_commands(cfg, p, rng, dt, lambda i: float(v[min(i, n - 1)])):
        parts.append(chunk)
        k += chunk.size
        if k >= n:
            break
    return v, _low_pass2(np.concatenate(parts)[:n], cfg.column_hz, dt)


@kernel
def advance_motion(vy: float, r: float, d0: float, v0: float, d1: float, v1: float,
                   cst: tuple[float, ...]) -> tuple[float, float]:
    """(v_y, r) one sample (DT_S) on: SIM_SUBSTEPS RK4 steps (rk4_motion), the inputs
    (road-wheel angle, speed) linear from (d0, v0) to (d1, v1) within the sample;
    cst: vecu.models.lateral.motion_constants."""
    hsub = DT_S / SIM_SUBSTEPS
    for s in range(SIM_SUBSTEPS):
        a0, a1 = s / SIM_SUBSTEPS, (s + 1) / SIM_SUBSTEPS
        vy, r = rk4_motion(vy, r, d0 + a0 * (d1 - d0), v0 + a0 * (v1 - v0),
                           d0 + a1 * (d1 - d0), v0 + a1 * (v1 - v0), hsub, cst)
    return vy, r


@kernel
def sample_motion(vy: float, r: float, d0: float, v0: float, d1: float, v1: float,
                  cst: tuple[float, ...]) -> tuple[float, float, float]:
    """(a_y at the sample, v_y and r one sample on): `h`'s a_y, then advance_motion."""
    ay = lateral_motion(vy, r, d0, v0, cst[0], cst[1], cst[2], cst[3], cst[4], cst[5], cst[6],
                        cst[7], cst[8])[0]
    vy, r = advance_motion(vy, r, d0, v0, d1, v1, cst)
    return ay, vy, r


def simulate_lateral(
    seed: int = 1, cfg: ManoeuvreConfig = ManoeuvreConfig(),
    params: VehicleParams = VehicleParams(), sensors: LateralSensors = LateralSensors(),
) -> LateralTrace:
    """Simulate the manoeuvre: truth by RK4 (SIM_SUBSTEPS per 10 ms sample, inputs linear
    within a sample; sample_motion, as DrivenLateral steps), sensors sampled at every 10 ms with
    eq. (3)."""
    rngs = rng_streams(seed, STREAMS)
    v_x, swa = steering_profile(cfg, params, rngs["steer.manoeuvre"])
    n = v_x.size
    delta = swa / params.steering_ratio
    cst = motion_constants(params, tyre_consts(params))
    vy_k, r_k = steady_state(float(delta[0]), float(v_x[0]), params)
    vy, r, ay = np.empty(n), np.empty(n), np.empty(n)
    d_l, v_l = delta.tolist(), v_x.tolist()
    for k in range(n):
        vy[k], r[k] = vy_k, r_k
        j = min(k + 1, n - 1)  # the last sample: its a_y (the step after it is not kept)
        ay[k], vy_k, r_k = sample_motion(vy_k, r_k, d_l[k], v_l[k], d_l[j], v_l[j], cst)
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


# --------------------------------------------------------------------------- on the drive
V_KINEMATIC_MPS = 2.0  # below: the linear steady state (the tyre model is stiff, then singular)
STEER_GATE_MPS = (5.0, 12.0)  # the manoeuvre's steering fades in between these speeds
AHEAD_S = 36.0  # a segment's amplitude is set for the fastest speed this far ahead (sweep + straight)
NOISE_BLOCK = 256  # sensor noise rows drawn at a time (4 per sample: r, a_y, v_x, SWA)


def linear_steady_state(delta: float, v_x: float, p: VehicleParams) -> tuple[float, float]:
    """(v_y, r) of the linear single-track model's steady turn: r = v delta / (L + K v^2),
    v_y = r (l_r - M l_f v^2 / (C_r L)); (0, 0) at standstill."""
    L = p.wheelbase_m
    r = v_x * delta / (L + p.understeer_rad_per_mps2 * v_x * v_x)
    return r * (p.l_r_m - p.mass_kg * p.l_f_m * v_x * v_x / (p.c_r_n_per_rad * L)), r


@dataclass(frozen=True)
class LateralSample:
    """One 10 ms sample of the vehicle on the drive: truth (rad, m/s) and sensor readings."""

    swa: float
    beta: float
    v_x: float
    meas_r: float
    meas_ay: float
    meas_vx: float
    meas_swa: float


class DrivenLateral:
    """The single-track vehicle at the drive's speed (vecu.plant.drive), one 10 ms sample per
    call: the manoeuvre of steering_commands, each amplitude set for the fastest speed the drive
    reaches within AHEAD_S (so a_y stays within ay_range), the command
    faded out below STEER_GATE_MPS (nobody slaloms at walking pace), then the steering column's
    low-pass. Stepped by `sample_motion` (RK4) at and above V_KINEMATIC_MPS, held on the linear steady
    state below it (0 at standstill). Sensors as simulate_lateral's, the speed reading >= 0."""

    def __init__(self, drive: Drive, seed: int, cfg: ManoeuvreConfig = ManoeuvreConfig(),
                 params: VehicleParams = VehicleParams(),
                 sensors: LateralSensors = LateralSensors()) -> None:
        rngs = rng_streams(seed, STREAMS)
        self._rs = rngs["steer.sensors"]
        self._drive, self._p, self._sensors = drive, params, sensors
        self._tc = tyre_consts(params)
        self._cst = motion_constants(params, self._tc)
        self._stride = round(DT_S / drive.dt_s)  # drive samples per lateral sample
        self._ahead = round(AHEAD_S / DT_S)
        self._col = math.exp(-2.0 * math.pi * cfg.column_hz * DT_S)
        self._cmd: deque[float] = deque()  # raw steering-wheel command of the samples to come (rad)
        self._j = 0  # index of the next sample made by _command
        self._s1: float | None = None
        self._s2 = 0.0
        self._noise: list[list[float]] = []
        self._chunks = steering_commands(cfg, params, rngs["steer.manoeuvre"], DT_S, self._v_ref)
        self._cur = self._command()
        d0, v0 = self._cur[0] / params.steering_ratio, self._cur[1]
        self._x = (steady_state(d0, v0, params) if v0 >= V_KINEMATIC_MPS
                   else linear_steady_state(d0, v0, params))

    def _v_ref(self, i: int) -> float:
        """The fastest speed within AHEAD_S of command sample i (at least the gate's)."""
        k = self._stride * i
        v = self._drive.speeds(k, k + self._stride * self._ahead)
        return max(float(v.max()), STEER_GATE_MPS[0])

    def _command(self) -> tuple[float, float]:
        """(steering-wheel angle after the column, speed) of the next sample."""
        if not self._cmd:
            self._cmd.extend(next(self._chunks).tolist())
        raw = self._cmd.popleft()
        v = self._drive.speed(self._stride * self._j)
        self._j += 1
        lo, hi = STEER_GATE_MPS
        x = raw * min(max((v - lo) / (hi - lo), 0.0), 1.0)
        a = self._col
        if self._s1 is None:
            self._s1 = self._s2 = x
        self._s1 = a * self._s1 + (1.0 - a) * x
        self._s2 = a * self._s2 + (1.0 - a) * self._s1
        return self._s2, v

    def sample(self) -> LateralSample:
        """This sample's truth and readings; the vehicle then moves on one sample."""
        p = self._p
        swa, v = self._cur
        nxt = self._command()
        delta = swa / p.steering_ratio
        x = self._x
        d1, v1 = nxt[0] / p.steering_ratio, nxt[1]
        if v >= V_KINEMATIC_MPS and v1 >= V_KINEMATIC_MPS:  # a_y of h, then RK4 (one call)
            ay, vy1, r1 = sample_motion(x[0], x[1], delta, v, d1, v1, self._cst)
            self._x = (vy1, r1)
        else:
            ay = h(x, (delta, v), p, self._tc)[1] if v >= V_KINEMATIC_MPS else v * x[1]
            self._x = linear_steady_state(d1, v1, p)
        self._cur = nxt
        if not self._noise:
            self._noise = self._rs.standard_normal((NOISE_BLOCK, 4)).tolist()[::-1]
        z = self._noise.pop()
        s = self._sensors
        return LateralSample(
            swa, math.atan2(x[0], v), v, s.yaw_rate.reading(x[1], z[0]),
            s.lat_accel.reading(ay, z[1]), max(s.speed.reading(v, z[2]), 0.0),
            s.steering_wheel.reading(swa, z[3]))


# --------------------------------------------------------------------------- on the bus
_SWA = FaultTarget.SWA  # bound once (per-tick code)


class LateralPart:
    """Single-track vehicle (Khalid) on the drive's speed: CHS_Lateral (gyro, lateral
    accelerometer, speed) and the E2E-protected SWA_Sensor every 10 ms (sample t_ns / 10 ms of
    DrivenLateral). The fault injector acts on the SWA sensor (deg)."""

    truth_message = "TRUTH_Steering"  # its truth frame (dbc/vecu_truth.dbc; PlantNode.enable_truth)
    name = "lateral"
    period_ns = 10 * NS_PER_MS

    def __init__(self, codec: DbcCodec, drive: Drive, seed: int, injector: FaultInjector,
                 vehicle: VehicleParams = VehicleParams(),
                 sensors: LateralSensors = LateralSensors()) -> None:
        self._lat = codec["CHS_Lateral"]
        self._swa = codec["SWA_Sensor"]
        self._lat_frame = self._lat.framer(("LAT_YawRate", "LAT_LatAccel", "LAT_VehSpeed"))
        self._swa_frame = self._swa.framer(("SWA_CRC", "SWA_AliveCounter", "SWA_Angle"))
        e2e = self._swa.e2e
        assert e2e is not None, "SWA_Sensor is E2E-protected in vecu.dbc"
        self._modulo = e2e.protection.counter_modulo  # P11: 0..14
        self.injector = injector
        self.vehicle = DrivenLateral(drive, seed, ManoeuvreConfig(), vehicle, sensors)
        self._j = 0  # the next sample of the vehicle
        self._counter = 0
        self.truth_msg = None  # TRUTH_Steering codec when recording truth
        # truth and sensor of the last tick (deg), read by probes
        self.swa = self.beta = 0.0
        self.swa_sensor: float | None = None

    def tick(self, t_ns: int, send: Send) -> None:
        j = t_ns // self.period_ns
        s = self.vehicle.sample()
        self._j += 1
        while self._j <= j:  # ticks the scheduler left out (live): the car drove on meanwhile
            s = self.vehicle.sample()
            self._j += 1
        swa, beta = s.swa * DEG_PER_RAD, s.beta * DEG_PER_RAD
        self.swa, self.beta = swa, beta
        ts = t_ns / NS_PER_S
        send(self._lat_frame(ts, s.meas_r * DEG_PER_RAD, s.meas_ay, s.meas_vx / MPS_PER_KMH)[0])
        if self.truth_msg is not None:
            send(self.truth_msg.frame({"TRU_SwAngle": swa, "TRU_SideSlip": beta}, ts))
        v = self.injector.apply(_SWA, s.meas_swa * DEG_PER_RAD)
        self.swa_sensor = v
        if v is not None:
            send(self._swa_frame(ts, 0, self._counter, v)[0])
            self._counter = (self._counter + 1) % self._modulo
