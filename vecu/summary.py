"""Typed run summaries: frozen dataclasses read by the CLI, scenario criteria, campaigns and
benches, and one JSON path (`to_json`) that gives the summary a user sees (`--summary`).

A dataclass becomes a dict of its fields in declaration order. Field metadata bends that where
today's JSON asks for it: OMIT_NONE leaves a None field out, FLATTEN merges a nested record's
keys into its parent's. A class with its own `json()` method is written by it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields, is_dataclass
from typing import Any

from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.ecu.sensor_monitor import SensorMonitor
from vecu.stats import ErrorStats

OMIT_NONE = {"omit_none": True}  # a None field is left out of the JSON
FLATTEN = {"flatten": True}      # a nested record's keys go into its parent's


def to_json(obj: Any) -> Any:
    """obj as JSON-ready data: dataclasses as dicts (field order, OMIT_NONE, FLATTEN), dicts,
    lists and tuples element by element (a tuple stays a tuple), anything else as it is."""
    if is_dataclass(obj) and not isinstance(obj, type):
        own = getattr(obj, "json", None)
        if own is not None:
            return own()
        out: dict[str, Any] = {}
        for f in fields(obj):
            value = getattr(obj, f.name)
            if value is None and f.metadata.get("omit_none"):
                continue
            if f.metadata.get("flatten"):
                out.update(to_json(value))
            else:
                out[f.name] = to_json(value)
        return out
    if isinstance(obj, Mapping):
        return {k: to_json(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [to_json(v) for v in obj]
    if isinstance(obj, tuple):
        return tuple(to_json(v) for v in obj)
    return obj


@dataclass(frozen=True)
class KillSplit:
    """One error statistic before and after a sensor's kill time."""

    before_kill: ErrorStats
    after_kill: ErrorStats


@dataclass(frozen=True)
class Detection:
    """Kill time, first confirmed fault, latency, and whether it came before any kill."""

    kill_time_s: float | None
    detected: bool
    detection_time_s: float | None
    detection_latency_ms: float | None
    detected_as: str | None
    false_alarm: bool
    dtc: str

    @classmethod
    def of(cls, mon: SensorMonitor, kill_ns: int | None) -> Detection:
        detect_ns = mon.first_fault_ns
        detected = detect_ns is not None and kill_ns is not None and detect_ns >= kill_ns
        return cls(
            kill_time_s=None if kill_ns is None else kill_ns / NS_PER_S,
            detected=detected,
            detection_time_s=detect_ns / NS_PER_S if detect_ns is not None else None,
            detection_latency_ms=((detect_ns - kill_ns) / NS_PER_MS  # type: ignore[operator]  # detected: both set
                                  if detected else None),
            detected_as=mon.first_fault_status.name.lower() if mon.first_fault_status else None,
            false_alarm=detect_ns is not None and (kill_ns is None or detect_ns < kill_ns),
            dtc=mon.dtc.name.lower())


@dataclass(frozen=True)
class FrameCounts:
    """Frames of a run: sent by plant and ECU, received and rejected by the ECU."""

    sent: int
    plant_sent: int
    ecu_sent: int
    send_errors: int
    received: int
    rejected: int
    ecu_rx: dict[str, int]
    logged: int | None
    rejected_fault_commands: int
    # requests whose handler raised (UDS, XCP, FI_Command), by "node: handler": answered with
    # the protocol's negative response or dropped, counted; the node kept ticking
    handler_errors: dict[str, int] = field(default_factory=dict)


@dataclass(frozen=True)
class RunSummary:
    """`vecu run`'s summary. `throttle` is the ECU's first function (always there); the other
    functions' sections are `functions` by name (JSON: top-level keys after the rest)."""

    config: dict[str, Any]
    ticks: int
    overruns: int
    tasks: dict[str, dict[str, Any]]
    sim_time_s: float
    wall_time_s: float
    x_realtime: float | None
    kernels: str
    throttle: Any  # vecu.functions.throttle.ThrottleSummary
    frames: FrameCounts
    fault_events: list[dict[str, Any]]
    kernel_load_s: float
    bus: str
    diagnostics: dict[str, dict[str, Any]]
    restbus: dict[str, Any] | None = field(default=None, metadata=OMIT_NONE)
    uds: dict[str, Any] | None = field(default=None, metadata=OMIT_NONE)
    uds_steps: list[dict[str, Any]] | None = field(default=None, metadata=OMIT_NONE)
    xcp: dict[str, Any] | None = field(default=None, metadata=OMIT_NONE)
    xcp_steps: list[dict[str, Any]] | None = field(default=None, metadata=OMIT_NONE)
    gateway: dict[str, Any] | None = field(default=None, metadata=OMIT_NONE)  # routing's figures
    functions: dict[str, Any] = field(default_factory=dict, metadata=FLATTEN)

    def section(self, name: str) -> Any:
        """A function's section by name (None: that function did not run)."""
        return self.throttle if name == "throttle" else self.functions.get(name)
