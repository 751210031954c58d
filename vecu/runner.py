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
from vecu.ecu.manifold_function import ManifoldFunction
from vecu.ecu.node import EcuFunction, EcuNode
from vecu.ecu.sensor_monitor import SOURCE_ESTIMATE, SensorMonitor
from vecu.ecu.speed_function import SpeedFunction
from vecu.ecu.steering_function import SteeringFunction
from vecu.ecu.throttle_function import ThrottleFunction, ThrottleFunctionConfig
from vecu.estimators.registry import make_throttle_estimator
from vecu.faults import FaultInjector, FaultKind, FaultTarget, parse_kind
from vecu.plant.node import (LateralPart, LongitudinalPart, ManifoldPart, PlantNode, PlantPart,
                             ThrottlePart)
from vecu.plant.throttle import (InputConfig, InputGenerator, ThrottlePlant, ThrottlePlantConfig,
                                 rng_streams)
from vecu.probes import (ManifoldProbe, SpeedProbe, SpeedSeries, SteeringProbe, SteeringSeries, ThrottleProbe,
                         ThrottleSeries)
from vecu.recorder import Recorder
from vecu.scheduler import Scheduler

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
    speed: bool = True  # longitudinal plant part + ECU speed function (Hernandez 2005)
    steering: bool = True  # lateral plant part + ECU steering function (Khalid)
    manifold: bool = True  # engine-event manifold part + ECU manifold function (Dutka 2006)
    manifold_filter: str = "sdkf"  # "sdkf" (live, one Riccati iteration per event) or "ekf"
    kill_swa_at_s: float | None = None
    swa_fault: str = "dead"
    swa_fault_value: float | None = None
    throttle: ThrottleFunctionConfig = field(default_factory=ThrottleFunctionConfig)

    def validate(self) -> None:
        if not (self.duration_s > 0 and math.isfinite(self.duration_s)):
            raise ValueError(f"duration must be a positive number of seconds, got {self.duration_s}")
        if self.kill_tps_at_s is not None and not 0 <= self.kill_tps_at_s < self.duration_s:
            raise ValueError(f"kill time {self.kill_tps_at_s} s is outside the run (0..{self.duration_s} s)")
        if self.noise_scale < 0:
            raise ValueError(f"noise scale must be >= 0, got {self.noise_scale}")
        if self.kill_swa_at_s is not None and not 0 <= self.kill_swa_at_s < self.duration_s:
            raise ValueError(f"SWA kill time {self.kill_swa_at_s} s is outside the run "
                             f"(0..{self.duration_s} s)")
        if self.kill_swa_at_s is not None and not self.steering:
            raise ValueError("an SWA fault needs the steering part (steering=True)")
        for name in (self.fault, self.swa_fault):
            if parse_kind(name) == FaultKind.CLEAR:
                raise ValueError("fault kind 'clear' cannot be injected")


@dataclass(frozen=True)
class RunResult:
    summary: dict[str, Any]
    throttle_series: ThrottleSeries | None
    speed_series: SpeedSeries | None = None
    steering_series: SteeringSeries | None = None
    manifold_series: np.ndarray | None = None  # rows (t_s, true P_im, estimated P_im) per event


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
        throttle_part = ThrottlePart(
            codec,
            ThrottlePlant(ThrottlePlantConfig(noise_scale=config.noise_scale), rngs["throttle.plant"]),
            InputGenerator(InputConfig(), rngs["throttle.input"]), injector,
            config.throttle.calibration)
        parts: list[PlantPart] = [throttle_part]
        estimator = make_throttle_estimator(config.estimator, noise_scale=config.noise_scale)
        throttle_fn = ThrottleFunction(codec, estimator, config.throttle)
        functions: list[EcuFunction] = [throttle_fn]
        speed_probe = None
        if config.speed:
            speed_part = LongitudinalPart(codec, config.seed)
            speed_fn = SpeedFunction(codec)
            parts.append(speed_part)
            functions.append(speed_fn)
            speed_probe = SpeedProbe(speed_part, speed_fn, n_ticks // 2 + 1, config.keep_series)
        steering_probe = None
        swa_kill_ns = (None if config.kill_swa_at_s is None
                       else int(round(config.kill_swa_at_s * NS_PER_S)))
        if config.steering:
            lateral_part = LateralPart(codec, config.seed, config.duration_s, injector)
            steering_fn = SteeringFunction(codec)
            parts.append(lateral_part)
            functions.append(steering_fn)
            steering_probe = SteeringProbe(lateral_part, steering_fn, swa_kill_ns,
                                           n_ticks // 10 + 1, config.keep_series)
        manifold_probe = None
        manifold_part = None
        if config.manifold:
            manifold_part = ManifoldPart(codec, config.seed)
            manifold_fn = ManifoldFunction(codec, config.manifold_filter)
            functions.append(manifold_fn)
            manifold_probe = ManifoldProbe(manifold_part, manifold_fn, config.keep_series)
        plant = PlantNode(plant_bus, codec, injector, parts)
        plant.manifold = manifold_part
        ecu = EcuNode(ecu_bus, codec, functions)
        probe = ThrottleProbe(throttle_part, throttle_fn, kill_ns, n_ticks, config.keep_series)
        sched.every(TICK_NS, plant.tick, name="plant", priority=PRIO_PLANT)
        ecu_task = sched.every(TICK_NS, ecu.tick, name="ecu", priority=PRIO_ECU)
        sched.every(TICK_NS, probe.tick, name="probe", priority=PRIO_PROBE)
        if speed_probe is not None:
            sched.every(SpeedFunction.period_ns, speed_probe.tick, name="speed-probe",
                        priority=PRIO_PROBE)
        if steering_probe is not None:
            sched.every(SteeringFunction.period_ns, steering_probe.tick, name="steering-probe",
                        priority=PRIO_PROBE)
        if manifold_probe is not None:
            sched.chain(0, plant.engine_event, name="engine-events", priority=PRIO_PLANT)
            sched.every(TICK_NS, manifold_probe.tick, name="manifold-probe", priority=PRIO_PROBE)
        if recorder is not None:
            sched.every(TICK_NS, recorder.drain, name="recorder", priority=PRIO_RECORD)
        if kill_ns is not None:
            kind = parse_kind(config.fault)
            sched.at(kill_ns, lambda t: injector.inject(t, FaultTarget.TPS, kind, config.fault_value,
                                                        source="schedule"),
                     name="kill-tps", priority=PRIO_PLANT - 1)
        if swa_kill_ns is not None:
            swa_kind = parse_kind(config.swa_fault)
            sched.at(swa_kill_ns, lambda t: injector.inject(t, FaultTarget.SWA, swa_kind,
                                                            config.swa_fault_value,
                                                            source="schedule"),
                     name="kill-swa", priority=PRIO_PLANT - 1)
        if config.realtime:
            _warm_up(config)
        wall0 = time.perf_counter()
        clock.start()  # set-up time must not count against the first deadlines
        sched.run_until(end_ns)
        wall = time.perf_counter() - wall0
        ecu.overruns = ecu_task.overruns
        if recorder is not None:
            recorder.drain(end_ns)
        summary = _summary(config, sched, plant, ecu, throttle_fn, probe, injector, kill_ns,
                           n_ticks, wall, recorder)
        if speed_probe is not None:
            summary["speed"] = speed_probe.summary()
        if manifold_probe is not None:
            summary["manifold"] = manifold_probe.summary()
        if steering_probe is not None:
            summary["steering"] = {**steering_probe.summary(),
                                   **detection(steering_fn.monitor, swa_kill_ns),
                                   "fault": config.swa_fault if swa_kill_ns is not None else None,
                                   "final_source": ("estimate"
                                                    if steering_fn.source == SOURCE_ESTIMATE
                                                    else "sensor"),
                                   "missing_broadcasts": n_ticks // 10 - steering_fn.estimates_sent}
    finally:
        if recorder is not None:
            recorder.close()
        for bus in buses:
            bus.shutdown()
    return RunResult(summary=summary, throttle_series=probe.series(),
                     speed_series=speed_probe.series() if speed_probe else None,
                     steering_series=steering_probe.series() if steering_probe else None,
                     manifold_series=manifold_probe.series() if manifold_probe else None)


def _warm_up(config: RunConfig) -> None:
    """Before a wall-clock run: exercise a throwaway estimator (first numpy calls cost ~7 ms)
    and move set-up objects out of the garbage collector's way, so the first ticks keep time."""
    spare = make_throttle_estimator(config.estimator, noise_scale=config.noise_scale)
    for k in range(200):
        spare.step(2.0, 4.0 + (k % 7))
    gc.collect()
    gc.freeze()


def detection(mon: SensorMonitor, kill_ns: int | None) -> dict[str, Any]:
    """Kill time, first confirmed fault, latency, and whether it came before any kill."""
    detect_ns = mon.first_fault_ns
    detected = detect_ns is not None and kill_ns is not None and detect_ns >= kill_ns
    return {
        "kill_time_s": None if kill_ns is None else kill_ns / NS_PER_S,
        "detected": detected,
        "detection_time_s": detect_ns / NS_PER_S if detect_ns is not None else None,
        "detection_latency_ms": (detect_ns - kill_ns) / NS_PER_MS if detected else None,
        "detected_as": mon.first_fault_status.name.lower() if mon.first_fault_status else None,
        "false_alarm": detect_ns is not None and (kill_ns is None or detect_ns < kill_ns),
        "dtc": mon.dtc.name.lower(),
    }


def _summary(config: RunConfig, sched: Scheduler, plant: PlantNode, ecu: EcuNode,
             fn: ThrottleFunction, probe: ThrottleProbe, injector: FaultInjector,
             kill_ns: int | None, n_ticks: int, wall_s: float,
             recorder: Recorder | None) -> dict[str, Any]:
    mon = fn.monitor
    throttle: dict[str, Any] = {
        "estimator": fn.estimator.name,
        "estimator_resets": fn.estimator.resets,
        "estimator_faults": fn.estimator_faults,
        **detection(mon, kill_ns),
        "fault": config.fault if kill_ns is not None else None,
        "final_status": fn.status.name.lower(),
        "final_source": "estimate" if fn.source == SOURCE_ESTIMATE else "sensor",
        "nan_outputs": probe.nan_outputs,
        # ticks without an estimate frame on the bus (skipped releases in live runs, send errors)
        "missing_broadcasts": n_ticks - fn.estimates_sent,
    }
    throttle.update(probe.summary())
    sim_s = n_ticks / 1000.0
    return {
        "config": {k: v for k, v in asdict(config).items() if k != "throttle"},
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
