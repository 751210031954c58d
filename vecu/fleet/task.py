"""One trace of a fleet, on a Dask worker: `vecu replay` of it alone (the same engine and
configuration, so the same output trace and summary), its diff against the recording and its
criteria, written under DIR/traces/, and its row of the fleet table."""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from vecu.clock import NS_PER_S
from vecu.errors import VecuError
from vecu.fleet.criteria import TraceCriteria, TraceCriteriaCheck
from vecu.fleet.diff import DiffSpec, RecordingDiff, as_row
from vecu.replay.engine import ReplayConfig, ecu_codec_of, replay
from vecu.summary import to_json

TRACES_DIR = "traces"  # DIR/traces/NAME.summary.json, NAME.diff.json, NAME.<out format>
COLUMNS = ["trace", "name", "status", "verdict", "error", "trace_duration_s", "frames_read",
           "rejected", "estimates_sent", "diff", "diff_paired", "diff_recorded_only",
           "diff_replayed_only", "diff_failed_signals", "diff_first_divergence_s",
           "criteria_failed"]


@dataclass(frozen=True)
class FleetConfig:
    """What every trace of a fleet is replayed with: `replay` is `vecu replay`'s configuration
    (its trace, out and progress set per trace); the output trace's format (a suffix, None: no
    output trace), the diff's tolerances (None: no diff) and the criteria (None: none)."""

    replay: ReplayConfig
    out_format: str | None = None
    diff: DiffSpec | None = None
    criteria: TraceCriteria | None = None


def outputs(out_dir: Path, name: str, out_format: str | None) -> dict[str, Path]:
    base = out_dir / TRACES_DIR
    paths = {"summary": base / f"{name}.summary.json", "diff": base / f"{name}.diff.json",
             "criteria": base / f"{name}.criteria.json"}
    if out_format is not None:
        paths["out"] = base / f"{name}.{out_format.lstrip('.')}"
    return paths


def replay_config(fleet: FleetConfig, trace: str, out_dir: Path, name: str) -> ReplayConfig:
    """The trace's ReplayConfig: exactly what `vecu replay TRACE --out OUT` runs."""
    out = outputs(out_dir, name, fleet.out_format).get("out")
    return replace(fleet.replay, trace=trace, out=None if out is None else str(out),
                   progress=False)


def replay_trace(fleet: FleetConfig, trace: str, name: str, out_dir: str) -> dict[str, Any]:
    """Replay one trace, write its outputs, return its row. A trace that cannot be read (at
    open or part-way: the position is in the message) is a row with status "error"; a bug in
    vecu raises (Dask retries the task once, then the fleet records it)."""
    base = Path(out_dir)
    (base / TRACES_DIR).mkdir(parents=True, exist_ok=True)
    paths = outputs(base, name, fleet.out_format)
    row: dict[str, Any] = {"trace": trace, "name": name, "status": "error", "verdict": "error",
                           "error": ""}
    config = replay_config(fleet, trace, base, name)
    try:
        codec = ecu_codec_of(config)
        diff = None if fleet.diff is None else RecordingDiff(codec, fleet.diff)
        check = (None if fleet.criteria is None
                 else TraceCriteriaCheck(fleet.criteria, codec))
        result = replay(config, extra_sinks=[s for s in (diff, check) if s is not None])
    except VecuError as exc:
        row["error"] = str(exc)
        return row
    paths["summary"].write_text(json.dumps(result.summary, indent=2) + "\n")
    report = result.report
    row.update(trace_duration_s=report.trace_duration_s, frames_read=report.frames.read,
               rejected=report.frames.rejected,
               estimates_sent=sum(f.estimates_sent or 0 for f in report.functions.values()))
    if result.error:
        row["error"] = result.error
        return row
    gap_ns = round(config.idle_gap_s * NS_PER_S)
    failed: list[str] = []
    if diff is not None:
        diff.read_recording(trace, config.fmt, gap_ns)
        d = diff.report()
        paths["diff"].write_text(json.dumps(to_json(d), indent=2) + "\n")
        row.update(as_row(d))
        if d.verdict == "fail":
            failed.append("diff")
    if check is not None:
        check.read_recording(trace, config.fmt, gap_ns)
        results = check.evaluate(report)
        paths["criteria"].write_text(json.dumps(
            [{"name": c.name, "measured": c.measured, "limit": c.limit, "passed": c.passed}
             for c in results], indent=2) + "\n")
        bad = [c.name for c in results if not c.passed]
        row["criteria_failed"] = "; ".join(bad)
        if bad:
            failed.append("criteria")
    row["status"] = "fail" if failed else "ok"
    if failed:
        row["verdict"] = "fail"
    elif fleet.criteria is None and row.get("diff") in (None, "none"):
        row["verdict"] = "none"  # nothing judged: no diff asked, or no recording to diff with
    else:
        row["verdict"] = "pass"
    return row


def lost_row(item: tuple[Any, ...], exc: BaseException) -> dict[str, Any]:
    """The row of a trace whose task failed past its retry (a killed worker, a bug)."""
    _, trace, name, _ = item
    return {"trace": trace, "name": name, "status": "error", "verdict": "error",
            "error": f"{type(exc).__name__}: {exc}"[:300]}
