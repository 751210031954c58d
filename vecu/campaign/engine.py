"""Run a campaign on Dask and keep every finished run.

- Cluster: `distributed.LocalCluster` of `workers` single-threaded processes by default, or an
  existing cluster (`dask scheduler` / `dask worker`) at `scheduler`. No home-made pool.
- Each run is one task `run_one(spec, i)`; a worker that dies has its runs retried (retries=2);
  a run that raises is a row with status "error" (its seed and message), never a lost run.
- Rows are appended to DIR/runs.csv as they finish (flushed line by line): Ctrl-C or a killed
  vecu loses only the runs in flight, and `resume` runs exactly the missing run ids. At the end
  runs.csv is rewritten in run-id order (the same bytes whatever the workers or the order) and
  DIR/summary.json and DIR/report.html are written (vecu.campaign.summary).
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import io
import json
import logging
import os
import signal
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from vecu.campaign.spec import CampaignSpec
from vecu.campaign.studies import metric_names, run_one
from vecu.clock import perf_s
from vecu.errors import BadArgumentError, BadFileError, UnavailableError

RUNS_CSV, META_JSON, SPEC_COPY = "runs.csv", "meta.json", "campaign.toml"


def columns(spec: CampaignSpec) -> list[str]:
    return (["run_id", "sim_seed", "status", "error"] + [f"draw:{v.path}" for v in spec.vary]
            + list(metric_names(spec)))


def _cell(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def format_row(cols: list[str], row: dict[str, Any]) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow([_cell(row.get(c)) for c in cols])
    return buf.getvalue()


def read_rows(path: Path, cols: list[str]) -> list[dict[str, str]]:
    """The complete rows of runs.csv (a line cut by a kill mid-write is dropped, and the file is
    truncated back to its last complete line so appending goes on cleanly)."""
    if not path.is_file():
        return []
    raw = path.read_bytes()
    good = raw[: raw.rfind(b"\n") + 1]
    if len(good) != len(raw):
        path.write_bytes(good)
    reader = csv.reader(io.StringIO(good.decode()))
    header = next(reader, None)
    if header != cols:
        raise BadFileError(path, "columns do not match this campaign file (use another --out)")
    return [dict(zip(cols, r)) for r in reader if len(r) == len(cols)]


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
        csv_path.write_text(format_row(columns(spec), {c: c for c in columns(spec)}))
    return done


class Progress:
    """One status line on stderr: runs done/failed, rate, ETA (throttled to 2 per second)."""

    def __init__(self, total: int, done: int, stream: TextIO | None) -> None:
        self.total, self.done, self.failed, self.new = total, done, 0, 0
        self._stream = stream
        self._t0 = perf_s()
        self._last = -1.0

    def update(self, ok: bool, force: bool = False) -> None:
        self.done += 1
        self.new += 1
        self.failed += 0 if ok else 1
        now = perf_s()
        if self._stream is None or (not force and now - self._last < 0.5):
            return
        self._last = now
        rate = self.new / max(now - self._t0, 1e-9)
        eta = (self.total - self.done) / rate if rate > 0 else float("inf")
        self._stream.write(f"\rvecu campaign: {self.done}/{self.total} runs, {self.failed} failed, "
                           f"{rate:.2f} runs/s, ETA {eta:.0f} s   ")
        self._stream.flush()

    def close(self) -> None:
        if self._stream is not None:
            self._stream.write("\n")
            self._stream.flush()


def open_client(workers: int | None, scheduler: str | None) -> tuple[Any, Any]:
    """(client, cluster or None): a LocalCluster of `workers` processes, or the scheduler's."""
    try:
        from distributed import Client, LocalCluster
    except ImportError as exc:  # a dependency of vecu: a broken or partial environment
        raise UnavailableError(f"campaigns run on Dask, which does not import here ({exc}): "
                               "pip install 'dask[distributed]>=2024.1'") from None
    if scheduler:
        logging.getLogger("distributed").setLevel(logging.ERROR)
        try:
            return Client(scheduler, timeout="10s"), None
        except OSError as exc:
            raise UnavailableError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
    n = workers or os.cpu_count() or 1
    for name in ("distributed", "tornado"):  # the cluster's own INFO chatter, not the user's
        logging.getLogger(name).setLevel(logging.ERROR)
    # the workers ignore SIGINT (inherited through their exec): a Ctrl-C on the terminal goes to
    # the whole process group, and each worker printed its KeyboardInterrupt traceback; vecu
    # stops them itself (cluster.close) once it has the interrupt
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        # the workers log only what is critical: a run's own error comes back as its row, and
        # a worker that loses its scheduler at an interrupt is not the user's business
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.CRITICAL)
    finally:
        signal.signal(signal.SIGINT, previous)
    return Client(cluster), cluster


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
        from distributed import as_completed

        from vecu.live.children import Terminated

        client, cluster = open_client(workers, scheduler)
        futures: list[Any] = []
        finished = False
        stopped_by: str | None = None
        try:
            with open(out / RUNS_CSV, "a", newline="") as fh:
                futures = [client.submit(run_one, spec, i, pure=False, retries=2,
                                         key=f"vecu-run-{spec.seed}-{i}-{os.getpid()}")
                           for i in todo]
                ids = {f.key: i for f, i in zip(futures, todo)}
                for fut in as_completed(futures):
                    try:
                        row = fut.result()
                    except Exception as exc:  # noqa: BLE001 (the worker died more often than retries allow)
                        row = {"run_id": ids[fut.key], "status": "error",
                               "error": f"{type(exc).__name__}: {exc}"[:300]}
                    fh.write(format_row(cols, row))
                    fh.flush()
                    bar.update(row["status"] == "ok")
                    fut.release()
            finished = True
        except KeyboardInterrupt:
            stopped_by = "SIGINT"
        except Terminated:
            stopped_by = "SIGTERM"
        finally:
            if not finished:  # Ctrl-C, SIGTERM or an error: stop what is still queued
                _quiet_shutdown(client, cluster, futures)
            else:
                client.close()
                if cluster is not None:
                    cluster.close()
            bar.close()
        if stopped_by is not None:
            kept = len(read_rows(out / RUNS_CSV, cols))
            raise CampaignInterrupted(kept, spec.runs, out, stopped_by)
    rows = read_rows(out / RUNS_CSV, cols)
    rows.sort(key=lambda r: int(r["run_id"]))
    tmp = out / (RUNS_CSV + ".tmp")
    tmp.write_text(format_row(cols, {c: c for c in cols})
                   + "".join(format_row(cols, r) for r in rows))
    tmp.replace(out / RUNS_CSV)
    summary = summarise(spec, rows)
    (out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    write_report(spec, rows, summary, out)
    failed = sum(r["status"] != "ok" for r in rows)
    return CampaignResult(out, spec.runs, len(rows), failed, bar.new, summary)


def _quiet_shutdown(client: Any, cluster: Any, futures: list[Any]) -> None:
    """Cancel the queued runs and stop the cluster, once, with nothing on the terminal but
    vecu's own line: a second Ctrl-C meanwhile does not cut the shutdown short (no orphan
    workers), and the cluster's complaints about the work it loses are not the user's."""
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    levels = {name: logging.getLogger(name).level
              for name in ("distributed", "tornado", "asyncio")}
    for name in levels:
        logging.getLogger(name).setLevel(logging.CRITICAL)
    try:
        with contextlib.suppress(Exception):  # the scheduler may be gone already
            client.cancel([f for f in futures if not f.done()])
        client.close()
        if cluster is not None:
            cluster.close()
    finally:
        for name, level in levels.items():
            logging.getLogger(name).setLevel(level)
        signal.signal(signal.SIGINT, previous)


def default_progress_stream() -> TextIO | None:
    return sys.stderr if sys.stderr.isatty() else None
