"""Run a campaign on Dask and keep every finished run.

- Cluster and rows on Dask: vecu.campaign.cluster (shared with fleet replays, vecu.fleet).
- Each run is one task `run_one(spec, i)`; a worker that dies has its runs retried (retries=2);
  a run that raises is a row with status "error" (its seed and message), never a lost run.
- Rows are appended to DIR/runs.csv as they finish (flushed line by line): Ctrl-C or a killed
  vecu loses only the runs in flight, and `resume` runs exactly the missing run ids. At the end
  runs.csv is rewritten in run-id order (the same bytes whatever the workers or the order) and
  DIR/summary.json and DIR/report.html are written (vecu.campaign.summary).
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from vecu.campaign.cluster import (
    Progress,
    append_rows,
    default_progress_stream,
    header,
    write_sorted,
)
from vecu.campaign.cluster import read_rows as _read_rows
from vecu.campaign.spec import CampaignSpec
from vecu.campaign.studies import metric_names, run_one
from vecu.errors import BadArgumentError

RUNS_CSV, META_JSON, SPEC_COPY = "runs.csv", "meta.json", "campaign.toml"


def columns(spec: CampaignSpec) -> list[str]:
    return (["run_id", "sim_seed", "status", "error"] + [f"draw:{v.path}" for v in spec.vary]
            + list(metric_names(spec)))


def read_rows(path: Path, cols: list[str]) -> list[dict[str, str]]:
    """The complete rows of runs.csv (vecu.campaign.cluster.read_rows)."""
    return _read_rows(path, cols, "this campaign file")


@dataclass(frozen=True)
class CampaignResult:
    out_dir: Path
    runs: int
    done: int  # rows in runs.csv
    failed: int
    new: int  # runs computed in this call
    summary: dict[str, Any]


def _meta(spec: CampaignSpec) -> dict[str, Any]:
    text = Path(spec.path).read_bytes()
    return {"spec_sha256": hashlib.sha256(text).hexdigest(), "seed": spec.seed,
            "runs": spec.runs, "kind": spec.kind, "name": spec.name}


def prepare_dir(spec: CampaignSpec, out: Path, resume: bool) -> set[int]:
    """Create or check DIR; the run ids already done (resume)."""
    out.mkdir(parents=True, exist_ok=True)
    meta_path, csv_path = out / META_JSON, out / RUNS_CSV
    meta = _meta(spec)
    if csv_path.exists() and not resume:
        raise BadArgumentError(f"{out}: holds results already; add --resume to complete them or "
                               f"choose another --out")
    if resume and meta_path.exists():
        old = json.loads(meta_path.read_text())
        for k in ("spec_sha256", "seed", "kind"):
            if old.get(k) != meta[k]:
                raise BadArgumentError(f"{out}: was run with a different campaign ({k} differs); "
                                       f"--resume needs the same file and seed")
    meta_path.write_text(json.dumps(meta, indent=1) + "\n")
    (out / SPEC_COPY).write_bytes(Path(spec.path).read_bytes())
    done = {int(r["run_id"]) for r in read_rows(csv_path, columns(spec))}
    if not csv_path.exists():
        csv_path.write_text(header(columns(spec)))
    return done


class CampaignInterrupted(Exception):
    """Ctrl-C or SIGTERM during a campaign: the finished rows are in runs.csv (resume them)."""

    def __init__(self, done: int, runs: int, out_dir: Path, signal_name: str) -> None:
        super().__init__(f"interrupted: {done}/{runs} runs kept in {out_dir}")
        self.done, self.runs, self.out_dir, self.signal_name = done, runs, out_dir, signal_name


def run_campaign(spec: CampaignSpec, out: Path, workers: int | None = None,
                 scheduler: str | None = None, resume: bool = False,
                 progress: TextIO | None = None) -> CampaignResult:
    """Run every missing run of spec on Dask, appending rows to out/runs.csv; then summarise."""
    from vecu.campaign.summary import summarise, write_report

    done = prepare_dir(spec, out, resume)
    todo = [i for i in range(spec.runs) if i not in done]
    cols = columns(spec)
    bar = Progress(spec.runs, len(done), progress)
    if todo:
        def lost(item: tuple[Any, ...], exc: BaseException) -> dict[str, Any]:
            return {"run_id": item[1], "status": "error",
                    "error": f"{type(exc).__name__}: {exc}"[:300]}

        stopped_by = append_rows(out / RUNS_CSV, cols, bar, run_one, [(spec, i) for i in todo],
                                 [f"vecu-run-{spec.seed}-{i}-{os.getpid()}" for i in todo],
                                 lost, workers, scheduler, retries=2)
        if stopped_by is not None:
            kept = len(read_rows(out / RUNS_CSV, cols))
            raise CampaignInterrupted(kept, spec.runs, out, stopped_by)
    rows = read_rows(out / RUNS_CSV, cols)
    rows.sort(key=lambda r: int(r["run_id"]))
    write_sorted(out / RUNS_CSV, cols, rows)
    summary = summarise(spec, rows)
    (out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    write_report(spec, rows, summary, out)
    failed = sum(r["status"] != "ok" for r in rows)
    return CampaignResult(out, spec.runs, len(rows), failed, bar.new, summary)


__all__ = ["META_JSON", "RUNS_CSV", "SPEC_COPY", "CampaignInterrupted", "CampaignResult",
           "columns", "default_progress_stream", "prepare_dir", "read_rows", "run_campaign"]
