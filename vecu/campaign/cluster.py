"""Many independent tasks on Dask, each a row kept as it finishes: what campaigns and fleet
replays (vecu.fleet) share.

- Cluster: `distributed.LocalCluster` of `workers` single-threaded processes by default, or an
  existing cluster (`dask scheduler` / `dask worker`) at `scheduler`. No home-made pool.
- `run_rows`: one task per item, a worker that dies has its task retried (`retries`); a task that
  raises past its retries is a row made by `lost(item, exc)`, never a lost item. Each row goes to
  `keep(row)` as it finishes; Ctrl-C or SIGTERM stop the cluster quietly and are returned.
- Rows files: one CSV line per row, flushed line by line (a kill loses only the tasks in flight);
  `read_rows` drops a line cut mid-write, `write_sorted` rewrites the file in a fixed order at the
  end (the same bytes whatever the workers or the order they finished in).
"""

from __future__ import annotations

import contextlib
import csv
import io
import logging
import os
import signal
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TextIO

from vecu.clock import perf_s
from vecu.errors import BadFileError, UnavailableError


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


def header(cols: list[str]) -> str:
    return format_row(cols, {c: c for c in cols})


def read_rows(path: Path, cols: list[str], what: str = "this campaign file") -> list[dict[str, str]]:
    """The complete rows of a rows file (a line cut by a kill mid-write is dropped, and the file
    is truncated back to its last complete line so appending goes on cleanly)."""
    if not path.is_file():
        return []
    raw = path.read_bytes()
    good = raw[: raw.rfind(b"\n") + 1]
    if len(good) != len(raw):
        path.write_bytes(good)
    reader = csv.reader(io.StringIO(good.decode()))
    head = next(reader, None)
    if head != cols:
        raise BadFileError(path, f"columns do not match {what} (use another output directory)")
    return [dict(zip(cols, r)) for r in reader if len(r) == len(cols)]


def write_sorted(path: Path, cols: list[str], rows: list[dict[str, str]]) -> None:
    """Rewrite the rows file with `rows` (already in their final order), atomically."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(header(cols) + "".join(format_row(cols, r) for r in rows))
    tmp.replace(path)


class Progress:
    """One status line on stderr: items done/failed, rate, ETA (throttled to 2 per second)."""

    def __init__(self, total: int, done: int, stream: TextIO | None,
                 label: str = "vecu campaign", noun: str = "runs") -> None:
        self.total, self.done, self.failed, self.new = total, done, 0, 0
        self.label, self.noun = label, noun
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
        self._stream.write(f"\r{self.label}: {self.done}/{self.total} {self.noun}, {self.failed} "
                           f"failed, {rate:.2f} {self.noun}/s, ETA {eta:.0f} s   ")
        self._stream.flush()

    def close(self) -> None:
        if self._stream is not None:
            self._stream.write("\n")
            self._stream.flush()


def default_progress_stream() -> TextIO | None:
    return sys.stderr if sys.stderr.isatty() else None


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
        # the workers log only what is critical: a task's own error comes back as its row, and
        # a worker that loses its scheduler at an interrupt is not the user's business
        # no dashboard; the scheduler's HTTP routes (health, metrics) on a free port, not on
        # 8787: a second cluster on the machine (another vecu, a parallel test) is no clash
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.CRITICAL,
                               scheduler_kwargs={"dashboard_address": ":0"})
    finally:
        signal.signal(signal.SIGINT, previous)
    return Client(cluster), cluster


def run_rows(fn: Callable[..., dict[str, Any]], items: Sequence[tuple[Any, ...]],
             keys: Sequence[str], keep: Callable[[dict[str, Any]], None],
             lost: Callable[[tuple[Any, ...], BaseException], dict[str, Any]],
             workers: int | None = None, scheduler: str | None = None,
             retries: int = 2) -> str | None:
    """fn(*item) for every item on Dask, each row to keep() as it finishes; None when all
    finished, else the signal that stopped it ("SIGINT" / "SIGTERM"; the cluster is stopped and
    whatever keep() got is kept)."""
    from distributed import as_completed

    from vecu.live.children import Terminated

    client, cluster = open_client(workers, scheduler)
    futures: list[Any] = []
    finished = False
    stopped_by: str | None = None
    try:
        futures = [client.submit(fn, *item, pure=False, retries=retries, key=key)
                   for item, key in zip(items, keys)]
        by_key = {f.key: item for f, item in zip(futures, items)}
        for fut in as_completed(futures):
            try:
                row = fut.result()
            except Exception as exc:  # noqa: BLE001 (the worker died more often than retries allow)
                row = lost(by_key[fut.key], exc)
            keep(row)
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
    return stopped_by


def append_rows(path: Path, cols: list[str], bar: Progress, fn: Callable[..., dict[str, Any]],
                items: Sequence[tuple[Any, ...]], keys: Sequence[str],
                lost: Callable[[tuple[Any, ...], BaseException], dict[str, Any]],
                workers: int | None, scheduler: str | None, retries: int) -> str | None:
    """run_rows() with each row appended to the rows file at `path` as it finishes (flushed)
    and counted on the progress line (status "ok" or not); the line is closed at the end."""
    try:
        with open(path, "a", newline="") as fh:
            def keep(row: dict[str, Any]) -> None:
                fh.write(format_row(cols, row))
                fh.flush()
                bar.update(row["status"] == "ok")

            return run_rows(fn, items, keys, keep, lost, workers, scheduler, retries)
    finally:
        bar.close()


def _quiet_shutdown(client: Any, cluster: Any, futures: list[Any]) -> None:
    """Cancel the queued tasks and stop the cluster, once, with nothing on the terminal but
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
