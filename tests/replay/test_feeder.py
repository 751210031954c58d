"""The replay feeder's reading (vecu.replay.feeder): fast mode reads and checks the trace a
large chunk at a time; live mode reads a few frames at a time, so that reading never holds the
player thread for long (a 16 k-frame read held it ~100 ms: live replay's schedule error p99 went
from ~0.7 ms to ~100 ms)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from vecu.replay.feeder import CHUNK, SMALL_CHUNK, Feeder, FrameTally
from vecu.replay.source import TraceSource

TRACE = Path(__file__).resolve().parents[2] / "traces" / "drive_tps_dead.blf"


class CountingSource:
    """A real TraceSource, counting the frames taken from it."""

    def __init__(self, path: Path) -> None:
        self.source = TraceSource(path)
        self.taken = 0

    def chunks(self, size: int) -> Iterator[list]:
        for chunk in self.source.chunks(size):
            self.taken += len(chunk)
            yield chunk


def test_live_feeding_reads_a_few_frames_ahead_not_a_whole_chunk():
    src = CountingSource(TRACE)
    feeder = Feeder(src, None, None, None, FrameTally(), {}, None, player=object())  # type: ignore[arg-type]  # live: only the source is used before the first release
    assert not feeder.done
    total = sum(1 for _ in TraceSource(TRACE))
    assert total > 2 * SMALL_CHUNK
    # the first few frames (a chunk of about SMALL_CHUNK), not min(CHUNK, total)
    assert SMALL_CHUNK <= src.taken <= 2 * SMALL_CHUNK
    assert SMALL_CHUNK <= 64 < CHUNK
