"""Trace input: python-can's readers (chosen by suffix) behind one iterator that never raises
mid-run, puts frames on a relative nanosecond time base, orders them by timestamp within a window,
shortens idle gaps and finds truncated files.

Decisions (docs/replay.md):
- Out-of-order timestamps: frames are re-ordered inside a sliding window of REORDER_WINDOW_NS; a
  frame older than what has already been released is delivered at the current time and counted as
  `late`. Every backwards step in the file is counted as `out_of_order`.
- Time resolution: a frame's time (relative to the first frame) is rounded to the nearest
  TIME_RESOLUTION_NS (1 us, what every format keeps: candump .log, .asc and .trc store it, BLF
  ns, CSV and MF4 floats). So each format gives the same times: python-can's MF4 writer stores them
  relative to the wall clock at open and they come back up to ~1e-7 s off. (vecu's recorder
  stamps frames at 1 us on the right side of each ECU tick: vecu.recorder.record_stamp.)
- Idle gaps: a silence longer than the idle gap (no frame at all) is shortened to it; later frames
  move earlier by what was skipped (`gaps`, `skipped_before()` maps a time back to the trace's).
"""

from __future__ import annotations

import contextlib
import gc
import gzip
import heapq
import io
import logging
import math
import os
import traceback
from bisect import bisect_right
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import can

from vecu.clock import NS_PER_S
from vecu.errors import BadArgumentError, BadFileError
from vecu.recorder import TIME_RESOLUTION_NS

log = logging.getLogger(__name__)

REORDER_WINDOW_NS = 50_000_000  # 50 ms: covers multi-channel loggers that flush per channel
IDLE_GAP_NS = 10 * NS_PER_S  # a longer silence is shortened to this (docs/replay.md)
MAX_GAPS_LISTED = 10
CHUNK_FRAMES = 16  # frames read ahead behind __iter__ (a live player reads that many at a time)
# Text formats whose writers end every line (candump -L, CANoe ASC, python-can CSV): a last line
# without a newline there is a cut-off file, and python-can would read its stub as a short frame.
# (TRC is left out: PCAN writers may omit the final newline, and python-can's TRC reader skips
# lines it cannot parse, with its own warning.)
LINE_TERMINATED = {"asc", "log", "csv"}


QUIET_LOGGERS = ("asammdf",)  # readers that log tracebacks of a corrupt file on stderr themselves


class TraceReadError(BadFileError):
    """The trace cannot be read: TraceReadError(path, problem)."""


@contextlib.contextmanager
def quiet_reader_logs() -> Iterator[None]:
    """The readers' own loggers silenced while a trace is opened and read: vecu reports a bad file
    in one line (TraceReadError, TraceSource.error), their tracebacks would only bury it."""
    loggers = [logging.getLogger(name) for name in QUIET_LOGGERS]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)


def _drop_half_built(exc: BaseException) -> None:
    """Let go now of what a reader that failed to open left in exc's frames, with the messages
    of their __del__ kept off stderr (asammdf's MDF4.__del__ raises on a half-built object:
    'Exception ignored in ...'); the traceback keeps its lines for --debug."""
    with contextlib.redirect_stderr(io.StringIO()):
        seen: set[int] = set()
        e: BaseException | None = exc
        while e is not None and id(e) not in seen:
            seen.add(id(e))
            traceback.clear_frames(e.__traceback__)
            e = e.__cause__ or e.__context__
        gc.collect()


@dataclass
class SourceStats:
    frames_read: int = 0
    out_of_order: int = 0   # timestamp lower than the previous frame's in the file
    late: int = 0           # so late that it fell outside the re-order window (delivered now)
    non_finite_time: int = 0  # NaN/inf timestamps: delivered at the current time
    gaps: int = 0           # idle gaps shortened to the idle gap
    skipped_ns: int = 0     # silence skipped in them
    longest_gap_ns: int = 0
    # the first MAX_GAPS_LISTED gaps: (start, length) in ns on the trace's own time base
    gap_list: list[tuple[int, int]] = field(default_factory=list)


def reader_formats() -> list[str]:
    """File formats python-can reads here (suffixes without the dot), e.g. for --format."""
    player = can.io.player
    if hasattr(player, "_update_reader_plugins"):
        player._update_reader_plugins()
    return sorted(s.lstrip(".") for s in getattr(player, "MESSAGE_READERS", {}))


# python-can's readers by the user's name for their format ("FILE: not a BLF file"); another
# reader a plug-in adds: "a .SUFFIX file"
FORMAT_NAMES = {"asc": "a Vector ASC log", "blf": "a BLF file", "csv": "a python-can CSV log",
                "db": "a python-can SQLite log", "log": "a candump -L log", "mf4": "an MF4 file",
                "trc": "a PCAN TRC file"}


def trace_format(path: str | Path, fmt: str | None = None) -> str:
    """The format a trace is read as: fmt, else its suffix (before .gz) without the dot; a suffix
    python-can has no reader for is a TraceReadError naming it and --format."""
    if fmt is not None:
        return fmt
    name = str(path).removesuffix(".gz")
    suffix = Path(name).suffix.lower()
    formats = reader_formats()
    if suffix.lstrip(".") in formats:
        return suffix.lstrip(".")
    known = f"python-can reads {', '.join(formats)}"
    raise TraceReadError(path, f"unknown suffix {suffix}: use --format ({known})" if suffix
                         else f"no suffix to tell the format: use --format ({known})")


def not_a(fmt: str, size: int | None = None, nothing_read: bool = False) -> str:
    """The user's words for a file that is not in format fmt, with what to try instead;
    nothing_read: the reader raised nothing but found no frame either."""
    name = FORMAT_NAMES.get(fmt, f"a .{fmt} file")
    if size == 0:
        return f"not {name} (the file is empty)"
    hint = f"another format? try --format {', '.join(f for f in reader_formats() if f != fmt)}"
    if fmt == "log":
        hint = f"a plain candump? python-can reads `candump -L` output only; {hint}"
    return f"no CAN frames in it (not {name}? {hint})" if nothing_read else f"not {name} ({hint})"


def open_reader(path: str | Path, fmt: str | None = None) -> can.io.generic.MessageReader:
    """python-can reader for path: by suffix (.asc .blf .log .trc .csv .mf4, + .gz), or fmt. A file
    the reader refuses is a TraceReadError in the user's words (not_a): python-can's exception
    stays its __cause__ (shown with --debug), not the message."""
    path = str(path)
    if not os.path.exists(path):
        raise TraceReadError(path, "no such file")
    if fmt is not None:
        readers = {f: can.io.player.MESSAGE_READERS["." + f] for f in reader_formats()}
        if fmt not in readers:
            raise BadArgumentError(f"unknown format {fmt!r} (python-can reads: "
                                   f"{', '.join(readers)})")
    kind = trace_format(path, fmt)
    try:
        with quiet_reader_logs():
            if fmt is None:
                return can.LogReader(path)
            cls = readers[fmt]
            if path.endswith(".gz"):
                text = issubclass(cls, can.io.generic.TextIOMessageReader)
                return cls(gzip.open(path, mode="rt" if text else "rb"))
            return cls(file=path)
    except (ImportError, NotImplementedError) as exc:  # python-can: an optional package missing
        need = ("the asammdf package: pip install 'vecu[mf4]'" if kind == "mf4"
                else f"an optional package: {exc}")
        raise TraceReadError(path, f"reading this format needs {need}") from exc
    except OSError as exc:
        if exc.strerror is None:  # gzip, struct and friends: the content, not the file system
            _drop_half_built(exc)
            raise TraceReadError(path, not_a(kind, _file_size(path))) from exc
        raise TraceReadError(path, f"cannot read: {exc.strerror}") from exc
    except Exception as exc:  # python-can raises many kinds: each a file it cannot read as kind
        _drop_half_built(exc)
        raise TraceReadError(path, not_a(kind, _file_size(path))) from exc


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}".rstrip(": ")


class TraceSource:
    """Frames of one trace file as (t_ns, message), t_ns relative to the first frame.

    Iterate once. A read error stops the iteration after everything read before it; `error` then
    holds a one-line description naming the file and the position (frame count, last timestamp).
    """

    def __init__(self, path: str | Path, fmt: str | None = None,
                 window_ns: int = REORDER_WINDOW_NS, idle_gap_ns: int = IDLE_GAP_NS) -> None:
        self.path = str(path)
        self.fmt = fmt
        self.window_ns = window_ns
        self.idle_gap_ns = idle_gap_ns
        # where each shortened gap ends on the replay's time base, and what was skipped up to it
        self._gap_ends: list[int] = []
        self._skipped_at: list[int] = []
        self.stats = SourceStats()
        self.error: str | None = None
        self.t0_s: float | None = None  # timestamp of the first frame (the time origin)
        self._last_ts: float | None = None  # of the last frame read (error messages)
        self._reader = open_reader(self.path, fmt)
        self.size_bytes = _file_size(self.path)

    # ---------------------------------------------------------------- progress
    def bytes_read(self) -> int | None:
        """Best-effort position in the (uncompressed) file for progress display."""
        f = getattr(self._reader, "file", None)
        for obj in (getattr(f, "buffer", None), f):
            try:
                return int(obj.tell())  # type: ignore[union-attr]  # None raises AttributeError, caught below
            except (AttributeError, OSError, ValueError, TypeError):
                continue
        return None

    # ---------------------------------------------------------------- iteration
    def __iter__(self) -> Iterator[tuple[int, can.Message]]:
        """(t_ns, msg) in timestamp order (within the re-order window), idle gaps shortened."""
        for chunk in self.chunks(CHUNK_FRAMES):
            yield from chunk

    def chunks(self, size: int) -> Iterator[list[tuple[int, can.Message]]]:
        """The frames of __iter__ in lists of `size` (the last one shorter; none empty): a
        consumer that takes them many at a time skips a generator step per frame."""
        with quiet_reader_logs():  # for as long as the file is read
            yield from self._frames(max(1, size))

    def _frames(self, size: int) -> Iterator[list[tuple[int, can.Message]]]:
        """Read, order and shorten in one loop (no generator per stage), `size` frames a list.

        While the file's times do not go backwards, the frames held for the re-order window
        wait in a FIFO (already in order, the heap's order too); the first frame that goes
        backwards turns the FIFO into the heap, which then holds them as before."""
        stats = self.stats
        window, idle_gap = self.window_ns, self.idle_gap_ns
        scale = NS_PER_S // TIME_RESOLUTION_NS
        fifo: deque[tuple[int, int, can.Message]] = deque()
        heap: list[tuple[int, int, can.Message]] = []
        pending: deque[tuple[int, int, can.Message]] | list[tuple[int, int, can.Message]] = fifo
        pop: Callable[[], tuple[int, int, can.Message]] = fifo.popleft  # pending's earliest
        released = -1  # t_ns (trace time) of the last frame handed out by the ordering (-1: none)
        prev_ts = -math.inf
        last: float = math.inf  # trace time of the last frame handed out (inf: none, no gap)
        skipped = 0
        seq = 0  # frames read
        ts = None
        t0 = None
        isfinite, floor = math.isfinite, math.floor
        out: list[tuple[int, can.Message]] = []
        append = out.append
        it = iter(self._reader)
        while True:
            try:
                msg = next(it)
            except StopIteration:
                break
            except Exception as exc:  # noqa: BLE001 - a corrupt file must not crash the run
                stats.frames_read, self._last_ts = seq, ts
                self.error = self._unreadable(exc)
                break
            ts = msg.timestamp
            if t0 is None:
                t0 = self.t0_s = ts if isfinite(ts) else 0.0
            if not isfinite(ts):
                stats.non_finite_time += 1
                t_ns = max(released, 0)
            else:
                if ts < prev_ts:
                    stats.out_of_order += 1
                prev_ts = ts
                t_ns = floor((ts - t0) * scale + 0.5) * TIME_RESOLUTION_NS  # _quantise
                if t_ns < 0:  # earlier than the first frame: deliver at the start
                    stats.late += 1
                    t_ns = 0
            if t_ns < released:
                stats.late += 1
                t_ns = released
            entry = (t_ns, seq, msg)
            seq += 1
            if pending is fifo:
                if fifo and t_ns < fifo[-1][0]:  # backwards: from now on the heap
                    heap = list(fifo)  # in order: a heap already
                    heapq.heappush(heap, entry)
                    pending, pop = heap, partial(heapq.heappop, heap)
                else:
                    fifo.append(entry)
            else:
                heapq.heappush(heap, entry)
            edge = t_ns - window
            while pending and pending[0][0] <= edge:
                released, _, out_msg = pop()
                if released - last > idle_gap:
                    skipped = self._gap(last, released, skipped)
                last = released
                append((released - skipped, out_msg))
            if len(out) >= size:
                stats.frames_read, self._last_ts = seq, ts
                yield out
                out = []
                append = out.append
        stats.frames_read, self._last_ts = seq, ts
        if self.error is None:
            self.error = self._truncation()
        if self.error is None and seq == 0 and self.size_bytes:  # a reader that skips lines
            self.error = (f"{self.path}: "
                          f"{not_a(trace_format(self.path, self.fmt), nothing_read=True)}")
        try:
            self._reader.stop()
        except Exception as exc:  # noqa: BLE001 - closing a reader that has failed may fail too
            log.debug("%s: closing the reader: %s", self.path, exc)
        rest = list(fifo) if pending is fifo else [heapq.heappop(heap) for _ in range(len(heap))]
        for released, _, out_msg in rest:
            if released - last > idle_gap:
                skipped = self._gap(last, released, skipped)
            last = released
            append((released - skipped, out_msg))
            if len(out) >= size:
                yield out
                out = []
                append = out.append
        if out:
            yield out

    def _gap(self, last: int, t_ns: int, skipped: int) -> int:
        """An idle gap from last to t_ns (trace time) shortened: recorded, new total skipped."""
        stats = self.stats
        gap = t_ns - last
        skipped += gap - self.idle_gap_ns
        stats.gaps += 1
        stats.skipped_ns = skipped
        stats.longest_gap_ns = max(stats.longest_gap_ns, gap)
        if len(stats.gap_list) < MAX_GAPS_LISTED:
            stats.gap_list.append((last, gap))
        self._gap_ends.append(t_ns - skipped)
        self._skipped_at.append(skipped)
        return skipped

    def _unreadable(self, exc: BaseException) -> str:
        """The read error in the user's words: not this format at all (nothing read), or
        where the readable part ends; python-can's own words at debug level only."""
        log.debug("%s: python-can's reader: %s", self.path, _one_line(exc))
        kind = trace_format(self.path, self.fmt)
        if self.stats.frames_read == 0:
            return f"{self.path}: {not_a(kind, self.size_bytes)}"
        name = FORMAT_NAMES.get(kind, f"a .{kind} file")
        return (f"{self.path}: unreadable after frame {self.stats.frames_read}{self._where()}: "
                f"the rest does not read as {name}")

    def _where(self) -> str:
        ts = self._last_ts
        return "" if ts is None else f" (last timestamp {ts:.6f} s)"

    def _truncation(self) -> str | None:
        """Files python-can reads without complaint although they were cut off."""
        path, suffix = self.path, Path(self.path).suffix.lower()
        fmt = self.fmt or suffix.lstrip(".")
        try:
            if fmt in LINE_TERMINATED and not path.endswith(".gz"):
                with open(path, "rb") as f:
                    f.seek(0, os.SEEK_END)
                    if f.tell() == 0:
                        return None
                    f.seek(-1, os.SEEK_END)
                    if f.read(1) not in (b"\n", b"\r"):
                        return (f"{path}: truncated: the last line is incomplete (after frame "
                                f"{self.stats.frames_read}{self._where()}, byte {f.tell()})")
            if fmt == "blf":
                declared = getattr(self._reader, "file_size", 0)
                actual = self.size_bytes
                if declared and actual is not None and actual < declared:
                    return (f"{path}: truncated: {actual} of {declared} bytes the BLF header "
                            f"declares (after frame {self.stats.frames_read}{self._where()})")
        except OSError as exc:
            return f"{path}: {_one_line(exc)}"
        return None

    def skipped_before(self, t_ns: int) -> int:
        """Idle time skipped before t_ns (replay time base): t_ns + this is the trace's time."""
        i = bisect_right(self._gap_ends, t_ns)
        return self._skipped_at[i - 1] if i else 0


def _quantise(dt_s: float) -> int:
    """Seconds -> ns, rounded to the nearest TIME_RESOLUTION_NS (half up)."""
    return math.floor(dt_s * (NS_PER_S // TIME_RESOLUTION_NS) + 0.5) * TIME_RESOLUTION_NS


def _file_size(path: str) -> int | None:
    try:
        return os.path.getsize(path)
    except OSError:
        return None
