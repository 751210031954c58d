"""Run a fleet of traces on Dask and keep every finished trace (as campaigns do: the cluster,
rows file and progress line of vecu.campaign.cluster).

- One task per trace, `replay_trace` (vecu.fleet.task); a worker killed mid-trace has the trace
  retried once (retries=1), then it is an error row; an unreadable or truncated trace is an
  error row (its message names the position) and the rest go on.
- DIR/runs.csv gets a row per trace as it finishes (flushed line by line); `resume` replays
  exactly the traces missing from it, nothing twice. The configuration (replay options, diff
  and criteria files) is fingerprinted in DIR/meta.json: resuming needs the same.
- At the end runs.csv is rewritten in the traces' order (the same bytes whatever the workers),
  then DIR/summary.json, DIR/report.html (a row per trace, a plot) and, if asked, JUnit XML
  with one test case per trace.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, TextIO

from vecu.campaign.cluster import Progress, append_rows, header, read_rows, write_sorted
from vecu.errors import BadArgumentError
from vecu.fleet.report import write_outputs
from vecu.fleet.task import COLUMNS, FleetConfig, lost_row, replay_trace
from vecu.fleet.traces import trace_names

RUNS_CSV, META_JSON = "runs.csv", "meta.json"
WHAT = "a fleet replay's runs.csv"


@dataclass(frozen=True)
class FleetResult:
    out_dir: Path
    traces: int
    done: int
    passed: int   # status ok
    failed: int   # a verdict failed
    errors: int   # not replayed to the end (unreadable, truncated, lost)
    new: int      # traces replayed in this call
    summary: dict[str, Any]


class FleetInterrupted(Exception):
    """Ctrl-C or SIGTERM during a fleet replay: finished traces are in runs.csv (resume)."""

    def __init__(self, done: int, total: int, out_dir: Path, signal_name: str) -> None:
        super().__init__(f"interrupted: {done}/{total} traces kept in {out_dir}")
        self.done, self.total, self.out_dir, self.signal_name = done, total, out_dir, signal_name


def fingerprint(fleet: FleetConfig) -> str:
    """What must not change between a fleet and its resume: the replay's options (not the
    trace, output or progress), the output format, and the diff / criteria files' bytes."""
    cfg = {k: v for k, v in asdict(fleet.replay).items() if k not in ("trace", "out", "progress")}
    files = {}
    for kind, spec in (("diff", fleet.diff), ("criteria", fleet.criteria)):
        path = getattr(spec, "path", None) if spec is not None else None
        files[kind] = (None if spec is None else
                       hashlib.sha256(Path(path).read_bytes()).hexdigest() if path else "defaults")
    text = json.dumps({"replay": cfg, "out_format": fleet.out_format, **files}, sort_keys=True,
                      default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def prepare_dir(fleet: FleetConfig, out: Path, resume: bool) -> set[str]:
    """Create or check DIR; the traces already done (resume)."""
    out.mkdir(parents=True, exist_ok=True)
    meta_path, csv_path = out / META_JSON, out / RUNS_CSV
    meta = {"config_sha256": fingerprint(fleet)}
    if csv_path.exists() and not resume:
        raise BadArgumentError(f"{out}: holds results already; add --resume to complete them or "
                               f"choose another --out-dir")
    if resume and meta_path.exists():
        old = json.loads(meta_path.read_text())
        if old.get("config_sha256") != meta["config_sha256"]:
            raise BadArgumentError(f"{out}: was replayed with other options, diff or criteria "
                                   "files; --resume needs the same")
    meta_path.write_text(json.dumps(meta, indent=1) + "\n")
    done = {r["trace"] for r in read_rows(csv_path, COLUMNS, WHAT)}
    if not csv_path.exists():
        csv_path.write_text(header(COLUMNS))
    return done


def run_fleet(traces: list[str], fleet: FleetConfig, out: Path, workers: int | None = None,
              scheduler: str | None = None, resume: bool = False,
              progress: TextIO | None = None, junit: str | None = None) -> FleetResult:
    """Replay every trace not yet in out/runs.csv on Dask; then the table, summary, report."""
    done = prepare_dir(fleet, out, resume)
    names = dict(zip(traces, trace_names(traces)))
    todo = [t for t in traces if t not in done]
    bar = Progress(len(traces), len(done & set(traces)), progress, label="vecu replay",
                   noun="traces")
    if todo:
        stopped_by = append_rows(out / RUNS_CSV, COLUMNS, bar, replay_trace,
                                 [(fleet, t, names[t], str(out)) for t in todo],
                                 [f"vecu-trace-{os.getpid()}-{names[t]}" for t in todo],
                                 lost_row, workers, scheduler, retries=1)
        if stopped_by is not None:
            kept = len(read_rows(out / RUNS_CSV, COLUMNS, WHAT))
            raise FleetInterrupted(kept, len(traces), out, stopped_by)
    rows = read_rows(out / RUNS_CSV, COLUMNS, WHAT)
    order = {t: i for i, t in enumerate(traces)}
    rows.sort(key=lambda r: (order.get(r["trace"], len(order)), r["trace"]))
    write_sorted(out / RUNS_CSV, COLUMNS, rows)
    summary = write_outputs(rows, out, junit)
    return FleetResult(out, len(traces), len(rows), summary["ok"], summary["fail"],
                       summary["error"], bar.new, summary)
