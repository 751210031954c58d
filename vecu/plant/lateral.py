"""Single-track (bicycle) vehicle, a seeded 300 s steering manoeuvre and in-vehicle sensors.

After Khalid et al. (steering-wheel angle by an unscented smoother): the paper's eq. (4) lateral
motion and eq. (11) yaw motion reduced to one axle each (its printed parameters and eqs. (6)-(14)
are unusable; the model and numbers follow /work/shared/design/steering.md, see docs/models.md).
SI units throughout: rad, rad/s, m, m/s, m/s^2, N.

State x = [v_y, r] (lateral velocity, yaw rate); input u = [delta, v_x] (road-wheel angle,
longitudinal speed, an exogenous input: the longitudinal motion is neglected as in the paper).
  alpha_f = delta - (v_y + l_f r) / v_x,   alpha_r = -(v_y - l_r r) / v_x
  F_y(alpha) = D sin(C atan(B alpha)),   D = mu F_z,  B = C_alpha / (C D)   (Pacejka, no shift)
  v_y' = (F_yf cos delta + F_yr) / M - v_x r        (eq. 4, per axle)
  r'   = (l_f F_yf cos delta - l_r F_yr) / I_z      (eq. 11, per axle, no l_s terms)
  a_y  = (F_yf cos delta + F_yr) / M                (the accelerometer's quantity)
Steering-wheel angle = i_s * delta. Sensors follow the paper's eq. (3): Y = G Y0 + nu, 0 <= G <= 1
(G = 1 healthy, G = 0 dead), here with an optional bias (gyro offset for mismatch studies).
`f`, `h` are pure functions of (x, u, params); `simulate_lateral` does the stepping (RK4 at 5 ms,
samples at 100 Hz) with the named streams of `rng_streams`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vecu.plant.throttle import rng_streams

G_MPS2 = 9.81
DEG = math.pi / 180.0
DT_S = 0.01  # sample period of the sensors and of the ECU filter (100 Hz)
SIM_SUBSTEPS = 2  # RK4 substeps per sample (5 ms)
STREAMS = ("steer.manoeuvre", "steer.sensors")
SEGMENTS = ("sine", "lane_change", "steady_turn", "sweep")


@dataclass(frozen=True)
class VehicleParams:
    """Single-track parameters. M, I_z: the paper, Section III. l_f, l_r, C_f, C_r, mu, i_s, C:
    design note (the paper's l_f = 1100 m, l_r = 1500 m are garbled). Understeer 1.78 deg/g,
    characteristic speed 28.7 m/s."""

    mass_kg: float = 1410.0
    yaw_inertia_kgm2: float = 1800.0
    l_f_m: float = 1.1
    l_r_m: float = 1.5
    c_f_n_per_rad: float = 100e3  # front axle cornering stiffness
    c_r_n_per_rad: float = 120e3
    mu: float = 1.0
    shape_c: float = 1.3  # Pacejka C
    steering_ratio: float = 16.0  # i_s: steering-wheel angle / road-wheel angle

    @property
    def wheelbase_m(self) -> float:
        return self.l_f_m + self.l_r_m

    @property
    def understeer_rad_per_mps2(self) -> float:
        """K = M / L (l_r / C_f - l_f / C_r): delta = (L + K v^2) r / v in a steady turn."""
        p = self
        return p.mass_kg / p.wheelbase_m * (p.l_r_m / p.c_f_n_per_rad - p.l_f_m / p.c_r_n_per_rad)


@dataclass(frozen=True)
class TyreConsts:
    """Per-axle D (N) and B (1/rad) derived once from VehicleParams (static axle loads)."""

    d_f: float
    b_f: float
    d_r: float
    b_r: float
    c: float


def tyre_consts(p: VehicleParams) -> TyreConsts:
    """D = mu F_z (static loads M g l_r / L front, M g l_f / L rear), B = C_alpha / (C D)."""
    fz_f = p.mass_kg * G_MPS2 * p.l_r_m / p.wheelbase_m
    fz_r = p.mass_kg * G_MPS2 * p.l_f_m / p.wheelbase_m
    d_f, d_r = p.mu * fz_f, p.mu * fz_r
    return TyreConsts(d_f, p.c_f_n_per_rad / (p.shape_c * d_f),
                      d_r, p.c_r_n_per_rad / (p.shape_c * d_r), p.shape_c)


def axle_forces(v_y: float, r: float, delta: float, v_x: float, p: VehicleParams,
                t: TyreConsts) -> tuple[float, float]:
    """(F_yf, F_yr) in N from the slip angles (module docstring)."""
    a_f = delta - (v_y + p.l_f_m * r) / v_x
    a_r = (p.l_r_m * r - v_y) / v_x
    return (t.d_f * math.sin(t.c * math.atan(t.b_f * a_f)),
            t.d_r * math.sin(t.c * math.atan(t.b_r * a_r)))


def f(x: tuple[float, float], u: tuple[float, float], p: VehicleParams,
      t: TyreConsts | None = None) -> tuple[float, float]:
    """Continuous dynamics (v_y', r') of eqs. (4), (11) for x = (v_y, r), u = (delta, v_x)."""
    t = t if t is not None else tyre_consts(p)
    v_y, r = x
    delta, v_x = u
    ff, fr = axle_forces(v_y, r, delta, v_x, p, t)
    ffc = ff * math.cos(delta)
    return ((ffc + fr) / p.mass_kg - v_x * r,
            (p.l_f_m * ffc - p.l_r_m * fr) / p.yaw_inertia_kgm2)


def h(x: tuple[float, float], u: tuple[float, float], p: VehicleParams,
      t: TyreConsts | None = None) -> tuple[float, float]:
    """True sensor quantities (r, a_y) for x = (v_y, r), u = (delta, v_x)."""
    t = t if t is not None else tyre_consts(p)
    v_y, r = x
    delta, v_x = u
    ff, fr = axle_forces(v_y, r, delta, v_x, p, t)
    return r, (ff * math.cos(delta) + fr) / p.mass_kg


def rk4_step(x: tuple[float, float], u0: tuple[float, float], u1: tuple[float, float], dt: float,
             p: VehicleParams, t: TyreConsts) -> tuple[float, float]:
    """One RK4 step of `f` with the input linear between u0 (start) and u1 (end)."""
    um = (0.5 * (u0[0] + u1[0]), 0.5 * (u0[1] + u1[1]))
    k1 = f(x, u0, p, t)
    k2 = f((x[0] + 0.5 * dt * k1[0], x[1] + 0.5 * dt * k1[1]), um, p, t)
    k3 = f((x[0] + 0.5 * dt * k2[0], x[1] + 0.5 * dt * k2[1]), um, p, t)
    k4 = f((x[0] + dt * k3[0], x[1] + dt * k3[1]), u1, p, t)
    return (x[0] + dt / 6.0 * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0]),
            x[1] + dt / 6.0 * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1]))


def steady_state(delta: float, v_x: float, p: VehicleParams, iters: int = 60) -> tuple[float, float]:
    """(v_y, r) of a steady turn at (delta, v_x): Newton on f = 0 from the linear solution."""
    t = tyre_consts(p)
    L = p.wheelbase_m
    r = v_x * delta / (L + p.understeer_rad_per_mps2 * v_x * v_x)
    x = np.array([r * (p.l_r_m - p.mass_kg * p.l_f_m * v_x * v_x / (p.c_r_n_per_rad * L)), r])
    for _ in range(iters):
        fx = np.array(f((x[0], x[1]), (delta, v_x), p, t))
        J = np.empty((2, 2))
        for j in range(2):
            e = np.zeros(2)
            e[j] = 1e-6
            J[:, j] = (np.array(f((x[0] + e[0], x[1] + e[1]), (delta, v_x), p, t)) - fx) / 1e-6
        x = x - np.linalg.solve(J, fx)
        if float(np.abs(fx).max()) < 1e-12:
            break
    return float(x[0]), float(x[1])


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

    yaw_rate: SensorModel = SensorModel(sigma=0.2 * DEG)
    lat_accel: SensorModel = SensorModel(sigma=0.1)
    speed: SensorModel = SensorModel(sigma=0.05)
    steering_wheel: SensorModel = SensorModel(sigma=0.1 * DEG)


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
        parts.append(np.convolve(rng.normal(0.0, 1.0 * DEG, straight), np.ones(50) / 50 ** 0.5,
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
