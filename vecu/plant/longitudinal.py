"""Longitudinal vehicle, braking manoeuvres, wheel-speed sensor (Hernández 2005, Section 2.2.2)
and accelerometer (Section 4) at 500 Hz; SI units, acceleration positive forward. Manoeuvres
and sensor figures: docs/models.md, "Vehicle speed › Plant"."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vecu.rng import rng_streams
from vecu.units import G_MPS2, MPS_PER_KMH

DT_S = 0.002  # 500 Hz, the paper's sampling frequency
MANOEUVRES = ("paper", "gentle", "abs", "launch_brake", "road")
STREAMS = ("speed.manoeuvre", "speed.wheel", "speed.accel")
ROAD_SPEED_MPS = (20.0, 30.0)  # "road" cruise targets (72-108 km/h, the lateral evaluation's)
MAX_S = 60.0  # longest manoeuvre before its stop ("road": 150 s)


@dataclass(frozen=True)
class ManoeuvreConfig:
    """Variant and its randomised ranges (uniform draws from the 'speed.manoeuvre' stream)."""

    kind: str = "paper"
    standstill_s: float = 1.5  # simulated time after the stop
    rolling: bool = False  # "road": start cruising at speed instead of launching from rest
    cruise_accel_std: float = 0.15  # m/s^2, low-passed (1 Hz) road/engine fluctuation in cruise


@dataclass(frozen=True)
class WheelSensorConfig:
    """Variable-reluctance wheel-speed sensor (after its conditioning), see docs/models.md."""

    sigma_mps: float = 0.35  # white noise std at and above sigma_ref_kmh
    sigma_ref_kmh: float = 10.0  # below this the std grows as sigma * ref / v
    sigma_max_mps: float = 2.0
    dropout_full_kmh: float = 2.0  # at and below: always reads 0
    dropout_none_kmh: float = 5.0  # at and above: never drops out; linear in between
    abs_slip_max: float = 0.2  # peak slip of an ABS cycle
    abs_off_kmh: float = 10.0  # ABS disconnects below this (Section 2.2.2)


@dataclass(frozen=True)
class AccelSensorConfig:
    """Capacitive accelerometer, +-2 g (Section 2.1.2)."""

    sigma_mps2: float = 0.6
    offset_mps2: float = 0.1  # mean offset; per run offset ~ N(offset, offset_spread)
    offset_spread_mps2: float = 0.05
    ring_gain: float = 0.04  # ringing amplitude per m/s^2 of deceleration lost at the stop
    ring_hz: float = 1.5  # eigenfrequency of the pitch ringing (1-2 Hz in the paper)
    ring_zeta: float = 0.15
    range_mps2: float = 2.0 * G_MPS2


@dataclass(frozen=True)
class SpeedTrace:
    """One simulated manoeuvre; arrays of length n, sample k at time k * DT_S."""

    kind: str
    t: np.ndarray
    v: np.ndarray  # true speed, m/s
    a: np.ndarray  # true longitudinal acceleration, m/s^2
    wheel: np.ndarray  # wheel-speed sensor reading, m/s (0 on dropout)
    accel: np.ndarray  # accelerometer reading, m/s^2
    abs_active: np.ndarray  # bool: ABS cycling (wheel slip present)
    accel_offset: float  # this run's accelerometer offset, m/s^2


@dataclass(frozen=True)
class _Profile:
    v0: float
    t_brake: float
    decel: float  # > 0
    jerk: float  # > 0, jerk limit of the brake application
    launch_accel: float  # > 0 for launch_brake (accelerate to v0 first)
    release_kmh: float  # below this speed the driver eases to release_decel (0: never)
    release_decel: float
    abs_hz: float
    abs_phase: float


def _draw_profile(kind: str, rng: np.random.Generator) -> _Profile:
    u = rng.uniform
    if kind == "paper":
        return _Profile(u(81.0, 87.0) * MPS_PER_KMH, u(1.5, 2.5), u(7.3, 8.7), u(25.0, 35.0), 0.0,
                        0.0, 0.0, 0.0, 0.0)
    if kind == "gentle":
        return _Profile(u(40.0, 60.0) * MPS_PER_KMH, u(1.5, 2.5), u(2.5, 3.5), u(8.0, 12.0), 0.0,
                        u(8.0, 12.0), u(1.0, 1.8), 0.0, 0.0)
    if kind == "abs":
        return _Profile(u(81.0, 87.0) * MPS_PER_KMH, u(1.5, 2.5), u(9.2, 9.8), u(40.0, 60.0), 0.0,
                        0.0, 0.0, u(5.0, 8.0), u(0.0, 2.0 * math.pi))
    if kind == "launch_brake":
        return _Profile(u(35.0, 45.0) * MPS_PER_KMH, u(0.8, 1.2), u(4.0, 6.0), u(15.0, 25.0), u(2.0, 3.0),
                        u(6.0, 10.0), u(1.5, 2.5), 0.0, 0.0)
    if kind == "road":  # t_brake: the cruise's length (from reaching v0)
        return _Profile(u(*ROAD_SPEED_MPS), u(30.0, 60.0), u(2.5, 3.5), u(8.0, 12.0), u(1.5, 2.5),
                        u(8.0, 12.0), u(1.0, 1.8), 0.0, 0.0)
    raise ValueError(f"unknown manoeuvre {kind!r}; choose from {', '.join(MANOEUVRES)}")


def _road_targets(p: _Profile, rng: np.random.Generator) -> list[tuple[float, float]]:
    """"road": (speed target m/s, rate m/s^2) for each 15 s of the cruise, the first v0."""
    n = int(p.t_brake // 15.0) + 1
    out = [(p.v0, 0.5)]
    for _ in range(n - 1):
        out.append((float(rng.uniform(*ROAD_SPEED_MPS)), float(rng.uniform(0.3, 0.8))))
    return out


def _truth(cfg: ManoeuvreConfig, p: _Profile, rng: np.random.Generator
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(v, a, braking flag, index of the stop) on the 2 ms grid."""
    dt = DT_S
    road = cfg.kind == "road"
    launch = p.launch_accel > 0.0 and not (road and cfg.rolling)
    # Cruise fluctuation: white noise through a 1 Hz first-order low-pass, std cruise_accel_std.
    alpha = math.exp(-2.0 * math.pi * 1.0 * dt)
    gain = cfg.cruise_accel_std * math.sqrt(1.0 - alpha * alpha)
    n_max = round((150.0 if road else MAX_S) / dt)
    white = rng.standard_normal(n_max).tolist()
    targets = _road_targets(p, rng) if road else []
    v_list: list[float] = []
    a_list: list[float] = []
    brk: list[bool] = []
    v = 0.0 if launch else p.v0
    a = 0.0
    fluct = cfg.cruise_accel_std * white[0]
    phase = "rest" if launch else "cruise"
    t_cruise = 0.0 if road else -1.0  # road: when the cruise began (its length is t_brake)
    stop_k = -1
    for k in range(n_max):
        t = k * dt
        v_list.append(v)
        a_list.append(a)
        if phase == "rest":
            a_cmd = 0.0
            if t >= (1.0 if road else p.t_brake):  # launch_brake: t_brake is the launch time
                phase = "launch"
        elif phase == "launch":
            a_cmd = p.launch_accel
            if v >= p.v0:
                phase, t_cruise = ("cruise", t) if road else ("brake", t_cruise)
        elif phase == "cruise":
            fluct = alpha * fluct + gain * white[k]
            a_cmd = fluct
            if road:  # towards the target of the moment, at its rate
                target, rate = targets[min(int((t - t_cruise) / 15.0), len(targets) - 1)]
                a_cmd += max(-rate, min(rate, 0.5 * (target - v)))
            if t >= (t_cruise + p.t_brake if road else p.t_brake):
                phase = "brake"
        elif phase == "brake":
            a_cmd = -p.decel
            if p.release_kmh > 0.0 and v < p.release_kmh * MPS_PER_KMH:
                a_cmd = -p.release_decel
        else:  # stopped
            a_cmd = 0.0
        brk.append(phase == "brake")
        if phase in ("stopped", "rest"):
            a = 0.0
            v = 0.0
        else:
            jerk = p.jerk if phase == "brake" else 30.0
            a += max(-jerk * dt, min(jerk * dt, a_cmd - a))
            v += a * dt
            if phase == "brake" and v <= 0.0:
                v = 0.0
                a = 0.0
                phase = "stopped"
                stop_k = k + 1
        if stop_k >= 0 and k + 1 >= stop_k + round(cfg.standstill_s / dt):
            break
    if stop_k < 0:
        raise RuntimeError(f"manoeuvre did not stop within {n_max * dt:g} s")
    return np.asarray(v_list), np.asarray(a_list), np.asarray(brk, dtype=bool), stop_k


def simulate_speed(
    seed: int = 0, manoeuvre: ManoeuvreConfig = ManoeuvreConfig(),
    wheel: WheelSensorConfig = WheelSensorConfig(), accel: AccelSensorConfig = AccelSensorConfig(),
) -> SpeedTrace:
    """One seeded manoeuvre with both sensors; streams 'speed.manoeuvre', 'speed.wheel',
    'speed.accel' are independent (vecu.plant.throttle.rng_streams)."""
    rngs = rng_streams(seed, STREAMS)
    prof = _draw_profile(manoeuvre.kind, rngs["speed.manoeuvre"])
    v, a, braking, stop_k = _truth(manoeuvre, prof, rngs["speed.manoeuvre"])
    n = len(v)
    t = np.arange(n) * DT_S

    # Wheel-speed sensor.
    rw = rngs["speed.wheel"]
    nz, ud = rw.standard_normal(n), rw.uniform(size=n)
    vk = v / MPS_PER_KMH
    sig = np.minimum(wheel.sigma_mps * np.maximum(1.0, wheel.sigma_ref_kmh / np.maximum(vk, 1e-6)),
                     wheel.sigma_max_mps)
    abs_on = braking & (prof.abs_hz > 0.0) & (vk > wheel.abs_off_kmh)
    slip = np.where(
        abs_on, wheel.abs_slip_max * 0.5 * (1.0 - np.cos(2.0 * math.pi * prof.abs_hz * t
                                                          + prof.abs_phase)), 0.0)
    p_drop = np.clip((wheel.dropout_none_kmh - vk)
                     / (wheel.dropout_none_kmh - wheel.dropout_full_kmh), 0.0, 1.0)
    ws = np.maximum(v * (1.0 - slip) + sig * nz, 0.0)
    ws = np.where(ud < p_drop, 0.0, ws)

    # Accelerometer.
    ra = rngs["speed.accel"]
    offset = accel.offset_mps2 + accel.offset_spread_mps2 * float(ra.standard_normal())
    na = ra.standard_normal(n)
    ring = np.zeros(n)
    a_lost = -float(a[stop_k - 1]) if stop_k > 0 else 0.0  # deceleration released at the stop
    wn = 2.0 * math.pi * accel.ring_hz
    wd = wn * math.sqrt(1.0 - accel.ring_zeta ** 2)
    tr = t[stop_k:] - t[stop_k]
    ring[stop_k:] = (accel.ring_gain * a_lost * np.exp(-accel.ring_zeta * wn * tr)
                     * np.cos(wd * tr))
    am = np.clip(a + offset + ring + accel.sigma_mps2 * na, -accel.range_mps2, accel.range_mps2)
    return SpeedTrace(manoeuvre.kind, t, v, a, ws, am, abs_on, offset)
