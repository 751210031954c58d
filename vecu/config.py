"""Run configuration shared by the simulated run, live processes, replay and scenarios."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from vecu.ecu.speed_function import SpeedFunctionConfig
from vecu.ecu.steering_function import SteeringFunctionConfig
from vecu.ecu.throttle_function import ThrottleFunctionConfig
from vecu.errors import ConfigError
from vecu.fault_kinds import check_value
from vecu.faults import FaultKind, ScheduledFault, parse_kind


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
    truth: bool = True  # with log_path: debug truth frames (dbc/vecu_truth.dbc) in the trace
    keep_series: bool = False
    speed: bool = True  # longitudinal plant part + ECU speed function (Hernandez 2005)
    steering: bool = True  # lateral plant part + ECU steering function (Khalid)
    manifold: bool = True  # engine-event manifold part + ECU manifold function (Dutka 2006)
    manifold_filter: str = "sdkf"  # "sdkf" (live, one Riccati iteration per event) or "ekf"
    kill_swa_at_s: float | None = None
    swa_fault: str = "dead"
    swa_fault_value: float | None = None
    throttle: ThrottleFunctionConfig = field(default_factory=ThrottleFunctionConfig)
    steering_fn: SteeringFunctionConfig = field(default_factory=SteeringFunctionConfig)
    speed_fn: SpeedFunctionConfig = field(default_factory=SpeedFunctionConfig)
    speed_manoeuvres: tuple[str, ...] | None = None  # longitudinal plant sequence (None: default)
    faults: tuple[ScheduledFault, ...] = ()  # fault timeline (scenarios), on top of the kills

    def validate(self) -> None:
        """Raise a UserError (ConfigError, BadArgumentError) on an impossible configuration."""
        if not (self.duration_s > 0 and math.isfinite(self.duration_s)):
            raise ConfigError(f"duration must be a positive number of seconds, got {self.duration_s}")
        if self.kill_tps_at_s is not None and not 0 <= self.kill_tps_at_s < self.duration_s:
            raise ConfigError(f"kill time {self.kill_tps_at_s} s is outside the run (0..{self.duration_s} s)")
        if self.noise_scale < 0:
            raise ConfigError(f"noise scale must be >= 0, got {self.noise_scale}")
        if self.kill_swa_at_s is not None and not 0 <= self.kill_swa_at_s < self.duration_s:
            raise ConfigError(f"SWA kill time {self.kill_swa_at_s} s is outside the run "
                              f"(0..{self.duration_s} s)")
        if self.kill_swa_at_s is not None and not self.steering:
            raise ConfigError("an SWA fault needs the steering part (steering=True)")
        for name in (self.fault, self.swa_fault, *(f.kind for f in self.faults)):
            if parse_kind(name) == FaultKind.CLEAR:
                raise ConfigError("fault kind 'clear' cannot be injected")
        if self.kill_tps_at_s is not None:  # a bad value fails now, not at the kill time
            check_value(parse_kind(self.fault), self.fault_value)
        if self.kill_swa_at_s is not None:
            check_value(parse_kind(self.swa_fault), self.swa_fault_value)
        for f in self.faults:
            if not 0 <= f.start_s < self.duration_s:
                raise ConfigError(f"fault {f.kind} on {f.target}: start {f.start_s} s is outside "
                                  f"the run (0..{self.duration_s} s)")
            if f.end_s is not None and not f.start_s < f.end_s:
                raise ConfigError(f"fault {f.kind} on {f.target}: end {f.end_s} s is not after "
                                  f"its start {f.start_s} s")
