"""Trace recorder: a python-can bus drained into a python-can writer chosen by file suffix."""

from __future__ import annotations

import can

from vecu.errors import BadFileError


class TraceWriteError(BadFileError):
    """The log file cannot be written: TraceWriteError(path, problem)."""


class Recorder:
    """Listens on its own bus (like candump) and writes every frame with python-can's Logger.

    Any suffix python-can knows works (.log, .asc, .blf, .csv, .trc, .mf4 with asammdf, .gz).
    close() flushes and closes the file and is safe to call on every exit path.
    """

    def __init__(self, bus: can.BusABC, path: str) -> None:
        self.bus = bus
        self.path = path
        try:
            self._writer = can.Logger(path)
        except (ValueError, OSError, ImportError) as exc:
            raise TraceWriteError(path, f"cannot write log: {exc}") from exc
        self.frames = 0
        self._closed = False

    def drain(self, t_ns: int = 0) -> None:
        recv = self.bus.recv
        write = self._writer.on_message_received
        while (msg := recv(0.0)) is not None:
            write(msg)
            self.frames += 1

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._writer.stop()
