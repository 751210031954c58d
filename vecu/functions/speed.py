"""The speed function (Hernandez 2005: vehicle speed and acceleration at 500 Hz) as a registry
entry: its plant part, ECU function, probe and typed summary (the paper's dB gains), replay
inputs and scoring."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.codec import DbcCodec
from vecu.config import RunConfig
from vecu.ecu.speed_function import SpeedFunction
from vecu.estimators.registry import ESTIMATORS
from vecu.faults import FaultInjector
from vecu.functions.base import EcuFunctionSpec, EcuInput, Sensor, TruthChannel, TruthPair
from vecu.plant.drive import Drive, LongitudinalPart
from vecu.probes import SeriesBuffer
from vecu.stats import ErrorStats, RunningStats
from vecu.units import MPS_PER_KMH

LOW_SPEED_KMH = 5.0  # the paper's split: the wheel-speed sensor is useless below 5 km/h
SPEED_BURN_IN_NS = 500_000_000  # the filter starts at rest: skip its start-up, as vecu.eval.speed does


@dataclass(frozen=True)
class SpeedSeries:
    """Per-2-ms speed signals (km/h, m/s^2) for plots."""

    t_s: np.ndarray
    v_true: np.ndarray
    v_wheel: np.ndarray
    v_est: np.ndarray
    a_true: np.ndarray
    a_est: np.ndarray

    def output(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """(t, estimate, truth, None): what a scenario's wheel criteria read (no source:
        coasting on the accelerometer is the fallback)."""
        return self.t_s, self.v_est, self.v_true, None

    def panel(self) -> tuple[str, list[tuple[np.ndarray, str, str, str]]]:
        """A scenario plot's panel: its y label and (values, label, colour, line style)."""
        return "speed (km/h)", [
            (self.v_true, "true speed", "black", "-"),
            (self.v_wheel, "wheel sensor (plant)", "tab:blue", "-"),
            (self.v_est, "estimate", "tab:red", "--")]


@dataclass(frozen=True)
class SpeedBand:
    estimate_error_kmh: ErrorStats
    raw_wheel_error_kmh: ErrorStats
    gain_db: float | None


@dataclass(frozen=True)
class AccelErrors:
    estimate_error_mps2: ErrorStats
    raw_accelerometer_error_mps2: ErrorStats
    gain_db: float | None


@dataclass(frozen=True)
class SpeedFilterCounts:
    resets: int
    rejected_wheel: int
    rejected_accel: int


@dataclass(frozen=True)
class SpeedSummary:
    """The speed function's section of a run summary (the paper's dB gains)."""

    burn_in_s: float
    speed_ge_5kmh: SpeedBand
    speed_lt_5kmh: SpeedBand
    accel: AccelErrors
    filter: SpeedFilterCounts
    estimates_sent: int
    coast_steps: int

    def lines(self) -> list[str]:
        """For `vecu run`'s printed summary."""
        hi, lo, ac = self.speed_ge_5kmh, self.speed_lt_5kmh, self.accel

        def verdict(db: float) -> str:  # against the raw sensor, the paper's reference
            return f"{db:+.1f} dB: {'better' if db > 0 else 'NOT better'} than the raw sensor"
        parts = [f"no samples after the {self.burn_in_s:g} s burn-in" if hi.gain_db is None
                 else f">= 5 km/h {hi.estimate_error_kmh.rms:.2f} km/h against the raw wheel "
                 f"sensor's {hi.raw_wheel_error_kmh.rms:.2f} ({verdict(hi.gain_db)})"]
        if lo.gain_db is not None:
            parts.append(f"< 5 km/h {lo.estimate_error_kmh.rms:.2f} km/h against "
                         f"{lo.raw_wheel_error_kmh.rms:.2f} ({verdict(lo.gain_db)})")
        if ac.gain_db is not None:
            parts.append(f"acceleration {ac.estimate_error_mps2.rms:.3f} m/s^2 against the "
                         f"accelerometer's {ac.raw_accelerometer_error_mps2.rms:.3f} "
                         f"({verdict(ac.gain_db)})")
        return ["speed filter (500 Hz), RMS error against the true value: " + "; ".join(parts)]


def _gain_db(raw: RunningStats, est: RunningStats) -> float | None:
    if raw.n == 0 or est.n == 0 or est.rms == 0.0:
        return None
    return round(20.0 * math.log10(raw.rms / est.rms), 2)


class SpeedProbe:
    """Estimated vs true speed and acceleration, and the raw sensors' errors (the paper's dB)."""

    period_ns = SpeedFunction.period_ns

    def __init__(self, part: LongitudinalPart, fn: SpeedFunction, n_samples: int,
                 keep_series: bool) -> None:
        self.part, self.fn = part, fn
        self.v_est = {"high": RunningStats(), "low": RunningStats()}
        self.v_raw = {"high": RunningStats(), "low": RunningStats()}
        self.a_est = RunningStats()
        self.a_raw = RunningStats()
        self._last_accel_raw = 0.0
        self._k = 0
        self._series = SeriesBuffer(6, n_samples) if keep_series else None

    def tick(self, t_ns: int) -> None:
        part, kf = self.part, self.fn.kf
        v, a = part.v, part.a
        s = self._series
        if s is not None:
            s.append((t_ns / NS_PER_S, v / MPS_PER_KMH, part.wheel / MPS_PER_KMH,
                      kf.speed_mps / MPS_PER_KMH, a, kf.accel_mps2))
        self._k += 1
        if t_ns < SPEED_BURN_IN_NS:
            return
        band = "high" if v / MPS_PER_KMH >= LOW_SPEED_KMH else "low"
        self.v_est[band].add((kf.speed_mps - v) / MPS_PER_KMH)
        self.v_raw[band].add((part.wheel - v) / MPS_PER_KMH)
        self.a_est.add(kf.accel_mps2 - a)
        self.a_raw.add(part.accel - a)

    def series(self) -> SpeedSeries | None:
        return None if self._series is None else SpeedSeries(*self._series.view())

    def summary(self) -> SpeedSummary:
        bands = {band: SpeedBand(self.v_est[band].summary(), self.v_raw[band].summary(),
                                 _gain_db(self.v_raw[band], self.v_est[band]))
                 for band in ("high", "low")}
        kf = self.fn.kf
        return SpeedSummary(
            burn_in_s=SPEED_BURN_IN_NS / NS_PER_S, speed_ge_5kmh=bands["high"],
            speed_lt_5kmh=bands["low"],
            accel=AccelErrors(self.a_est.summary(), self.a_raw.summary(),
                              _gain_db(self.a_raw, self.a_est)),
            filter=SpeedFilterCounts(kf.resets, kf.rejected_wheel, kf.rejected_accel),
            estimates_sent=self.fn.estimates_sent, coast_steps=self.fn.coast_steps)


def _part(config: RunConfig, codec: DbcCodec, injector: FaultInjector,
          rngs: Mapping[str, np.random.Generator], drive: Drive) -> LongitudinalPart:
    return LongitudinalPart(codec, config.seed, drive=drive)


def _plot(sp: SpeedSeries, ax: Any) -> None:
    ax.plot(sp.t_s, sp.v_wheel, color="tab:gray", lw=0.5, alpha=0.6, label="wheel-speed sensor")
    ax.plot(sp.t_s, sp.v_true, color="black", lw=1.0, label="true speed")
    ax.plot(sp.t_s, sp.v_est, color="tab:green", lw=0.9, ls="--", label="estimate (500 Hz KF)")
    ax.set_ylabel("speed (km/h)")
    ax.legend(loc="upper right", fontsize=8, ncol=3)


SPEC = EcuFunctionSpec(
    name="speed", enabled=lambda config: config.speed,
    build=lambda config, codec, seam: SpeedFunction(
        codec, ESTIMATORS["speed"].make("kf", config.params.ecu.speed.filter),
        config.params.ecu.speed),
    part_name="longitudinal", plant_part=_part,
    probe=lambda part, fn, config, n_ticks: SpeedProbe(part, fn, n_ticks // 2 + 1,
                                                       config.keep_series),
    probe_task="speed-probe",
    sensors={"wheel": Sensor("ESC_Motion", "ecu.speed.wheel_monitor", "km/h", rank=2)},
    inputs={
        "wheel_speed": EcuInput("ESC_Motion", "ESC_WheelSpeed", "km/h"),
        "long_accel": EcuInput("ESC_Motion", "ESC_LongAccel", "m/s^2"),
    },
    truth=TruthChannel("ECU_SpeedEstimate", "TRUTH_Speed", 2 * NS_PER_MS, (
        TruthPair("speed_error_kmh", "SPD_VehSpeed", "TRU_VehSpeed"),
        TruthPair("accel_error_mps2", "SPD_VehAccel", "TRU_VehAccel"),
    ), burn_in_ns=SPEED_BURN_IN_NS, validity=("ECU_SpeedEstimate", "SPD_Validity"),
        describe=lambda e: (
        f"RMS {e['speed_error_kmh'].rms:.3f} km/h, accel {e['accel_error_mps2'].rms:.3f} m/s^2")),
    plot=_plot, report_rank=1, label="vehicle speed [km/h]",
    profile=(
        ("vecu.plant.drive", "LongitudinalPart", "tick", "plant: longitudinal part"),
        ("vecu.ecu.speed_function", "SpeedFunction", "run", "ecu: speed function"),
        ("vecu.estimators.speed.kf", "SpeedKalmanFilter", "step", "estimator: speed KF"),
        ("vecu.functions.speed", "SpeedProbe", "tick", "probes"),
    ),
    estimators=ESTIMATORS["speed"].names)
