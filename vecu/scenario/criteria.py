"""Pass criteria of a scenario, evaluated on a finished run (summary + per-tick series)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from vecu import functions
from vecu.faults import parse_site
from vecu.runner import RunResult
from vecu.scenario.loader import SENSORS, Scenario, SensorCriteria


@dataclass(frozen=True)
class CriterionResult:
    name: str
    measured: str
    limit: str
    passed: bool


@dataclass(frozen=True)
class ScenarioOutcome:
    """One scenario's verdict: criteria, timing, plot, error (vecu.scenario.batch)."""

    name: str
    path: str
    description: str
    passed: bool
    criteria: tuple[CriterionResult, ...]
    sim_s: float
    wall_s: float        # whole scenario: set-up, run, criteria, plot
    x_realtime: float    # simulated / wall seconds of the simulation loop (runner summary)
    x_realtime_cpu: float = 0.0  # simulated / CPU seconds of the whole run (robust on a busy host)
    plot: str | None = None
    error: str | None = None
    diagnostics: dict[str, Any] | None = None
    fault_events: tuple[dict[str, Any], ...] = ()

    @property
    def failures(self) -> list[CriterionResult]:
        return [c for c in self.criteria if not c.passed]


def fault_start(scenario: Scenario, sensor: str) -> float | None:
    """Start of the first timeline fault on the sensor's message."""
    message = SENSORS[sensor]
    starts = [f.start_s for f in scenario.config.faults if parse_site(f.target).message == message]
    return min(starts) if starts else None


def fault_windows(scenario: Scenario) -> list[tuple[float, float, str]]:
    """(start, end, label) of every timeline fault (end: the run's end if open)."""
    dur = scenario.config.duration_s
    return [(f.start_s, dur if f.end_s is None else min(f.end_s, dur), f"{f.target} {f.kind}")
            for f in scenario.config.faults]


def _first_after(history: list, t0: float, states: tuple[str, ...] | None = None,
                 exclude: str | None = None) -> tuple[float, str] | None:
    for t, state in history:
        if t >= t0 - 1e-9 and (states is None or state in states) and state != exclude:
            return t, state
    return None


def _series(result: RunResult, sensor: str) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                       np.ndarray | None] | None:
    """(t, broadcast, truth, source or None) for the sensor's output (its function's series)."""
    series = result.series_of(functions.sensors()[sensor][0])
    return None if series is None else series.output()


def _sensor(scenario: Scenario, result: RunResult, c: SensorCriteria) -> list[CriterionResult]:
    out: list[CriterionResult] = []
    diag = result.report.diagnostics.get(c.sensor)
    if diag is None:
        return [CriterionResult(f"{c.sensor}: monitored", "no monitor", "present", False)]
    t0 = c.fault_at_s if c.fault_at_s is not None else fault_start(scenario, c.sensor)
    det = None if t0 is None else _first_after(diag["status_history"], t0, exclude="ok")
    if c.not_detected:
        first = _first_after(diag["status_history"], 0.0, exclude="ok")
        out.append(CriterionResult(f"{c.sensor}: never diagnosed faulty",
                                   "ok throughout" if first is None else
                                   f"{first[1]} at {first[0]:.3f} s", "ok throughout",
                                   first is None))
    if c.detect_within_ms is not None:
        latency = None if det is None else (det[0] - t0) * 1000.0
        out.append(CriterionResult(
            f"{c.sensor}: detection latency", "not detected" if latency is None else
            f"{latency:.1f} ms ({det[1]})", f"<= {c.detect_within_ms:g} ms",
            latency is not None and latency <= c.detect_within_ms + 1e-6))
    if c.detected_as is not None:
        out.append(CriterionResult(f"{c.sensor}: detected as", "not detected" if det is None
                                   else det[1], " or ".join(c.detected_as),
                                   det is not None and det[1] in c.detected_as))
    fb = _fallback_time(result, c.sensor, t0, det)
    if c.fallback_within_ms is not None:
        ms = None if fb is None else (fb - t0) * 1000.0
        out.append(CriterionResult(f"{c.sensor}: time to fallback",
                                   "no fallback" if ms is None else f"{ms:.1f} ms",
                                   f"<= {c.fallback_within_ms:g} ms",
                                   ms is not None and ms <= c.fallback_within_ms + 1e-6))
    if c.max_error_after_fallback is not None or c.rms_error_after_fallback is not None:
        err = _error_after(result, c.sensor, fb)
        unit = functions.sensors()[c.sensor][1].unit
        for label, limit, value in (("max", c.max_error_after_fallback,
                                     None if err is None else float(np.max(np.abs(err)))),
                                    ("RMS", c.rms_error_after_fallback,
                                     None if err is None else float(np.sqrt(np.mean(err ** 2))))):
            if limit is not None:
                out.append(CriterionResult(
                    f"{c.sensor}: {label} error after fallback",
                    "no fallback" if value is None else f"{value:.2f} {unit}",
                    f"<= {limit:g} {unit}", value is not None and value <= limit))
    if c.dtc is not None:
        out.append(CriterionResult(f"{c.sensor}: final DTC state", diag["dtc"], c.dtc,
                                   diag["dtc"] == c.dtc))
    return out


def _fallback_time(result: RunResult, sensor: str, t0: float | None,
                   det: tuple[float, str] | None) -> float | None:
    """First time at/after t0 the output is the estimate (wheel: coasting = detection)."""
    if t0 is None:
        return None
    s = _series(result, sensor)
    if s is None or s[3] is None:
        return None if det is None else det[0]
    t, _, _, source = s
    idx = np.flatnonzero((t >= t0 - 1e-9) & (source == 1))
    return float(t[idx[0]]) if idx.size else None


def _error_after(result: RunResult, sensor: str, t_fb: float | None) -> np.ndarray | None:
    s = _series(result, sensor)
    if s is None or t_fb is None:
        return None
    t, out, truth, _ = s
    sel = t >= t_fb - 1e-9
    return (out - truth)[sel] if sel.any() else None


def evaluate(scenario: Scenario, result: RunResult) -> list[CriterionResult]:
    """Every criterion of the scenario against one run."""
    crit = scenario.criteria
    summary = result.report
    out: list[CriterionResult] = []
    if crit.no_nan:
        nan = summary.throttle.nan_outputs
        for sensor in SENSORS:
            s = _series(result, sensor)
            if s is not None:
                nan += int(np.count_nonzero(~np.isfinite(s[1])))
        out.append(CriterionResult("no NaN outputs", f"{nan} NaN", "0 NaN", nan == 0))
    if crit.no_overruns:
        out.append(CriterionResult("no scheduler overruns", str(summary.overruns), "0",
                                   summary.overruns == 0))
    if crit.no_false_dtc:
        false = []
        for name, diag in summary.diagnostics.items():
            if name == "bus":
                kinds = {f.kind for f in scenario.config.faults}
                if diag["confirmations"] and "error_frames" not in kinds:
                    false.append("bus")
                continue
            t0 = fault_start(scenario, name) if name in SENSORS else None
            confirmed = [t for t, st in diag["dtc_history"] if st == "confirmed"]
            if confirmed and (t0 is None or confirmed[0] < t0):
                false.append(f"{name} at {confirmed[0]:.3f} s")
        out.append(CriterionResult("no false DTC (confirmed before its fault)",
                                   ", ".join(false) or "none", "none", not false))
    for c in crit.sensors:
        out.extend(_sensor(scenario, result, c))
    for i, step in enumerate(summary.uds_steps or []):
        latency = "" if step["latency_ms"] is None else f" after {step['latency_ms']:g} ms"
        out.append(CriterionResult(
            f"uds[{i}] at {step['at_s']:g} s: {step['request']}",
            (step["response"] or "no response") + latency, step["expected"], step["passed"]))
    for i, step in enumerate(summary.xcp_steps or []):
        latency = "" if step["latency_ms"] is None else f" after {step['latency_ms']:g} ms"
        out.append(CriterionResult(f"xcp[{i}] at {step['at_s']:g} s: {step['step']}",
                                   step["got"] + latency, step["expected"], step["passed"]))
    if crit.bus_dtc is not None:
        state = summary.diagnostics["bus"]["dtc"]
        out.append(CriterionResult("bus: final DTC state", state, crit.bus_dtc,
                                   state == crit.bus_dtc))
    return out
