"""The replay's feeder: the scheduler task that hands the trace's frames to the ECU (fast mode,
in blocks: vecu.codec.blocks) or plays them onto a bus (live mode), and the tally of what became
of each frame."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass, field
from itertools import islice

import can

from vecu.clock import WallClock
from vecu.codec import BlockChecks, DbcCodec, FrameCodec
from vecu.ecu.node import EcuNode, Route
from vecu.replay.scoring import TruthScorer
from vecu.replay.source import TraceSource
from vecu.stats import DurationHistogram

log = logging.getLogger(__name__)

SCHEDULE_ERROR_LIMIT_US = 200_000  # 1 us bins up to 200 ms; beyond: counted, max kept
# frames read (and, fast, checked per message in blocks) at a time: 16 k was no faster (up to ~5 %
# slower in same-run comparisons: the chunk's objects no longer in the caches)
CHUNK = 2048
# ... and without blocks (live): reading thousands of frames holds the GIL for ms, a stall of the
# player thread's schedule; a few frames at a time spread the reader's cost between sends
SMALL_CHUNK = 16


@dataclass
class FrameTally:
    """What happened to each frame of the trace (each lands in exactly one of the bins)."""

    truth: int = 0           # debug truth frames (scoring)
    decoded_other: int = 0   # known to the trace's database, not an ECU input, decoded fine
    decode_errors: dict[str, int] = field(default_factory=dict)  # known, not decodable: reason



# what the block path does with a frame (Feeder._load)
_TO_ECU, _TRUTH, _COPY = 0, 1, 2


class Feeder:
    """Scheduler chain task: hands every frame due by now to the ECU (fast) or the bus (live).

    With `block` (fast mode) the trace is read CHUNK frames at a time (TraceSource.chunks) and
    each chunk is sorted out at once: the frames known to the trace's database that neither
    feed the ECU nor are truth frames are tallied there and then (and, without `copy_to`, not
    handed on at all); the ECU's input frames and the truth frames are checked and decoded per
    message in blocks (numpy, FrameCodec.check_block) and handed over one by one at their times,
    in trace order, as frame by frame. Without `block` (live, and the reference of the block
    path), frames go one by one, SMALL_CHUNK read at a time."""

    def __init__(self, source: TraceSource, ecu: EcuNode, db: DbcCodec, scorer: TruthScorer,
                 tally: FrameTally, routes: dict[tuple[int, bool], Route],
                 copy_to: can.Listener | None, block: bool = False,
                 player: can.BusABC | None = None, speed: float = 1.0,
                 clock: WallClock | None = None, until_ns: int | None = None) -> None:
        """Live (player given): every frame is sent onto `player` at `speed` times its recorded
        pace, its schedule error measured on `clock` (the player's time base); else the frames
        are handed to the ECU. until_ns: the trace ends after its frames up to this time."""
        self.block = block and player is None
        self.source, self.ecu, self.db, self.scorer, self.tally = source, ecu, db, scorer, tally
        self.routes = routes
        self.copy_to = copy_to
        self.done = False
        self.last_ns = 0
        self.player = player
        self.speed = speed
        self.clock = clock
        self.until_ns = until_ns
        self.schedule_error = DurationHistogram(limit_us=SCHEDULE_ERROR_LIMIT_US)
        self._i = 0
        self._sorting: dict[tuple[int, bool], tuple[int, FrameCodec | None]] = {}  # _sort's
        if self.block:
            self._chunks: Iterator[list[tuple[int, can.Message]]] | None = source.chunks(CHUNK)
            # per frame handed on: its time, message, what to do, its block's checks, place
            self._times: list[int] = []
            self._msgs: list[can.Message] = []
            self._kinds: list[int] = []
            self._checks: list[BlockChecks | None] = []
            self._at: list[int] = []
            if not self._load():
                self._finish()
            return
        self.frames: Iterator[tuple[int, can.Message]] = iter(source)
        self._buf: list[tuple[int, can.Message]] = []
        self._i = -1
        self._pending = self._next()
        if self._pending is None:
            self.done = True

    # ------------------------------------------------------------ where a frame goes (both paths)
    def _sort(self, key: tuple[int, bool]) -> tuple[int, FrameCodec | None]:
        """What becomes of a (non-error, non-remote) frame with this key, and the codec that
        checks it: its block's (truth, ECU input; None: one by one) or its database's (other)."""
        truth, routes = self.scorer.truth_codecs, self.routes
        if key in truth or key in routes:
            fc = truth[key] if key in truth else routes[key].codec
            return (_TRUTH if key in truth else _TO_ECU), (fc if fc.block is not None else None)
        if key in self.db.by_id:
            return _COPY, self.db.by_id[key]
        return _TO_ECU, None  # unknown: the ECU counts it

    def _kind(self, msg: can.Message) -> tuple[int, FrameCodec | None]:
        """_sort of msg's key (looked up once per key); error and remote frames go to the ECU."""
        if msg.is_error_frame or msg.is_remote_frame:
            return _TO_ECU, None
        key = (msg.arbitration_id, msg.is_extended_id)
        got = self._sorting.get(key)
        if got is None:
            got = self._sorting[key] = self._sort(key)
        return got

    def _count_other(self, fc: FrameCodec, data: bytes | bytearray) -> None:
        """A frame the database knows that neither feeds the ECU nor is truth: tallied as
        decoded or by why it does not decode."""
        tally = self.tally
        reason = "dlc" if len(data) != fc.length else fc.decode_problem(data)
        if reason is None:
            tally.decoded_other += 1
        else:
            tally.decode_errors[reason] = tally.decode_errors.get(reason, 0) + 1

    # ------------------------------------------------------------ block path (fast)
    def _load(self) -> bool:
        """Sort out the next chunk that has frames to hand on (False: the trace has ended)."""
        copy = self.copy_to is not None
        kind_of, count_other = self._kind, self._count_other
        while self._chunks is not None:
            buf = next(self._chunks, None)
            if buf is not None and self.until_ns is not None and buf[-1][0] > self.until_ns:
                buf = [f for f in buf if f[0] <= self.until_ns]  # the frames are in time order
                self._chunks = None
            if not buf:
                self._chunks = None
                return False
            self.last_ns = buf[-1][0]
            times: list[int] = []
            msgs: list[can.Message] = []
            kinds: list[int] = []
            groups: dict[FrameCodec, tuple[list[int], list[bytearray]]] = {}
            for t_ns, msg in buf:
                kind, fc = kind_of(msg)
                if kind == _COPY:  # known, not an input: count whether it decodes
                    count_other(fc, msg.data)  # type: ignore[arg-type]  # _COPY: a codec
                    if not copy:
                        continue
                elif fc is not None and len(msg.data) == fc.length:
                    group = groups.get(fc)
                    if group is None:
                        group = groups[fc] = ([], [])
                    group[0].append(len(times))
                    group[1].append(msg.data)
                times.append(t_ns)
                msgs.append(msg)
                kinds.append(kind)
            if not times:
                continue
            checks: list[BlockChecks | None] = [None] * len(times)
            at = [0] * len(times)
            for fc, (index, payloads) in groups.items():
                block = fc.check_block(payloads)
                for j, i in enumerate(index):
                    checks[i] = block
                    at[i] = j
            self._times, self._msgs, self._kinds, self._checks, self._at = (
                times, msgs, kinds, checks, at)
            self._i = 0
            return True
        return False

    def _finish(self) -> None:
        self.done = True
        self._chunks = None

    def _release_block(self, now_ns: int) -> int | None:
        i, times = self._i, self._times
        msgs, kinds, checks, at = self._msgs, self._kinds, self._checks, self._at
        receive, on_truth, tally, copy_to = (self.ecu.receive, self.scorer.on_truth, self.tally,
                                             self.copy_to)
        while True:
            if i >= len(times):
                if not self._load():
                    self._finish()
                    return None
                i, times = 0, self._times
                msgs, kinds, checks, at = self._msgs, self._kinds, self._checks, self._at
            t_ns = times[i]
            if t_ns > now_ns:
                self._i = i
                return max(now_ns + 1, t_ns)
            msg, kind, block = msgs[i], kinds[i], checks[i]
            if kind == _TO_ECU:  # its rx counters: accepted / ignored / why not
                receive(msg, t_ns, block[at[i]] if block is not None else None)
            elif kind == _TRUTH:
                tally.truth += 1
                on_truth(msg, t_ns, block[at[i]][1] if block is not None else None)
            if copy_to is not None:
                copy_to.on_message_received(msg)
            i += 1

    # ------------------------------------------------------------ frame by frame (live)
    def _next(self) -> tuple[int, can.Message] | None:
        """The next frame of the trace (reading the next few as needed)."""
        i = self._i + 1
        if i >= len(self._buf):
            self._buf = list(islice(self.frames, SMALL_CHUNK))
            i = 0
            if not self._buf:
                self._i = 0
                return None
        self._i = i
        frame = self._buf[i]
        if self.until_ns is not None and frame[0] > self.until_ns:
            return None
        return frame

    def release(self, now_ns: int) -> int | None:
        """Hand on (or send) every frame due by now_ns; the time of the next one (None: end)."""
        if self.block:
            return self._release_block(now_ns)
        pending = self._pending
        live = self.player is not None
        while pending is not None:
            t_ns, msg = pending
            due = int(t_ns / self.speed) if live else t_ns
            if due > now_ns:
                break
            if live:
                self._send_live(msg, due)
            else:
                self._deliver(msg, t_ns)
            if self.copy_to is not None:
                self.copy_to.on_message_received(msg)
            self.last_ns = t_ns
            pending = self._next()
        self._pending = pending
        if pending is None:
            self.done = True
            return None
        return max(now_ns + 1, int(pending[0] / self.speed) if live else pending[0])

    def _deliver(self, msg: can.Message, t_ns: int) -> None:
        """One frame to where _sort sends it (the block path's, one by one)."""
        kind, fc = self._kind(msg)
        if kind == _TRUTH:
            self.tally.truth += 1
            self.scorer.on_truth(msg, t_ns, None)
        elif kind == _TO_ECU:
            self.ecu.receive(msg, t_ns, None)  # its rx counters: accepted / ignored / why not
        else:
            self._count_other(fc, msg.data)  # type: ignore[arg-type]  # _COPY: a codec

    def _send_live(self, msg: can.Message, due_ns: int) -> None:
        assert self.player is not None and self.clock is not None
        try:
            self.player.send(msg)
        except can.CanError as exc:
            self.tally.decode_errors["send_failed"] = self.tally.decode_errors.get(
                "send_failed", 0) + 1
            log.warning("replay: send failed: %s", exc)
        self.schedule_error.record(self.clock.now_ns() - due_ns)
