"""The throttle function (Pavković 2006: the ETB angle from the wattmeter, hot standby for the
TPS) as a registry entry: its plant part, ECU function, probe and typed summary, replay inputs
and scoring."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.codec import DbcCodec
from vecu.config import RunConfig
from vecu.ecu.sensor_monitor import SOURCE_ESTIMATE
from vecu.ecu.throttle_function import ThrottleFunction
from vecu.estimators.registry import ESTIMATORS, make_throttle_estimator
from vecu.faults import FaultInjector, FaultTarget
from vecu.functions.base import EcuFunctionSpec, EcuInput, Kill, Sensor, TruthChannel, TruthPair
from vecu.plant.drive import Drive
from vecu.plant.input_file import FileInput, load_input_file
from vecu.plant.throttle import InputGenerator, ThrottlePart, ThrottlePlant
from vecu.probes import SeriesBuffer, source_name
from vecu.stats import ErrorStats, RunningStats
from vecu.summary import FLATTEN, Detection


@dataclass(frozen=True)
class ThrottleSeries:
    """Per-tick throttle signals (deg) for plots."""

    t_s: np.ndarray
    theta_true: np.ndarray
    theta_sensor: np.ndarray  # NaN where no TPS frame was sent
    theta_broadcast: np.ndarray
    theta_est: np.ndarray
    theta_est_std: np.ndarray
    source: np.ndarray
    status: np.ndarray

    def output(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """(t, broadcast, truth, source): what a scenario's TPS criteria read."""
        return self.t_s, self.theta_broadcast, self.theta_true, self.source

    def panel(self) -> tuple[str, list[tuple[np.ndarray, str, str, str]]]:
        """A scenario plot's panel: its y label and (values, label, colour, line style)."""
        return "throttle (deg)", [
            (self.theta_true, "true θ", "black", "-"), (self.theta_sensor, "TPS sensor",
                                                       "tab:blue", "-"),
            (self.theta_est, "estimate", "tab:orange", "-"),
            (self.theta_broadcast, "broadcast", "tab:red", "--")]


@dataclass(frozen=True)
class PhaseErrors:
    """Throttle errors (deg) in one phase of the run (before / after the TPS kill)."""

    broadcast_error_deg: ErrorStats
    estimate_error_deg: ErrorStats


@dataclass(frozen=True)
class ThrottleSummary:
    """The throttle function's section of a run summary."""

    estimator: str
    estimator_resets: int
    estimator_faults: int
    detection: Detection = field(metadata=FLATTEN)
    fault: str | None
    final_status: str
    final_source: str
    nan_outputs: int
    missing_broadcasts: int  # ticks without an estimate frame (skipped releases, send errors)
    before_kill: PhaseErrors
    after_kill: PhaseErrors


class ThrottleProbe:
    """Broadcast and estimator error against the true angle, split at the TPS kill time."""

    period_ns = NS_PER_MS

    def __init__(self, part: ThrottlePart, fn: ThrottleFunction, kill_ns: int | None,
                 n_ticks: int, keep_series: bool, fault: str = "dead") -> None:
        """fault: the kind of the TPS kill at kill_ns (for the summary)."""
        self.part, self.fn, self.kill_ns = part, fn, kill_ns
        self.n_ticks, self.fault = n_ticks, fault
        self.bc = {"before_kill": RunningStats(), "after_kill": RunningStats()}
        self.est = {"before_kill": RunningStats(), "after_kill": RunningStats()}
        self.nan_outputs = 0
        self._k = 0
        self._series = SeriesBuffer(8, n_ticks) if keep_series else None

    def tick(self, t_ns: int) -> None:
        fn = self.fn
        truth = self.part.theta
        angle = fn.angle
        est = fn.estimator
        if not math.isfinite(angle):
            self.nan_outputs += 1
        phase = "after_kill" if self.kill_ns is not None and t_ns >= self.kill_ns else "before_kill"
        self.bc[phase].add(angle - truth)
        self.est[phase].add(est.theta_deg - truth)
        s = self._series
        if s is not None:
            v = self.part.tps_voltage
            s.append((t_ns / NS_PER_S, truth,
                      self.part.calibration.angle(v) if v is not None else np.nan, angle,
                      est.theta_deg, est.theta_std_deg, fn.source, int(fn.status)))
        self._k += 1

    def series(self) -> ThrottleSeries | None:
        if self._series is None:
            return None
        s = self._series.view()
        return ThrottleSeries(s[0], s[1], s[2], s[3], s[4], s[5], s[6].astype(int),
                              s[7].astype(int))

    def summary(self) -> ThrottleSummary:
        """The section after the run's n_ticks ticks."""
        fn, n_ticks, fault = self.fn, self.n_ticks, self.fault
        phases = {phase: PhaseErrors(self.bc[phase].summary(), self.est[phase].summary())
                  for phase in ("before_kill", "after_kill")}
        return ThrottleSummary(
            estimator=fn.estimator.name, estimator_resets=fn.estimator.resets,
            estimator_faults=fn.estimator_faults,
            detection=Detection.of(fn.monitor, self.kill_ns),
            fault=fault if self.kill_ns is not None else None,
            final_status=fn.status.name.lower(), final_source=source_name(fn.source),
            nan_outputs=self.nan_outputs, missing_broadcasts=n_ticks - fn.estimates_sent,
            before_kill=phases["before_kill"], after_kill=phases["after_kill"])


def _build(config: RunConfig, codec: DbcCodec, make_estimator: object) -> ThrottleFunction:
    """From ecu.throttle; make_estimator(name, noise_scale=..., model=...): a bench's seam."""
    cal = config.params.ecu.throttle
    make = make_estimator if callable(make_estimator) else make_throttle_estimator
    estimator = make(cal.estimator, noise_scale=cal.noise_scale, model=cal.model)
    return ThrottleFunction(codec, estimator, cal)


def _part(config: RunConfig, codec: DbcCodec, injector: FaultInjector,
          rngs: Mapping[str, np.random.Generator], drive: Drive) -> ThrottlePart:
    car = config.params.plant
    inputs: InputGenerator | FileInput = (  # the §III-B excitation, or a user's u(t) file
        InputGenerator(car.input, rngs["throttle.input"]) if config.throttle_input is None
        else FileInput(load_input_file(config.throttle_input)))
    return ThrottlePart(codec, ThrottlePlant(car.throttle, rngs["throttle.plant"]), inputs,
                        injector, car.sensors.tps)


def _kill(config: RunConfig) -> Kill | None:
    if config.kill_tps_at_s is None:
        return None
    return Kill("kill-tps", round(config.kill_tps_at_s * NS_PER_S), FaultTarget.TPS,
                config.fault, config.fault_value)


def _probe(part: ThrottlePart, fn: ThrottleFunction, config: RunConfig,
           n_ticks: int) -> ThrottleProbe:
    kill = _kill(config)
    return ThrottleProbe(part, fn, None if kill is None else kill.at_ns, n_ticks,
                         config.keep_series, config.fault)


SPEC = EcuFunctionSpec(
    name="throttle", enabled=lambda config: True, build=_build,
    part_name="throttle", plant_part=_part, probe=_probe, probe_task="probe", kill=_kill,
    sensors={"tps": Sensor("TPS_Sensor", "ecu.throttle.tps_monitor", "deg", rank=0)},
    inputs={
        "motor_voltage": EcuInput("ETB_Wattmeter", "ETB_Voltage", "V"),
        "motor_power": EcuInput("ETB_Wattmeter", "ETB_Power", "W"),
        "tps_voltage": EcuInput("TPS_Sensor", "TPS_Voltage", "V", required=False),
    },
    truth=TruthChannel("ECU_ThrottleEstimate", "TRUTH_Throttle", NS_PER_MS, (
        TruthPair("broadcast_error_deg", "THR_Angle", "TRU_ThrottleAngle"),
        TruthPair("estimate_error_deg", "THR_AngleEst", "TRU_ThrottleAngle"),
        TruthPair("fallback_error_deg", "THR_Angle", "TRU_ThrottleAngle",
                  ("THR_Source", SOURCE_ESTIMATE)),
    ), validity=("ECU_ThrottleEstimate", "THR_Validity"), describe=lambda e: (
        f"broadcast RMS {e['broadcast_error_deg'].rms:.2f} deg, estimator "
        f"{e['estimate_error_deg'].rms:.2f} deg, after fallback "
        f"{e['fallback_error_deg'].rms:.2f} deg ({e['fallback_error_deg'].n} ticks)")),
    report_rank=0, label="throttle angle [deg]",
    profile=(
        ("vecu.plant.throttle", "ThrottlePart", "tick", "plant: throttle part"),
        ("vecu.plant.throttle", "ThrottlePlant", "ticks", "plant: throttle model ticks"),
        ("vecu.plant.throttle", "InputGenerator", "take", "plant: throttle input generator"),
        ("vecu.ecu.throttle_function", "ThrottleFunction", "run", "ecu: throttle function"),
        ("vecu.estimators.throttle.pf.filter", "ThrottleParticleFilter", "step",
         "estimator: throttle production PF/KF"),
        ("vecu.functions.throttle", "ThrottleProbe", "tick", "probes"),
    ),
    estimators=ESTIMATORS["throttle"].names)
