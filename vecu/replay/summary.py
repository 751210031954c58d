"""`vecu replay`'s summary as frozen dataclasses; vecu.summary.to_json gives the JSON a user
sees (`--summary`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from vecu.stats import ErrorStats
from vecu.summary import FLATTEN, OMIT_NONE


@dataclass(frozen=True)
class ReplayFrames:
    """What became of the trace's frames."""

    read: int
    decoded: int
    ignored_known: int
    unknown_id: int
    error_frames: int
    remote_frames: int
    rejected: int
    rejected_by_reason: dict[str, int]
    truth: int
    out_of_order: int
    late: int
    non_finite_time: int
    ecu_rx: dict[str, int]


@dataclass(frozen=True)
class FunctionReport:
    """One ECU function in a replay: enabled by the map, ran (had input frames), its estimates;
    reason: why it did not run (None: it ran)."""

    enabled: bool
    ran: bool = False
    estimates_sent: int | None = None
    reason: str | None = None

    def json(self) -> dict[str, Any]:
        if not self.enabled:
            return {"enabled": False, "reason": self.reason}
        out: dict[str, Any] = {"enabled": True, "ran": self.ran,
                               "estimates_sent": self.estimates_sent}
        if self.reason is not None:
            out["reason"] = self.reason
        return out


@dataclass(frozen=True)
class MapReport:
    file: str | None
    notes: list[str]


@dataclass(frozen=True)
class IdleGaps:
    threshold_s: float
    count: int
    skipped_s: float
    longest_s: float
    first: list[list[float]]  # [start_s, length_s] of the first gaps


@dataclass(frozen=True)
class ScoreSection:
    """One function's estimates scored against the trace's truth frames."""

    errors: dict[str, ErrorStats] = field(metadata=FLATTEN)
    unmatched_estimates: int
    not_valid_estimates: int = 0  # flagged init / invalid by the ECU (vecu.ecu.validity): skipped


@dataclass(frozen=True)
class ReplayScore:
    truth_frames: int
    bad_truth_frames: int
    functions: dict[str, ScoreSection] = field(metadata=FLATTEN)


@dataclass(frozen=True)
class ReplaySummary:
    trace: str
    mode: str
    config: dict[str, Any]
    error: str | None
    frames: ReplayFrames
    functions: dict[str, FunctionReport]
    map: MapReport
    trace_duration_s: float
    simulated_s: float  # what the ECU ran: the trace less the idle time skipped
    idle_gaps: IdleGaps
    wall_time_s: float
    x_realtime: float | None
    frames_per_s: int | None
    kernels: str
    frames_written: int
    ecu_overruns: int
    score: ReplayScore | None
    schedule_error: dict[str, Any] | None = field(default=None, metadata=OMIT_NONE)  # live only
    kernel_load_s: float = 0.0
    gateway: dict[str, Any] | None = field(default=None, metadata=OMIT_NONE)  # --gateway: routes
