"""Wire plant, fault injector, ECU and recorder onto one bus and one scheduler, run, summarise."""

from __future__ import annotations

import gc
import math
import time
from dataclasses import asdict, dataclass, field
from typing import Any

import can
import numpy as np

from vecu.bus import open_bus
from vecu.clock import NS_PER_MS, NS_PER_S, SimClock, WallClock
from vecu.codec import DbcCodec
from vecu.ecu.node import SOURCE_ESTIMATE, EcuConfig, EcuNode
from vecu.estimators.registry import make_throttle_estimator
from vecu.faults import FaultInjector, FaultKind, FaultTarget, parse_kind
from vecu.plant.node import ThrottlePlantNode
from vecu.plant.throttle import (InputConfig, InputGenerator, ThrottlePlant, ThrottlePlantConfig,
                                 rng_streams)
from vecu.recorder import Recorder
from vecu.scheduler import Scheduler
from vecu.stats import RunningStats

TICK_NS = NS_PER_MS
PRIO_PLANT, PRIO_ECU, PRIO_PROBE, PRIO_RECORD = 0, 10, 20, 30


@dataclass(frozen=True)
class RunConfig:
    """Everything `vecu run` needs; defaults are the demo (10 s, TPS dead at 5 s)."""

    duration_s: float = 10.0
    seed: int = 0
    noise_scale: float = 1.0
    kill_tps_at_s: float | None = 5.0
    fault: str = "dead"
    fault_value: float | None = None
    estimator: str = "production"
    realtime: bool = False
    interface: str | None = None
    channel: str | None = None
    bitrate: int | None = None
    log_path: str | None = None
    keep_series: bool = False
    ecu: EcuConfig = field(default_factory=EcuConfig)

    def validate(self) -> None:
        if not (self.duration_s > 0 and math.isfinite(self.duration_s)):
            raise ValueError(f"duration must be a positive number of seconds, got {self.duration_s}")
        if self.kill_tps_at_s is not None and not 0 <= self.kill_tps_at_s < self.duration_s:
            raise ValueError(f"kill time {self.kill_tps_at_s} s is outside the run (0..{self.duration_s} s)")
        if self.noise_scale < 0:
            raise ValueError(f"noise scale must be >= 0, got {self.noise_scale}")
        kind = parse_kind(self.fault)
        if kind == FaultKind.CLEAR:
            raise ValueError("fault kind 'clear' cannot be injected")


@dataclass(frozen=True)
class Series:
    """Per-tick signals (deg) for plots."""

    t_s: np.ndarray
    theta_true: np.ndarray
    theta_sensor: np.ndarray  # NaN where no valid TPS frame
    theta_broadcast: np.ndarray
    theta_est: np.ndarray
    theta_est_std: np.ndarray
    source: np.ndarray
    status: np.ndarray


@dataclass(frozen=True)
class RunResult:
    summary: dict[str, Any]
    series: Series | None


class ThrottleProbe:
    """Reads truth and ECU output after each tick: error statistics split at the kill time."""

    def __init__(self, plant: ThrottlePlantNode, ecu: EcuNode, kill_ns: int | None,
                 n_ticks: int, keep_series: bool) -> None:
        self.plant, self.ecu, self.kill_ns = plant, ecu, kill_ns
        self.calibration = plant.calibration
        self.bc = {"before_kill": RunningStats(), "after_kill": RunningStats()}
        self.est = {"before_kill": RunningStats(), "after_kill": RunningStats()}
        self.nan_outputs = 0
        self._k = 0
        self.series = np.full((8, n_ticks), np.nan) if keep_series else None

    def tick(self, t_ns: int) -> None:
        ecu = self.ecu
        truth = self.plant.theta
        angle = ecu.angle
        est = ecu.estimator
        if not math.isfinite(angle):
            self.nan_outputs += 1
        phase = "after_kill" if self.kill_ns is not None and t_ns >= self.kill_ns else "before_kill"
        self.bc[phase].add(angle - truth)
        self.est[phase].add(est.theta_deg - truth)
        s = self.series
        if s is not None and self._k < s.shape[1]:
            k = self._k
            s[0, k] = t_ns / NS_PER_S
            s[1, k] = truth
            v = self.plant.tps_voltage
            s[2, k] = self.calibration.angle(v) if v is not None else np.nan
            s[3, k] = angle
            s[4, k] = est.theta_deg
            s[5, k] = est.theta_std_deg
            s[6, k] = ecu.source
            s[7, k] = int(ecu.status)
        self._k += 1


def run(config: RunConfig) -> RunResult:
    """Run plant + injector + ECU (+ recorder) for config.duration_s on one scheduler."""
    config.validate()
    rngs = rng_streams(config.seed, ("throttle.input", "throttle.plant", "faults"))
    codec = DbcCodec()
    bus_args = dict(interface=config.interface, channel=config.channel, bitrate=config.bitrate)
    clock = WallClock() if config.realtime else SimClock()
    sched = Scheduler(clock)
    n_ticks = int(round(config.duration_s * 1000))
    end_ns = n_ticks * TICK_NS
    kill_ns = None if config.kill_tps_at_s is None else int(round(config.kill_tps_at_s * NS_PER_S))
    buses: list[can.BusABC] = []
    recorder: Recorder | None = None
    try:
        if config.log_path:  # open first so it sees every frame
            rec_bus = open_bus(**bus_args, receive_own_messages=False)
            buses.append(rec_bus)
            recorder = Recorder(rec_bus, config.log_path)
        plant_bus = open_bus(**bus_args)
        buses.append(plant_bus)
        ecu_bus = open_bus(**bus_args)
        buses.append(ecu_bus)
        injector = FaultInjector(rngs["faults"])
        plant = ThrottlePlantNode(
            plant_bus, codec,
            ThrottlePlant(ThrottlePlantConfig(noise_scale=config.noise_scale), rngs["throttle.plant"]),
            InputGenerator(InputConfig(), rngs["throttle.input"]), injector,
            config.ecu.calibration)
        estimator = make_throttle_estimator(config.estimator, noise_scale=config.noise_scale)
        ecu = EcuNode(ecu_bus, codec, estimator, config.ecu)
        probe = ThrottleProbe(plant, ecu, kill_ns, n_ticks, config.keep_series)
        sched.every(TICK_NS, plant.tick, name="plant", priority=PRIO_PLANT)
        ecu_task = sched.every(TICK_NS, ecu.tick, name="ecu", priority=PRIO_ECU)
        sched.every(TICK_NS, probe.tick, name="probe", priority=PRIO_PROBE)
        if recorder is not None:
            sched.every(TICK_NS, recorder.drain, name="recorder", priority=PRIO_RECORD)
        if kill_ns is not None:
            kind = parse_kind(config.fault)
            sched.at(kill_ns, lambda t: injector.inject(t, FaultTarget.TPS, kind, config.fault_value,
                                                        source="schedule"),
                     name="kill-tps", priority=PRIO_PLANT - 1)
        if config.realtime:
            _warm_up(config)
        wall0 = time.perf_counter()
        clock.start()  # set-up time must not count against the first deadlines
        sched.run_until(end_ns)
        wall = time.perf_counter() - wall0
        ecu.overruns = ecu_task.overruns
        if recorder is not None:
            recorder.drain(end_ns)
        summary = _summary(config, sched, plant, ecu, probe, injector, kill_ns, n_ticks, wall,
                           recorder)
    finally:
        if recorder is not None:
            recorder.close()
        for bus in buses:
            bus.shutdown()
    series = None
    if probe.series is not None:
        s = probe.series
        series = Series(s[0], s[1], s[2], s[3], s[4], s[5], s[6].astype(int), s[7].astype(int))
    return RunResult(summary=summary, series=series)


def _warm_up(config: RunConfig) -> None:
    """Before a wall-clock run: exercise a throwaway estimator (first numpy calls cost ~7 ms)
    and move set-up objects out of the garbage collector's way, so the first ticks keep time."""
    spare = make_throttle_estimator(config.estimator, noise_scale=config.noise_scale)
    for k in range(200):
        spare.step(2.0, 4.0 + (k % 7))
    gc.collect()
    gc.freeze()


def _summary(config: RunConfig, sched: Scheduler, plant: ThrottlePlantNode, ecu: EcuNode,
             probe: ThrottleProbe, injector: FaultInjector, kill_ns: int | None, n_ticks: int,
             wall_s: float, recorder: Recorder | None) -> dict[str, Any]:
    mon = ecu.monitor
    detect_ns = mon.first_fault_ns
    false_alarm = detect_ns is not None and (kill_ns is None or detect_ns < kill_ns)
    detected = detect_ns is not None and kill_ns is not None and detect_ns >= kill_ns
    throttle: dict[str, Any] = {
        "estimator": ecu.estimator.name,
        "estimator_resets": ecu.estimator.resets,
        "estimator_faults": ecu.estimator_faults,
        "kill_time_s": None if kill_ns is None else kill_ns / NS_PER_S,
        "fault": config.fault if kill_ns is not None else None,
        "detected": detected,
        "detection_time_s": detect_ns / NS_PER_S if detect_ns is not None else None,
        "detection_latency_ms": (detect_ns - kill_ns) / NS_PER_MS if detected else None,
        "detected_as": mon.first_fault_status.name.lower() if mon.first_fault_status else None,
        "false_alarm": false_alarm,
        "final_status": ecu.status.name.lower(),
        "final_source": "estimate" if ecu.source == SOURCE_ESTIMATE else "sensor",
        "dtc": mon.dtc.name.lower(),
        "nan_outputs": probe.nan_outputs,
        # ticks without an estimate frame on the bus (skipped releases in live runs, send errors)
        "missing_broadcasts": n_ticks - ecu.estimates_sent,
    }
    for phase in ("before_kill", "after_kill"):
        throttle[phase] = {"broadcast_error_deg": probe.bc[phase].as_dict(),
                           "estimate_error_deg": probe.est[phase].as_dict()}
    sim_s = n_ticks / 1000.0
    return {
        "config": {k: v for k, v in asdict(config).items() if k != "ecu"},
        "ticks": n_ticks,
        "overruns": sched.overruns,
        "tasks": {t.name: {"runs": t.runs, "overruns": t.overruns, "skipped": t.skipped,
                           "max_lateness_ms": round(t.max_lateness_ns / NS_PER_MS, 3)}
                  for t in sched.stats},
        "sim_time_s": sim_s,
        "wall_time_s": round(wall_s, 4),
        "x_realtime": round(sim_s / wall_s, 2) if wall_s > 0 else None,
        "throttle": throttle,
        "frames": {
            "sent": plant.frames_sent + ecu.frames_sent,
            "plant_sent": plant.frames_sent,
            "ecu_sent": ecu.frames_sent,
            "send_errors": plant.send_errors + ecu.send_errors,
            "received": ecu.rx.received,
            "rejected": ecu.rx.rejected,
            "ecu_rx": ecu.rx.as_dict(),
            "logged": recorder.frames if recorder else None,
            "rejected_fault_commands": injector.rejected_commands,
        },
        "fault_events": [
            {"t_s": e.t_ns / NS_PER_S, "target": e.target.name.lower(), "kind": e.kind.name.lower(),
             "value": e.value, "source": e.source} for e in injector.events
        ],
    }
