"""Scenario criteria on a replayed trace (`--criteria FILE.toml`): the `[criteria]` keys of a
scenario file (vecu.scenario.loader.parse_criteria) that a trace can answer, judged from what the
replayed ECU sent (its sensors' status and DTC signals), the fault events the trace recorded
(FI_Event frames) and the replay's summary; plus `[truth]` limits on the errors against the
trace's truth frames (vecu.replay.scoring). Results are vecu.scenario.criteria.CriterionResult.

- no_nan: no decoded value of the ECU's frames is NaN or infinite;
- no_overruns: the replay's ECU overran no tick;
- no_false_dtc: no DTC confirmed before the first fault event on its sensor's message;
- per sensor: not_detected, detect_within_ms and detected_as (from fault_at_s, else the first
  FI_Event starting a fault on the sensor's message; latency to the first status other than ok),
  dtc (the final DTC state); fallback and error-after-fallback limits need the run's series
  and are refused (one error line);
- bus.dtc: the final bus DTC state;
- `[truth]`: "function.error" = { rms = X, max = Y } against the replay's score.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import can

from vecu.can_message import Values
from vecu.codec import DbcCodec, FrameCodec
from vecu.ecu.sensor_monitor import DtcState, SensorStatus
from vecu.errors import BadFileError
from vecu.replay.source import TraceSource
from vecu.replay.summary import ReplaySummary
from vecu.scenario.criteria import CriterionResult
from vecu.scenario.loader import SENSORS, Criteria, parse_criteria
from vecu.tomlfile import read_toml

# sensor -> (its status signal, its DTC signal), "Message.Signal" of the ECU's frames: the
# fastest frame that carries each
SENSOR_SIGNALS = {
    "tps": ("ECU_ThrottleEstimate.THR_TpsStatus", "ECU_Diag.DIAG_TpsDtc"),
    "swa": ("ECU_SteeringEstimate.STE_SwaStatus", "ECU_Diag.DIAG_SwaDtc"),
    "wheel": ("ECU_Diag.DIAG_WheelStatus", "ECU_Diag.DIAG_WheelDtc"),
}
BUS_DTC = "ECU_Diag.DIAG_BusDtc"
FAULT_EVENT = "FI_Event"
UNSUPPORTED = ("fallback_within_ms", "max_error_after_fallback", "rms_error_after_fallback")


class CriteriaFileError(BadFileError):
    """A bad --criteria file: CriteriaFileError(path, problem naming the key)."""


@dataclass(frozen=True)
class TraceCriteria:
    path: str
    criteria: Criteria
    truth: tuple[tuple[str, str, float], ...] = ()  # (function.error, rms|max, limit)


def load_trace_criteria(path: str) -> TraceCriteria:
    data = read_toml(path, CriteriaFileError)
    unknown = set(data) - {"criteria", "truth"}
    if unknown:
        raise CriteriaFileError(path, f"unknown table {min(unknown)!r} (known: criteria, "
                                "truth)")
    crit = parse_criteria(path, data.get("criteria", {}))
    for c in crit.sensors:
        for key in UNSUPPORTED:
            if getattr(c, key) is not None:
                raise CriteriaFileError(path, f"criteria.{c.sensor}.{key}: needs the run's "
                                        "series, which a trace does not hold (use [truth])")
    truth = []
    for name, limits in data.get("truth", {}).items():
        if not isinstance(limits, dict) or not limits or set(limits) - {"rms", "max"}:
            raise CriteriaFileError(path, f"truth.{name}: expected {{ rms = X, max = Y }}")
        for kind, limit in limits.items():
            if isinstance(limit, bool) or not isinstance(limit, (int, float)) or limit < 0:
                raise CriteriaFileError(path, f"truth.{name}.{kind}: expected a number >= 0")
            truth.append((str(name), kind, float(limit)))
    return TraceCriteria(path, crit, tuple(truth))


class TraceCriteriaCheck:
    """Collects the replayed ECU's status/DTC signals (on_estimate), the trace's fault events
    (read_recording) and judges the criteria (evaluate)."""

    def __init__(self, spec: TraceCriteria, codec: DbcCodec) -> None:
        self.spec = spec
        self._codec = codec
        self.codecs: dict[tuple[int, bool], FrameCodec] = {
            key: codec.by_id[key] for key in codec.sent_by("VECU")}
        self.history: dict[str, list[tuple[float, int]]] = {}  # Message.Signal -> changes
        self.non_finite = 0
        self.fault_starts: dict[int, float] = {}  # message ID -> first fault start (s)
        self._fi = codec[FAULT_EVENT] if FAULT_EVENT in codec else None  # noqa: SIM401 (no .get)
        self._watch = {s for pair in SENSOR_SIGNALS.values() for s in pair} | {BUS_DTC}

    def on_estimate(self, values: Values | None, msg: can.Message, t_ns: int) -> None:
        fc = self.codecs.get((msg.arbitration_id, msg.is_extended_id))
        if fc is None:
            return
        for name, v in fc.decode(msg.data).items():
            v = float(v)
            if not math.isfinite(v):
                self.non_finite += 1
                continue
            key = f"{fc.name}.{name}"
            if key in self._watch:
                hist = self.history.setdefault(key, [])
                if not hist or hist[-1][1] != int(v):
                    hist.append((t_ns / 1e9, int(v)))

    def read_recording(self, trace: str, fmt: str | None, idle_gap_ns: int) -> None:
        """The trace's FI_Event frames: where each fault started (replay time base, s)."""
        fi = self._fi
        if fi is None:
            return
        for chunk in TraceSource(trace, fmt, idle_gap_ns=idle_gap_ns).chunks(2048):
            for t_ns, msg in chunk:
                if msg.arbitration_id != fi.frame_id or msg.is_extended_id != fi.is_extended:
                    continue
                try:
                    ev = fi.decode(msg.data)
                except Exception:  # noqa: BLE001, S112 - a damaged event frame is no fault event
                    continue
                if int(ev["FI_EvActive"]) == 1:
                    self.fault_starts.setdefault(int(ev["FI_EvMessageId"]), t_ns / 1e9)

    def _fault_at(self, sensor: str, given: float | None) -> float | None:
        if given is not None:
            return given
        message = SENSORS[sensor]
        if message not in self._codec:
            return None
        return self.fault_starts.get(self._codec[message].frame_id)

    def evaluate(self, summary: ReplaySummary) -> list[CriterionResult]:
        crit = self.spec.criteria
        out: list[CriterionResult] = []
        if crit.no_nan:
            out.append(CriterionResult("no NaN outputs", f"{self.non_finite} NaN", "0 NaN",
                                       self.non_finite == 0))
        if crit.no_overruns:
            out.append(CriterionResult("no scheduler overruns", str(summary.ecu_overruns), "0",
                                       summary.ecu_overruns == 0))
        if crit.no_false_dtc:
            false = []
            for sensor, (_, dtc) in SENSOR_SIGNALS.items():
                t0 = self._fault_at(sensor, None)
                confirmed = [t for t, v in self.history.get(dtc, []) if v == DtcState.CONFIRMED]
                if confirmed and (t0 is None or confirmed[0] < t0):
                    false.append(f"{sensor} at {confirmed[0]:.3f} s")
            out.append(CriterionResult("no false DTC (confirmed before its fault)",
                                       ", ".join(false) or "none", "none", not false))
        for c in crit.sensors:
            status, dtc = SENSOR_SIGNALS[c.sensor]
            hist = self.history.get(status, [])
            t0 = self._fault_at(c.sensor, c.fault_at_s)
            det = None if t0 is None else next(
                ((t, v) for t, v in hist if t >= t0 - 1e-9 and v != SensorStatus.OK), None)
            if c.not_detected:
                first = next(((t, v) for t, v in hist if v != SensorStatus.OK), None)
                out.append(CriterionResult(
                    f"{c.sensor}: never diagnosed faulty", "ok throughout" if first is None
                    else f"{_status(first[1])} at {first[0]:.3f} s", "ok throughout",
                    first is None))
            if c.detect_within_ms is not None:
                latency = None if det is None or t0 is None else (det[0] - t0) * 1000.0
                out.append(CriterionResult(
                    f"{c.sensor}: detection latency",
                    ("no fault event in the trace" if t0 is None else "not detected")
                    if latency is None or det is None else f"{latency:.1f} ms ({_status(det[1])})",
                    f"<= {c.detect_within_ms:g} ms",
                    latency is not None and latency <= c.detect_within_ms + 1e-6))
            if c.detected_as is not None:
                out.append(CriterionResult(f"{c.sensor}: detected as", "not detected"
                                           if det is None else _status(det[1]),
                                           " or ".join(c.detected_as),
                                           det is not None and _status(det[1]) in c.detected_as))
            if c.dtc is not None:
                final = _final(self.history.get(dtc))
                out.append(CriterionResult(f"{c.sensor}: final DTC state", final, c.dtc,
                                           final == c.dtc))
        if crit.bus_dtc is not None:
            final = _final(self.history.get(BUS_DTC))
            out.append(CriterionResult("bus: final DTC state", final, crit.bus_dtc,
                                       final == crit.bus_dtc))
        out += _truth(self.spec.truth, summary)
        return out


def _status(v: int) -> str:
    try:
        return SensorStatus(v).name.lower()
    except ValueError:
        return str(v)


def _final(hist: list[tuple[float, int]] | None) -> str:
    if not hist:
        return "no frame"
    try:
        return DtcState(hist[-1][1]).name.lower()
    except ValueError:
        return str(hist[-1][1])


def _truth(limits: tuple[tuple[str, str, float], ...],
           summary: ReplaySummary) -> list[CriterionResult]:
    out = []
    score = summary.score
    for name, kind, limit in limits:
        function, _, error = name.partition(".")
        section = None if score is None else score.functions.get(function)
        stats: Any = None if section is None else section.errors.get(error)
        value = None if stats is None or not stats.n else (
            stats.rms if kind == "rms" else stats.max_abs)
        out.append(CriterionResult(f"{name}: {kind} error against truth",
                                   "no truth frames" if value is None else f"{value:.4g}",
                                   f"<= {limit:g}", value is not None and value <= limit))
    return out
