"""Trace recorder: a python-can bus drained into a python-can writer chosen by file suffix."""

from __future__ import annotations

import importlib
from pathlib import PurePath

import can

from vecu.errors import BadFileError, UnavailableError

MF4_HINT = "writing .mf4 needs the asammdf package: pip install 'vecu[mf4]'"


class TraceWriteError(BadFileError):
    """The log file cannot be written: TraceWriteError(path, problem)."""


TIME_RESOLUTION_NS = 1_000  # 1 us: the time resolution every trace format keeps (docs/replay.md)
TICK_GRID_NS = 1_000_000  # the ECU's 1 ms ticks on a simulated run's time base


def record_stamp(t_s: float, before_ns: int | None = None) -> float:
    """A frame's timestamp as recorded: at 1 us (so every format stores the same time), on the
    same side of every ECU tick as the frame itself. Rounded to the nearest us, except that a frame
    sent just after a tick is not stamped on it (the ECU's next tick took it, not that one: +1 us),
    and a frame sent before `before_ns` (the end of a run, where no tick followed) stays before it
    (-1 us). A replay then hands every frame to the same ECU tick as the live run did."""
    t_ns = round(t_s * 1e9)
    q = (t_ns + TIME_RESOLUTION_NS // 2) // TIME_RESOLUTION_NS * TIME_RESOLUTION_NS
    if q < t_ns and q % TICK_GRID_NS == 0:
        q += TIME_RESOLUTION_NS
    if before_ns is not None and t_ns < before_ns <= q:
        q = before_ns - TIME_RESOLUTION_NS
    return q / 1e9


def writer_suffixes() -> list[str]:
    """The suffixes python-can writes here (with the dot), e.g. ['.asc', '.blf', …]."""
    logger = can.io.logger
    if hasattr(logger, "_update_writer_plugins"):
        logger._update_writer_plugins()
    return sorted(getattr(logger, "MESSAGE_WRITERS", {}))


def check_log_path(path: str) -> None:
    """Raise before anything is opened when python-can has no writer for path's suffix (python-can's
    rule: the last suffix, or the one before .gz), or when the writer's package is missing (asammdf
    for .mf4): TraceWriteError or UnavailableError, one line."""
    writers = writer_suffixes()
    known = f"python-can writes {', '.join(writers)}, and .gz of the text formats"
    suffixes = [s.lower() for s in PurePath(path).suffixes]
    suffix = suffixes[-1] if suffixes else ""
    if suffix == ".gz":
        inner = suffixes[-2] if len(suffixes) == 2 else ""
        cls = can.io.logger.MESSAGE_WRITERS.get(inner) if inner not in (".blf", ".db") else None
        if cls is None or not issubclass(cls, (can.io.generic.BinaryIOMessageWriter,
                                               can.io.generic.TextIOMessageWriter)):
            raise TraceWriteError(path, f"cannot write log: no compressed format named like this "
                                        f"({known}, e.g. trace.log.gz)")
        suffix = inner
    if suffix not in writers:
        raise TraceWriteError(path, f"cannot write log: unknown format {suffix!r} ({known})"
                              if suffix else f"cannot write log: no suffix to tell the format ({known})")
    if suffix == ".mf4":
        try:
            importlib.import_module("asammdf")
        except ImportError:
            raise UnavailableError(f"{path}: {MF4_HINT}") from None


class Recorder:
    """Listens on its own bus (like candump) and writes every frame with python-can's Logger.

    Any suffix python-can knows works (.log, .asc, .blf, .csv, .trc, .mf4 with asammdf, .gz).
    close() flushes and closes the file and is safe to call on every exit path.
    """

    def __init__(self, bus: can.BusABC, path: str) -> None:
        self.bus = bus
        self.path = path
        check_log_path(path)
        try:
            self._writer = can.Logger(path)
        except NotImplementedError as exc:  # python-can's word for a missing optional package
            raise UnavailableError(f"{path}: cannot write log: {exc}") from exc
        except (ValueError, OSError, ImportError) as exc:
            raise TraceWriteError(path, f"cannot write log: {exc}") from exc
        self.frames = 0
        self._closed = False

    def drain(self, t_ns: int = 0, before_ns: int | None = None) -> None:
        """Write every frame received so far, stamped by record_stamp(); before_ns: the end of
        the run (these frames were sent after the ECU's last tick)."""
        recv = self.bus.recv
        write = self._writer.on_message_received
        while (msg := recv(0.0)) is not None:
            if msg.timestamp is not None:
                msg.timestamp = record_stamp(msg.timestamp, before_ns)
            write(msg)
            self.frames += 1

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._writer.stop()
