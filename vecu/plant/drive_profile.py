"""Seeded US06-like drive profile for the intake-manifold plant (Dutka 2006, Section IV, Fig. 2):
N in [700, 5600] rpm, throttle setpoint steps within [floor(N), 90 deg] (docs/models.md, "Drive
profile")."""

# ruff: noqa: FURB136 (x if c else y in the kernel mirrors min()/max(), NaN included)
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vecu.kernels import kernel
from vecu.models.manifold_params import V8_5L7, ManifoldParams
from vecu.rng import rng_streams

STREAM = "manifold.profile"
MANEUVERS = ("pull", "tip_in", "cruise", "decel", "idle")
MANEUVER_P = (0.3, 0.25, 0.25, 0.12, 0.08)


@dataclass(frozen=True)
class DriveProfileConfig:
    """Cycle length and grid; WOT pull rates per gear (rpm/s) and upshift speed ratios."""

    duration_s: float = 80.0
    dt_s: float = 0.01  # grid of the stored profile (events interpolate N, hold the setpoint)
    gear_rate_rpm_s: tuple[float, ...] = (2200.0, 1300.0, 850.0, 600.0)
    shift_ratio: tuple[float, ...] = (0.62, 0.70, 0.76)
    shift_time_s: float = 0.3  # throttle lifted to the floor during an upshift


@kernel
def profile_at(prof_n, prof_sp, dt_p, time):
    """(N, TA_SP) at `time` on the grid t_k = k dt_p: N interpolated linearly, the setpoint
    held (snaps stay snaps); time clamped to the grid."""
    last = len(prof_n) - 1
    fx = time / dt_p
    fx = 0.0 if 0.0 > fx else fx
    fx = float(last) if float(last) < fx else fx
    i = int(fx)
    i = last - 1 if last - 1 < i else i
    frac = fx - i
    n = prof_n[i] + frac * (prof_n[i + 1] - prof_n[i])
    return n, prof_sp[i if frac < 1.0 else i + 1]


@dataclass(frozen=True)
class DriveProfile:
    """Engine speed (rpm) and throttle setpoint (rad) on a uniform grid t_k = k dt."""

    dt_s: float
    n_rpm: np.ndarray
    ta_sp: np.ndarray

    @property
    def duration_s(self) -> float:
        return self.dt_s * (len(self.n_rpm) - 1)

    @property
    def t(self) -> np.ndarray:
        return self.dt_s * np.arange(len(self.n_rpm))

    def at(self, t: float) -> tuple[float, float]:
        """(N, TA_SP) at time t (profile_at)."""
        n, sp = profile_at(self.n_rpm, self.ta_sp, self.dt_s, float(t))
        return float(n), float(sp)


class _Builder:
    """Appends samples of (N, setpoint in deg) on the grid; setpoints clipped to [floor, 90 deg]."""

    def __init__(self, dt: float, params: ManifoldParams, rng: np.random.Generator) -> None:
        self.dt = dt
        self.p = params
        self.rng = rng
        self.n = params.n_idle_rpm
        self.ns: list[float] = []
        self.sps: list[float] = []

    @property
    def t(self) -> float:
        return len(self.ns) * self.dt

    def _floor_deg(self) -> float:
        return math.degrees(self.p.throttle_floor_rad(self.n))

    def run(self, duration: float, sp_deg: float | None, rate: float, n_target: float) -> None:
        """Hold setpoint sp_deg (None: the floor) while N moves to n_target at |rate| rpm/s."""
        lo, hi = self.p.n_idle_rpm, self.p.n_max_rpm
        target = min(max(n_target, lo), hi)
        for _ in range(max(1, round(duration / self.dt))):
            step = abs(rate) * self.dt
            self.n = min(self.n + step, target) if self.n < target else max(self.n - step, target)
            floor = self._floor_deg()
            sp = floor if sp_deg is None else min(max(sp_deg, floor), 90.0)
            self.ns.append(self.n)
            self.sps.append(sp)

    def idle(self, duration: float) -> None:
        self.run(duration, None, 1500.0, self.p.n_idle_rpm)

    def pull(self, sp_deg: float, gears: int, shift_rpm: float, cfg: DriveProfileConfig) -> None:
        """Snap to sp_deg and accelerate through `gears` gears, upshifting at shift_rpm."""
        frac = 0.35 + 0.65 * sp_deg / 90.0  # less throttle, slower rise
        for g in range(gears):
            rate = cfg.gear_rate_rpm_s[min(g, len(cfg.gear_rate_rpm_s) - 1)] * frac
            while self.n < shift_rpm - 1e-9 and self.t < cfg.duration_s:
                self.run(self.dt, sp_deg, rate, shift_rpm)
            if g == gears - 1:
                break
            ratio = cfg.shift_ratio[min(g, len(cfg.shift_ratio) - 1)]
            drop = self.n * (1.0 - ratio)
            self.run(cfg.shift_time_s, None, drop / cfg.shift_time_s, self.n * ratio)

    def cruise(self, duration: float) -> None:
        """Part load: setpoint steps of a few degrees every 0.5-2.5 s, N drifting to a target."""
        end = self.t + duration
        n_target = self.rng.uniform(1600.0, 3200.0)
        while self.t < end:
            d = min(self.rng.uniform(0.5, 2.5), end - self.t)
            self.run(d, self.rng.uniform(12.0, 28.0), 300.0, n_target)

    def tip_in(self, duration: float) -> None:
        self.run(duration, self.rng.uniform(40.0, 90.0), self.rng.uniform(600.0, 1400.0),
                 self.p.n_max_rpm)

    def decel(self, to_rpm: float) -> None:
        """Snap tip-out to the floor; N falls (engine braking) to to_rpm."""
        rate = self.rng.uniform(400.0, 1000.0)
        self.run(max((self.n - to_rpm) / rate, self.dt), None, rate, to_rpm)


def us06_like(seed: int = 0, config: DriveProfileConfig = DriveProfileConfig(),
              params: ManifoldParams = V8_5L7) -> DriveProfile:
    """Seeded aggressive cycle: idle, WOT launch to the rev limit, random maneuvers, back to idle
    (both ends of the speed range every time). Same seed, same profile."""
    rng = rng_streams(seed, (STREAM,))[STREAM]
    b = _Builder(config.dt_s, params, rng)
    end = config.duration_s
    b.idle(rng.uniform(1.5, 3.0))
    b.pull(90.0, 3, params.n_max_rpm, config)
    b.decel(rng.uniform(1500.0, 2500.0))
    b.cruise(rng.uniform(3.0, 6.0))
    b.decel(params.n_idle_rpm)
    b.idle(rng.uniform(1.0, 3.0))
    while b.t < end - 6.0:
        kind = rng.choice(MANEUVERS, p=MANEUVER_P)
        if kind == "pull":
            sp, gears = rng.uniform(50.0, 90.0), int(rng.integers(2, 5))
            b.pull(sp, gears, rng.uniform(4200.0, 5600.0), config)
        elif kind == "tip_in":
            b.tip_in(rng.uniform(1.0, 3.0))
        elif kind == "cruise":
            b.cruise(rng.uniform(2.0, 6.0))
        elif kind == "decel":
            b.decel(rng.uniform(900.0, 2000.0))
        else:
            b.decel(params.n_idle_rpm)
            b.idle(rng.uniform(1.0, 2.5))
    b.decel(params.n_idle_rpm)
    while b.t < end + config.dt_s:
        b.idle(config.dt_s)
    k = round(end / config.dt_s) + 1
    return DriveProfile(dt_s=config.dt_s, n_rpm=np.array(b.ns[:k]),
                        ta_sp=np.radians(np.array(b.sps[:k])))
