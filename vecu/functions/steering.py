"""The steering function (Khalid: steering-wheel angle and side-slip, SWA hot standby) as a
registry entry: its plant part, ECU function, probe and typed summary, replay inputs and
scoring."""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.codec import DbcCodec
from vecu.config import RunConfig
from vecu.ecu.sensor_monitor import SOURCE_ESTIMATE
from vecu.ecu.steering_function import SteeringFunction
from vecu.estimators.registry import ESTIMATORS
from vecu.faults import FaultInjector, FaultTarget
from vecu.functions.base import EcuFunctionSpec, EcuInput, Kill, Sensor, TruthChannel, TruthPair
from vecu.plant.drive import Drive
from vecu.plant.lateral import LateralPart
from vecu.probes import SeriesBuffer, source_name
from vecu.stats import ErrorStats, RunningStats
from vecu.summary import FLATTEN, Detection, KillSplit


@dataclass(frozen=True)
class SteeringSeries:
    """Per-10-ms steering signals (deg) for plots."""

    t_s: np.ndarray
    swa_true: np.ndarray
    swa_sensor: np.ndarray  # NaN where no SWA frame was sent
    swa_broadcast: np.ndarray
    swa_est: np.ndarray
    source: np.ndarray

    def output(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """(t, broadcast, truth, source): what a scenario's SWA criteria read."""
        return self.t_s, self.swa_broadcast, self.swa_true, self.source

    def panel(self) -> tuple[str, list[tuple[np.ndarray, str, str, str]]]:
        """A scenario plot's panel: its y label and (values, label, colour, line style)."""
        return "steering wheel (deg)", [
            (self.swa_true, "true SWA", "black", "-"), (self.swa_sensor, "SWA sensor",
                                                       "tab:blue", "-"),
            (self.swa_est, "UKF estimate", "tab:orange", "-"),
            (self.swa_broadcast, "broadcast", "tab:red", "--")]


@dataclass(frozen=True)
class SteeringSummary:
    """The steering function's section of a run summary."""

    swa_broadcast_error_deg: KillSplit
    swa_ukf_error_deg: ErrorStats
    swa_smoothed_error_deg: ErrorStats
    side_slip_ukf_error_deg: ErrorStats
    side_slip_smoothed_error_deg: ErrorStats
    smoother_lag_ms: float | None
    estimates_sent: int
    ukf_rejected: int
    detection: Detection = field(metadata=FLATTEN)
    fault: str | None
    final_source: str
    missing_broadcasts: int

    def lines(self) -> list[str]:
        """For `vecu run`'s printed summary."""
        det = self.detection
        smoothed = ("fixed-lag smoother: no output yet (the run is shorter than its lag)"
                    if self.smoother_lag_ms is None else
                    f"fixed-lag smoother ({self.smoother_lag_ms:g} ms behind) "
                    f"{self.swa_smoothed_error_deg.rms:.2f} deg"
                    + (f" ({self.swa_ukf_error_deg.rms / self.swa_smoothed_error_deg.rms:.1f}x "
                       "better than the live UKF)" if self.swa_smoothed_error_deg.rms else ""))
        line = (f"steering, RMS error against the truth: steering-wheel angle (SWA) from yaw "
                f"rate and lateral acceleration, live UKF {self.swa_ukf_error_deg.rms:.2f} deg "
                f"(the fallback for the SWA sensor), {smoothed}; side-slip "
                f"{self.side_slip_ukf_error_deg.rms:.3f} deg")
        if det.kill_time_s is not None:
            after = self.swa_broadcast_error_deg.after_kill
            line += (f"; SWA fault '{self.fault}' at {det.kill_time_s:.2f} s "
                     + (f"detected as {det.detected_as} after {det.detection_latency_ms:.0f} ms"
                        if det.detected else "NOT detected")
                     + f", broadcast error after {after.rms:.2f} deg RMS")
        if det.false_alarm:
            line += f"; WARNING: SWA fault reported before any injection ({det.detection_time_s} s)"
        return [line]


class SteeringProbe:
    """Steering-wheel angle and side-slip errors (deg): broadcast, live UKF, and the fixed-lag
    smoother against the truth of the time its estimate describes; split at the SWA kill time."""

    period_ns = SteeringFunction.period_ns

    def __init__(self, part: LateralPart, fn: SteeringFunction, kill_ns: int | None,
                 n_samples: int, keep_series: bool, n_ticks: int = 0,
                 fault: str = "dead") -> None:
        """n_ticks: the run's base ticks; fault: the kind of the SWA kill at kill_ns."""
        self.part, self.fn, self.kill_ns = part, fn, kill_ns
        self.n_ticks, self.fault = n_ticks, fault
        self.bc = {"before_kill": RunningStats(), "after_kill": RunningStats()}
        self.ukf = RunningStats()
        self.smoothed = RunningStats()
        self.beta_ukf = RunningStats()
        self.beta_smoothed = RunningStats()
        self._truth: deque[tuple[float, float]] = deque(maxlen=1000)
        self._k = 0
        self._series = SeriesBuffer(6, n_samples) if keep_series else None

    def tick(self, t_ns: int) -> None:
        part, fn = self.part, self.fn
        swa, beta = part.swa, part.beta
        self._truth.append((swa, beta))
        phase = "after_kill" if self.kill_ns is not None and t_ns >= self.kill_ns else "before_kill"
        self.bc[phase].add(fn.angle - swa)
        ukf = fn.ukf
        self.ukf.add(ukf.swa_rad * 180.0 / math.pi - swa)
        self.beta_ukf.add(ukf.side_slip_rad * 180.0 / math.pi - beta)
        if fn.lagged is not None:
            lag_ms, swa_s, beta_s = fn.lagged
            back = round(lag_ms * 1e6 / fn.period_ns)
            if back < len(self._truth):
                swa_then, beta_then = self._truth[-1 - back]
                self.smoothed.add(swa_s - swa_then)
                self.beta_smoothed.add(beta_s - beta_then)
        s = self._series
        if s is not None:
            v = part.swa_sensor
            s.append((t_ns / NS_PER_S, swa, np.nan if v is None else v, fn.angle,
                      ukf.swa_rad * 180.0 / math.pi, fn.source))
        self._k += 1

    def series(self) -> SteeringSeries | None:
        if self._series is None:
            return None
        s = self._series.view()
        return SteeringSeries(s[0], s[1], s[2], s[3], s[4], s[5].astype(int))

    def summary(self) -> SteeringSummary:
        """The section after the run's n_ticks base ticks."""
        fn, n_ticks, fault = self.fn, self.n_ticks, self.fault
        return SteeringSummary(
            swa_broadcast_error_deg=KillSplit(self.bc["before_kill"].summary(),
                                              self.bc["after_kill"].summary()),
            swa_ukf_error_deg=self.ukf.summary(),
            swa_smoothed_error_deg=self.smoothed.summary(),
            side_slip_ukf_error_deg=self.beta_ukf.summary(),
            side_slip_smoothed_error_deg=self.beta_smoothed.summary(),
            smoother_lag_ms=fn.lagged[0] if fn.lagged else None,
            estimates_sent=fn.estimates_sent, ukf_rejected=fn.ukf.rejected,
            detection=Detection.of(fn.monitor, self.kill_ns),
            fault=fault if self.kill_ns is not None else None,
            final_source=source_name(fn.source),
            missing_broadcasts=n_ticks * NS_PER_MS // fn.period_ns - fn.estimates_sent)


def _part(config: RunConfig, codec: DbcCodec, injector: FaultInjector,
          rngs: Mapping[str, np.random.Generator], drive: Drive) -> LateralPart:
    car = config.params.plant
    return LateralPart(codec, drive, config.seed, injector, car.lateral, car.sensors.lateral)


def _kill(config: RunConfig) -> Kill | None:
    if config.kill_swa_at_s is None:
        return None
    return Kill("kill-swa", round(config.kill_swa_at_s * NS_PER_S), FaultTarget.SWA,
                config.swa_fault, config.swa_fault_value)


def _probe(part: LateralPart, fn: SteeringFunction, config: RunConfig,
           n_ticks: int) -> SteeringProbe:
    kill = _kill(config)
    return SteeringProbe(part, fn, None if kill is None else kill.at_ns, n_ticks // 10 + 1,
                         config.keep_series, n_ticks, config.swa_fault)


def _plot(st: SteeringSeries, ax: Any) -> None:
    # the noisy UKF estimate at the bottom, the truth wide and pale over it, so that the sensor
    # and the broadcast that follow the truth closely stay visible on top (thin, dashed)
    ax.plot(st.t_s, st.swa_est, color="tab:orange", lw=0.7, alpha=0.8, label="UKF estimate",
            zorder=1)
    ax.plot(st.t_s, st.swa_true, color="black", lw=2.4, alpha=0.3, label="true SWA", zorder=2)
    ax.plot(st.t_s, st.swa_sensor, color="tab:blue", lw=0.7, label="SWA sensor", zorder=3)
    ax.plot(st.t_s, st.swa_broadcast, color="tab:red", lw=0.9, ls=(0, (4, 3)),
            label="broadcast", zorder=4)
    on_est = st.source == 1
    if on_est.any():
        ax.fill_between(st.t_s, 0, 1, where=on_est, transform=ax.get_xaxis_transform(),
                        color="tab:red", alpha=0.07, lw=0, label="broadcasting estimate")
    ax.set_ylabel("steering wheel (deg)")
    lo, hi = ax.get_ylim()  # head room for the legend, above the traces rather than over them
    ax.set_ylim(lo, hi + 0.35 * (hi - lo))
    ax.legend(loc="upper right", fontsize=8, ncol=5)


SPEC = EcuFunctionSpec(
    name="steering", enabled=lambda config: config.steering,
    build=lambda config, codec, seam: SteeringFunction(codec, config.params.ecu.steering),
    part_name="lateral", plant_part=_part, probe=_probe, probe_task="steering-probe",
    kill=_kill, sensors={"swa": Sensor("SWA_Sensor", "ecu.steering.monitor", "deg", rank=1)},
    inputs={
        "yaw_rate": EcuInput("CHS_Lateral", "LAT_YawRate", "deg/s"),
        "lat_accel": EcuInput("CHS_Lateral", "LAT_LatAccel", "m/s^2"),
        "vehicle_speed": EcuInput("CHS_Lateral", "LAT_VehSpeed", "km/h"),
        "steering_angle": EcuInput("SWA_Sensor", "SWA_Angle", "deg", required=False),
    },
    truth=TruthChannel("ECU_SteeringEstimate", "TRUTH_Steering", 10 * NS_PER_MS, (
        TruthPair("swa_broadcast_error_deg", "STE_SwAngle", "TRU_SwAngle"),
        TruthPair("swa_estimate_error_deg", "STE_SwAngleEst", "TRU_SwAngle"),
        TruthPair("side_slip_error_deg", "STE_SideSlip", "TRU_SideSlip"),
        TruthPair("swa_fallback_error_deg", "STE_SwAngle", "TRU_SwAngle",
                  ("STE_Source", SOURCE_ESTIMATE)),
    ), validity=("ECU_SteeringEstimate", "STE_Validity"), describe=lambda e: (
        f"SWA broadcast RMS {e['swa_broadcast_error_deg'].rms:.2f} deg, UKF "
        f"{e['swa_estimate_error_deg'].rms:.2f} deg, side-slip "
        f"{e['side_slip_error_deg'].rms:.3f} deg")),
    plot=_plot, report_rank=3, label="steering-wheel angle [deg]",
    profile=(
        ("vecu.plant.lateral", "LateralPart", "tick", "plant: lateral part"),
        ("vecu.ecu.steering_function", "SteeringFunction", "run", "ecu: steering function"),
        ("vecu.estimators.steering.smoothers", "FixedLagSmoother", "step",
         "estimator: steering smoother (w/o UKF)"),
        ("vecu.estimators.steering.filters", "_SteeringFilter", "step", "estimator: steering UKF"),
        ("vecu.functions.steering", "SteeringProbe", "tick", "probes"),
    ),
    estimators=ESTIMATORS["steering"].names)
