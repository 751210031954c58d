"""Driveline: the engine speed and throttle setpoint that carry the car at a given speed (road
load, six gears, torque converter; docs/models.md, "One car")."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vecu.models.manifold_params import ManifoldParams
from vecu.units import G_MPS2

RPM_PER_RAD_S = 60.0 / (2.0 * math.pi)


@dataclass(frozen=True)
class Driveline:
    """Gearbox, final drive, tyres and road loads of the simulated car (a 5.7 L V8 coupe with a
    six-speed gearbox, T56-like ratios); shift and converter laws as in the module docstring."""

    gear_ratios: tuple[float, ...] = (2.66, 1.78, 1.30, 1.00, 0.74, 0.50)
    final_drive: float = 3.42
    tyre_radius_m: float = 0.32
    efficiency: float = 0.9
    max_torque_nm: float = 470.0  # flat: the pedal's full scale
    rolling_resistance: float = 0.012  # c_rr
    drag_area_m2: float = 0.65  # C_d A
    air_density_kg_m3: float = 1.2
    n_up_rpm: tuple[float, float] = (1800.0, 4500.0)  # upshift at pedal 0 / 1
    n_down_rpm: tuple[float, float] = (1100.0, 2100.0)  # downshift at pedal 0 / 1
    n_stall_rpm: float = 2200.0  # converter stall speed at full pedal
    shift_s: float = field(default=0.3, metadata={"bounds": (0.002, 2.0)})
    demand_tau_s: float = field(default=1.0, metadata={"bounds": (0.002, 10.0)})

    def rpm_per_mps(self, gear: int) -> float:
        """Engine speed per vehicle speed in gear (1-based), rpm / (m/s)."""
        return (self.gear_ratios[gear - 1] * self.final_drive / self.tyre_radius_m
                * RPM_PER_RAD_S)


@dataclass
class DrivelineState:
    """What carries over from one sample (and one manoeuvre) to the next."""

    gear: int = 0  # 0: not yet chosen (the first sample picks the gear for its speed)
    shift_from: float = 0.0  # rpm per m/s of the gear shifted from
    shift_left_s: float = 0.0
    demand: float = 0.0  # the pedal low-passed over demand_tau_s: what the shift lines read


@dataclass(frozen=True)
class EngineTrack:
    """Per sample: gear (1-based), engine speed N (rpm), throttle setpoint (rad), pedal (0-1)."""

    gear: np.ndarray
    n_rpm: np.ndarray
    ta_sp: np.ndarray
    pedal: np.ndarray


def _pedal(force: float, wheel: float, line: Driveline, gear: int) -> float:
    """Pedal (0-1) for the tractive force in gear: torque F r_w / (i_g i_f eta) over T_max."""
    return min(max(force * wheel / (line.gear_ratios[gear - 1] * line.max_torque_nm), 0.0), 1.0)


def engine_track(v: np.ndarray, a: np.ndarray, dt_s: float, mass_kg: float, line: Driveline,
                 engine: ManifoldParams, state: DrivelineState) -> EngineTrack:
    """The engine behind the vehicle speed v (m/s) and acceleration a (m/s^2) sampled every
    dt_s; `state` is advanced in place (module docstring)."""
    n = len(v)
    gears = np.empty(n, dtype=np.int64)
    ns = np.empty(n)
    sps = np.empty(n)
    pedals = np.empty(n)
    top = len(line.gear_ratios)
    ratios = [line.rpm_per_mps(g) for g in range(1, top + 1)]
    wheel = line.tyre_radius_m / (line.final_drive * line.efficiency)
    load = mass_kg * G_MPS2 * line.rolling_resistance
    aero = 0.5 * line.air_density_kg_m3 * line.drag_area_m2
    up0, up1 = line.n_up_rpm
    dn0, dn1 = line.n_down_rpm
    idle, n_max = engine.n_idle_rpm, engine.n_max_rpm
    gear, shift_from, shift_left = state.gear, state.shift_from, state.shift_left_s
    demand = state.demand
    smooth = min(dt_s / line.demand_tau_s, 1.0)
    for k, (vk, ak) in enumerate(zip(v.tolist(), a.tolist())):
        force = mass_kg * ak + (load + aero * vk * vk if vk > 0.0 else 0.0)
        if gear == 0:  # the first sample: the highest gear that would not shift down
            gear = top
            while gear > 1 and ratios[gear - 1] * vk < dn0 + _pedal(force, wheel, line, gear) * (
                    dn1 - dn0):
                gear -= 1
            demand = _pedal(force, wheel, line, gear)
        pedal = _pedal(force, wheel, line, gear)
        demand += smooth * (pedal - demand)
        n_gear = ratios[gear - 1] * vk
        if gear < top and pedal > 0.0 and n_gear > min(up0 + demand * (up1 - up0), n_max):
            shift_from, shift_left, gear = ratios[gear - 1], line.shift_s, gear + 1
        elif gear > 1 and n_gear < dn0 + demand * (dn1 - dn0):
            shift_from, shift_left, gear = ratios[gear - 1], line.shift_s, gear - 1
        ratio = ratios[gear - 1]
        if shift_left > 0.0:  # the shift's inertia phase: N moves to the new ratio
            frac = shift_left / line.shift_s
            ratio = frac * shift_from + (1.0 - frac) * ratio
            shift_left = max(shift_left - dt_s, 0.0)
        n_eng = min(max(ratio * vk, idle + pedal * (line.n_stall_rpm - idle)), n_max)
        floor = engine.throttle_floor_rad(n_eng)
        gears[k], ns[k], pedals[k] = gear, n_eng, pedal
        sps[k] = floor + pedal * (0.5 * math.pi - floor)
    state.gear, state.shift_from, state.shift_left_s = gear, shift_from, shift_left
    state.demand = demand
    return EngineTrack(gears, ns, sps, pedals)
