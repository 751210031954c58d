"""The drive: one car's speed, acceleration and engine, read by every plant part tick by tick
(longitudinal manoeuvres after Hernandez 2005, the driveline behind them; docs/models.md, "One
car"). `LongitudinalPart` sends the drive's speed sensors (ESC_Motion).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vecu.can_message import message
from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.codec import DbcCodec
from vecu.models.lateral import VehicleParams
from vecu.models.manifold_params import V8_5L7, ManifoldParams
from vecu.plant.drive_profile import DriveProfile
from vecu.plant.driveline import Driveline, DrivelineState, EngineTrack, engine_track
from vecu.plant.longitudinal import (
    DT_S,
    AccelSensorConfig,
    ManoeuvreConfig,
    SpeedTrace,
    WheelSensorConfig,
    simulate_speed,
)
from vecu.plant.part import Send, payload_rows
from vecu.units import MPS_PER_KMH

# the default: the paper's braking, one launch-and-brake cycle, then road legs (launch, 30-60 s
# at 72-108 km/h, brake to rest) for as long as the plant runs
SEQUENCE = ("paper", "launch_brake", "road")
KEEP_S = 120.0  # legs ending this long before the furthest sample asked for are dropped


@dataclass(frozen=True)
class Leg:
    """One manoeuvre of the drive: samples start .. start + len(trace.v) - 1 of the 2 ms grid."""

    index: int
    start: int
    trace: SpeedTrace
    engine: EngineTrack
    profile: DriveProfile  # the engine's (N, throttle setpoint) for vecu.plant.node.ManifoldPart

    @property
    def end(self) -> int:
        return self.start + len(self.trace.v)


class Drive:
    """The car's motion on the 2 ms grid (sample k at k * DT_S), leg by leg (module docstring)."""

    dt_s = DT_S

    def __init__(self, seed: int, sequence: tuple[str, ...] | None = None,
                 wheel: WheelSensorConfig = WheelSensorConfig(),
                 accel: AccelSensorConfig = AccelSensorConfig(),
                 vehicle: VehicleParams = VehicleParams(), driveline: Driveline = Driveline(),
                 engine: ManifoldParams = V8_5L7) -> None:
        self.seed = seed
        self.sequence = tuple(sequence) if sequence else SEQUENCE
        self._sensors = (wheel, accel)
        self._vehicle, self._line, self._engine = vehicle, driveline, engine
        self._state = DrivelineState()
        self._legs: list[Leg] = []
        self._made = 0  # legs made so far (the next leg's index)
        self._next_start = 0
        self._furthest = 0

    def _make(self) -> Leg:
        i = self._made
        kind = self.sequence[min(i, len(self.sequence) - 1)]
        trace = simulate_speed(seed=(self.seed << 16) + i,
                               manoeuvre=ManoeuvreConfig(kind=kind, rolling=i == 0),
                               wheel=self._sensors[0], accel=self._sensors[1])
        eng = engine_track(trace.v, trace.a, DT_S, self._vehicle.mass_kg, self._line,
                           self._engine, self._state)
        # the profile's last point holds the leg's last sample (the next leg starts there)
        profile = DriveProfile(dt_s=DT_S, n_rpm=np.append(eng.n_rpm, eng.n_rpm[-1]),
                               ta_sp=np.append(eng.ta_sp, eng.ta_sp[-1]))
        leg = Leg(i, self._next_start, trace, eng, profile)
        self._made += 1
        self._next_start = leg.end
        self._legs.append(leg)
        return leg

    def leg(self, index: int) -> Leg:
        """Leg `index` (0: the first manoeuvre); made on demand."""
        while self._made <= index:
            self._make()
        for leg in self._legs:
            if leg.index == index:
                return leg
        raise LookupError(f"drive leg {index} was dropped (more than {KEEP_S} s behind)")

    def leg_at(self, k: int) -> Leg:
        """The leg that holds sample k."""
        self._furthest = max(self._furthest, k)
        while self._next_start <= k:
            self._make()
        keep = self._furthest - round(KEEP_S / DT_S)
        while len(self._legs) > 1 and self._legs[0].end < keep:
            self._legs.pop(0)
        for leg in reversed(self._legs):
            if leg.start <= k:
                return leg
        raise LookupError(f"drive sample {k} was dropped (more than {KEEP_S} s behind)")

    def speed(self, k: int) -> float:
        """True speed (m/s) at sample k."""
        leg = self.leg_at(k)
        return float(leg.trace.v[k - leg.start])

    def speeds(self, k0: int, k1: int) -> np.ndarray:
        """True speeds (m/s) at samples k0 .. k1 - 1."""
        out = np.empty(k1 - k0)
        k = k0
        while k < k1:
            leg = self.leg_at(k)
            m = min(k1, leg.end) - k
            out[k - k0:k - k0 + m] = leg.trace.v[k - leg.start:k - leg.start + m]
            k += m
        return out


class LongitudinalPart:
    """Longitudinal vehicle (Hernandez 2005): ESC_Motion (wheel speed, accelerometer) every 2 ms,
    sample t_ns / 2 ms of the drive (without one, its own from seed and sequence)."""

    truth_message = "TRUTH_Speed"  # its truth frame (dbc/vecu_truth.dbc; PlantNode.enable_truth)
    name = "longitudinal"
    period_ns = 2 * NS_PER_MS

    def __init__(self, codec: DbcCodec, seed: int, sequence: tuple[str, ...] | None = None,
                 wheel: WheelSensorConfig = WheelSensorConfig(),
                 accel: AccelSensorConfig = AccelSensorConfig(), drive: Drive | None = None) -> None:
        self._msg = codec["ESC_Motion"]
        self._frame = self._msg.framer(("ESC_WheelSpeed", "ESC_LongAccel"))
        self.drive = drive if drive is not None else Drive(seed, sequence, wheel, accel)
        self._cols: tuple[list[float], ...] = ()
        self._payloads: list[bytearray | None] = []
        self._leg = leg = self.drive.leg_at(0)
        self._enter(leg)
        self.truth_msg = None  # TRUTH_Speed codec when recording truth
        self.v = self.a = self.wheel = self.accel = 0.0  # truth and raw sensors of the last tick (SI)

    def _enter(self, leg: Leg) -> None:
        self._leg = leg
        trace = leg.trace
        self._cols = (trace.v.tolist(), trace.a.tolist(), trace.wheel.tolist(),
                      trace.accel.tolist())
        # the whole manoeuvre's ESC_Motion payloads at once (FrameCodec.encode_rows: the
        # framer's payloads); rows it leaves (none for finite sensors) go to the framer
        encoded = self._msg.encode_rows(("ESC_WheelSpeed", "ESC_LongAccel"),
                                        (trace.wheel / MPS_PER_KMH, trace.accel))
        self._payloads = payload_rows(encoded, len(trace.v))

    def tick(self, t_ns: int, send: Send) -> None:
        k = t_ns // self.period_ns
        leg = self._leg
        if not leg.start <= k < leg.end:
            leg = self.drive.leg_at(k)
            self._enter(leg)
        i = k - leg.start
        cols = self._cols
        v, a, wheel, accel = cols[0][i], cols[1][i], cols[2][i], cols[3][i]
        self.v, self.a, self.wheel, self.accel = v, a, wheel, accel
        ts = t_ns / NS_PER_S
        data = self._payloads[i]
        if data is not None:
            send(message(ts, self._msg.frame_id, self._msg.is_extended, data, self._msg.is_fd))
        else:
            send(self._frame(ts, wheel / MPS_PER_KMH, accel)[0])
        if self.truth_msg is not None:
            send(self.truth_msg.frame({"TRU_VehSpeed": v / MPS_PER_KMH, "TRU_VehAccel": a}, ts))
