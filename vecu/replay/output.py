"""The replay's `--out` trace: a python-can Logger that counts frames (locked in a live
replay), and the ECU's frames handed to it as an estimate sink, back on the trace's time base."""

from __future__ import annotations

import threading

import can

from vecu.can_message import Values
from vecu.clock import NS_PER_S
from vecu.recorder import TraceWriteError
from vecu.replay.source import TraceSource

OUT_CHANNEL = "vecu"  # channel name of the ECU's frames in --out


class OutputWriter(can.Listener):
    """The --out writer: counts frames; locked in a live replay, where the player thread copies
    inputs and the ECU thread writes estimates."""

    def __init__(self, inner: can.Listener, locked: bool) -> None:
        self.inner = inner
        self.lock = threading.Lock() if locked else None
        self.frames = 0

    def on_message_received(self, msg: can.Message) -> None:
        if self.lock is None:
            self.inner.on_message_received(msg)
            self.frames += 1
        else:
            with self.lock:
                self.inner.on_message_received(msg)
                self.frames += 1

    def stop(self) -> None:
        self.inner.stop()


class EstimateOut:
    """The --out writer as an estimate sink (vecu.bus.EstimateSink): each frame the ECU sends
    (and, with --gateway, each routed frame: write), back on the trace's time base (its skipped
    idle time too; live: the ECU's time times the speed), on `channel` unless it names its own."""

    def __init__(self, writer: OutputWriter | None, source: TraceSource, speed: float | None,
                 channel: str) -> None:
        self.writer, self.source, self.speed, self.channel = writer, source, speed, channel

    def on_estimate(self, values: Values | None, msg: can.Message, t_ns: int) -> None:
        self.write(msg, t_ns)

    def write(self, msg: can.Message, t_ns: int) -> None:
        if self.writer is None:
            return
        source, speed = self.source, self.speed
        skipped = source.skipped_before(int(t_ns * speed) if speed is not None else t_ns)
        msg.timestamp += (source.t0_s or 0.0) + skipped / NS_PER_S
        if msg.channel is None:
            msg.channel = self.channel
        self.writer.on_message_received(msg)


def open_writer(path: str | None, locked: bool) -> OutputWriter | None:
    if path is None:
        return None
    try:
        return OutputWriter(can.Logger(path), locked)
    except (ValueError, OSError, ImportError) as exc:
        raise TraceWriteError(path, f"cannot write: {exc}") from exc
