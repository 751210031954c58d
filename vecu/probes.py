"""Probes: read plant truth and ECU output after each tick, in constant memory (plus optional series)."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.ecu.manifold_function import ManifoldFunction
from vecu.ecu.sensor_monitor import SOURCE_ESTIMATE
from vecu.ecu.speed_function import SpeedFunction
from vecu.ecu.steering_function import SteeringFunction
from vecu.ecu.throttle_function import ThrottleFunction
from vecu.plant.node import LateralPart, LongitudinalPart, ManifoldPart, ThrottlePart
from vecu.stats import ErrorStats, RunningStats
from vecu.summary import FLATTEN, Detection, KillSplit
from vecu.units import MPS_PER_KMH

LOW_SPEED_KMH = 5.0  # the paper's split: the wheel-speed sensor is useless below 5 km/h
SPEED_BURN_IN_NS = 500_000_000  # the filter starts at rest: skip its start-up, as vecu.eval.speed does


class SeriesBuffer:
    """A probe's per-tick series rows: appended as tuples, written into the preallocated
    (columns x capacity) float array a chunk at a time (one numpy call per CHUNK rows instead
    of one per tick); rows past the capacity are dropped."""

    CHUNK = 1024

    def __init__(self, columns: int, capacity: int) -> None:
        self._array = np.full((columns, capacity), np.nan)
        self._rows: list[tuple[float, ...]] = []
        self._n = 0
        self._room = capacity

    def append(self, row: tuple[float, ...]) -> None:
        if self._room:
            self._room -= 1
            rows = self._rows
            rows.append(row)
            if len(rows) == self.CHUNK:
                self._flush()

    def _flush(self) -> None:
        rows = self._rows
        if rows:
            self._array[:, self._n:self._n + len(rows)] = np.array(rows, dtype=np.float64).T
            self._n += len(rows)
            rows.clear()

    def view(self) -> np.ndarray:
        """(columns, rows so far)"""
        self._flush()
        return self._array[:, :self._n]


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


@dataclass(frozen=True)
class SpeedSeries:
    """Per-2-ms speed signals (km/h, m/s^2) for plots."""

    t_s: np.ndarray
    v_true: np.ndarray
    v_wheel: np.ndarray
    v_est: np.ndarray
    a_true: np.ndarray
    a_est: np.ndarray


@dataclass(frozen=True)
class SteeringSeries:
    """Per-10-ms steering signals (deg) for plots."""

    t_s: np.ndarray
    swa_true: np.ndarray
    swa_sensor: np.ndarray  # NaN where no SWA frame was sent
    swa_broadcast: np.ndarray
    swa_est: np.ndarray
    source: np.ndarray


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
        parts = [f"no samples after the {self.burn_in_s:g} s burn-in" if hi.gain_db is None
                 else f"speed >= 5 km/h: RMS {hi.estimate_error_kmh.rms:.2f} km/h "
                 f"(raw wheel {hi.raw_wheel_error_kmh.rms:.2f}, {hi.gain_db:+.1f} dB)"]
        if lo.gain_db is not None:
            parts.append(f"< 5 km/h: {lo.gain_db:+.1f} dB")
        if ac.gain_db is not None:
            parts.append(f"accel RMS {ac.estimate_error_mps2.rms:.3f} m/s^2 "
                         f"({ac.gain_db:+.1f} dB vs accelerometer)")
        return ["speed estimate: " + "; ".join(parts)]


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
                    f"fixed-lag smoother ({self.smoother_lag_ms} ms behind) "
                    f"{self.swa_smoothed_error_deg.rms:.2f} deg")
        line = (f"steering: SWA UKF RMS {self.swa_ukf_error_deg.rms:.2f} deg, {smoothed}, "
                f"side-slip {self.side_slip_ukf_error_deg.rms:.3f} deg")
        if det.kill_time_s is not None:
            after = self.swa_broadcast_error_deg.after_kill
            line += (f"; SWA fault '{self.fault}' at {det.kill_time_s:.2f} s "
                     + (f"detected as {det.detected_as} after {det.detection_latency_ms:.0f} ms"
                        if det.detected else "NOT detected")
                     + f", broadcast error after {after.rms:.2f} deg RMS")
        if det.false_alarm:
            line += f"; WARNING: SWA fault reported before any injection ({det.detection_time_s} s)"
        return [line]


@dataclass(frozen=True)
class ManifoldSummary:
    """The manifold function's section of a run summary (Dutka 2006 Table 3 errors)."""

    filter: str
    events: int
    lost_events: int
    implausible_inputs: int  # events refused (e.g. 0 rpm)
    # under numba the usual event's filter, CAC and prediction are one call, timed in the
    # first (ManifoldFunction); their sum is the event's cost under both backends
    filter_us_per_event: float
    cac_prediction_us_per_event: float
    p_im_error_kpa: ErrorStats
    t_im_error_k: ErrorStats
    cac_error_mg: ErrorStats
    cac_pred6_error_mg: ErrorStats
    cac_pred6_abs_error_pct: ErrorStats
    p_im_estimate_range_kpa: list[float] | None
    filter_resets: int
    estimator_faults: int

    def lines(self) -> list[str]:
        """For `vecu run`'s printed summary."""
        return [(f"manifold ({self.filter}, {self.events} engine events, {self.lost_events} lost): "
                 f"P_im RMS {self.p_im_error_kpa.rms:.3f} kPa, T_im {self.t_im_error_k.rms:.2f} K, "
                 f"CAC {self.cac_error_mg.rms:.2f} mg, 6-event CAC prediction "
                 f"{self.cac_pred6_abs_error_pct.mean:.2f} % mean |error|; "
                 f"{self.filter_us_per_event + self.cac_prediction_us_per_event:.0f} us/event "
                 "(filter, CAC and prediction)")]


def _source_name(source: int) -> str:
    return "estimate" if source == SOURCE_ESTIMATE else "sensor"


class ThrottleProbe:
    """Broadcast and estimator error against the true angle, split at the TPS kill time."""

    def __init__(self, part: ThrottlePart, fn: ThrottleFunction, kill_ns: int | None,
                 n_ticks: int, keep_series: bool) -> None:
        self.part, self.fn, self.kill_ns = part, fn, kill_ns
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

    def summary(self, n_ticks: int, fault: str) -> ThrottleSummary:
        """The section after n_ticks ticks; fault: the TPS fault kind (when killed)."""
        fn = self.fn
        phases = {phase: PhaseErrors(self.bc[phase].summary(), self.est[phase].summary())
                  for phase in ("before_kill", "after_kill")}
        return ThrottleSummary(
            estimator=fn.estimator.name, estimator_resets=fn.estimator.resets,
            estimator_faults=fn.estimator_faults,
            detection=Detection.of(fn.monitor, self.kill_ns),
            fault=fault if self.kill_ns is not None else None,
            final_status=fn.status.name.lower(), final_source=_source_name(fn.source),
            nan_outputs=self.nan_outputs, missing_broadcasts=n_ticks - fn.estimates_sent,
            before_kill=phases["before_kill"], after_kill=phases["after_kill"])


def _gain_db(raw: RunningStats, est: RunningStats) -> float | None:
    if raw.n == 0 or est.n == 0 or est.rms == 0.0:
        return None
    return round(20.0 * math.log10(raw.rms / est.rms), 2)


class SpeedProbe:
    """Estimated vs true speed and acceleration, and the raw sensors' errors (the paper's dB)."""

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


class SteeringProbe:
    """Steering-wheel angle and side-slip errors (deg): broadcast, live UKF, and the fixed-lag
    smoother against the truth of the time its estimate describes; split at the SWA kill time."""

    def __init__(self, part: LateralPart, fn: SteeringFunction, kill_ns: int | None,
                 n_samples: int, keep_series: bool) -> None:
        self.part, self.fn, self.kill_ns = part, fn, kill_ns
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

    def summary(self, n_ticks: int, fault: str) -> SteeringSummary:
        """The section after n_ticks base ticks; fault: the SWA fault kind (when killed)."""
        fn = self.fn
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
            final_source=_source_name(fn.source),
            missing_broadcasts=n_ticks * NS_PER_MS // fn.period_ns - fn.estimates_sent)


class ManifoldProbe:
    """Per engine event: posterior P_im / T_im and CAC against the plant's truth at that event,
    and each 6-event CAC prediction against the truth when that event comes."""

    def __init__(self, part: ManifoldPart, fn: ManifoldFunction, keep_series: bool,
                 horizon: int = 6) -> None:
        self.part, self.fn, self.horizon = part, fn, horizon
        self._series: list[tuple[float, float, float]] | None = [] if keep_series else None
        self.p_err = RunningStats()
        self.t_err = RunningStats()
        self.cac_err = RunningStats()
        self.pred_err = RunningStats()
        self.pred_rel = RunningStats()
        self.p_min, self.p_max = math.inf, -math.inf
        self._pending: dict[int, float] = {}
        self._seen = -1

    def tick(self, t_ns: int) -> None:
        last = self.fn.last
        if last is None or last[0] == self._seen:
            return
        idx, p, t, cac, cac6 = last
        self._seen = idx
        truth = self.part.truth.get(idx)
        if truth is not None:
            p_true, t_true, cac_true = truth
            self.p_err.add(p - p_true)
            self.t_err.add(t - t_true)
            self.cac_err.add((cac - cac_true) * 1e6)
            self.p_min, self.p_max = min(self.p_min, p), max(self.p_max, p)
            if self._series is not None:
                self._series.append((t_ns / NS_PER_S, p_true, p))
            pred = self._pending.pop(idx, None)
            if pred is not None:
                self.pred_err.add((pred - cac_true) * 1e6)
                self.pred_rel.add(100.0 * abs(pred - cac_true) / cac_true)
        self._pending[idx + self.horizon] = cac6
        for old in [k for k in self._pending if k < idx]:
            del self._pending[old]

    def series(self) -> np.ndarray | None:
        """Rows (t_s, true P_im, estimated P_im), one per engine event."""
        return None if self._series is None else np.array(self._series).reshape(-1, 3)

    def summary(self) -> ManifoldSummary:
        fn = self.fn
        return ManifoldSummary(
            filter=fn.filter_name, events=fn.events, lost_events=fn.lost_events,
            implausible_inputs=fn.implausible_inputs,
            filter_us_per_event=round(fn.filter_seconds / max(fn.events, 1) * 1e6, 1),
            cac_prediction_us_per_event=round(fn.predict_seconds / max(fn.events, 1) * 1e6, 1),
            p_im_error_kpa=self.p_err.summary(), t_im_error_k=self.t_err.summary(),
            cac_error_mg=self.cac_err.summary(), cac_pred6_error_mg=self.pred_err.summary(),
            cac_pred6_abs_error_pct=self.pred_rel.summary(),
            p_im_estimate_range_kpa=([round(self.p_min, 2), round(self.p_max, 2)]
                                     if self.p_err.n else None),
            filter_resets=fn.filter.resets, estimator_faults=fn.estimator_faults)
