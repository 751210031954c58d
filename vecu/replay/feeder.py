"""The replay's feeder: the scheduler task that hands the trace's frames to the ECU (fast mode,
checked in blocks: FrameCodec.check_block, vecu.codec.blocks) or plays them onto a bus (live
mode), and the tally of what became of each frame."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass, field

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



# what the feeder does with a frame (Feeder._load)
_TO_ECU, _TRUTH, _COPY = 0, 1, 2


class Feeder:
    """Scheduler chain task: hands every frame due by now to the ECU (fast) or the bus (live).

    One path either way: the trace is read a chunk at a time (TraceSource.chunks; CHUNK frames
    fast, SMALL_CHUNK live) and each chunk is sorted out at once (_load), then its frames are
    released one by one at their times, in trace order (release).

    Fast: the frames known to the trace's database that neither feed the ECU nor are truth
    frames are tallied there and then (and, without `copy_to`, not handed on at all); the ECU's
    input frames and the truth frames are checked and decoded per message in blocks (numpy,
    FrameCodec.check_block; `checks` below) and handed over with their block's row. Live: every
    frame is sent onto the player bus unsorted (the ECU reads it from its own bus)."""

    def __init__(self, source: TraceSource, ecu: EcuNode, db: DbcCodec, scorer: TruthScorer,
                 tally: FrameTally, routes: dict[tuple[int, bool], Route],
                 copy_to: can.Listener | None,
                 player: can.BusABC | None = None, speed: float = 1.0,
                 clock: WallClock | None = None) -> None:
        """Live (player given): every frame is sent onto `player` at `speed` times its recorded
        pace, its schedule error measured on `clock` (the player's time base); else the frames
        are handed to the ECU."""
        self.source, self.ecu, self.db, self.scorer, self.tally = source, ecu, db, scorer, tally
        self.routes = routes
        self.copy_to = copy_to
        self.done = False
        self.last_ns = 0
        self.player = player
        self.live = player is not None
        self.speed = speed
        self.clock = clock
        self.schedule_error = DurationHistogram(limit_us=SCHEDULE_ERROR_LIMIT_US)
        self._sorting: dict[tuple[int, bool], tuple[int, FrameCodec | None]] = {}  # _sort's
        self.unknown_ids: set[tuple[int, bool]] = set()  # keys in no database (fast mode)
        self._chunks: Iterator[list[tuple[int, can.Message]]] | None = source.chunks(
            SMALL_CHUNK if self.live else CHUNK)
        # per frame handed on: its time (live: its due time), message, what to do, its block's
        # checks, place in the block
        self._i = 0
        self._times: list[int] = []
        self._msgs: list[can.Message] = []
        self._kinds: list[int] = []
        self._checks: list[BlockChecks | None] = []
        self._at: list[int] = []
        if not self._load():
            self._finish()

    # ------------------------------------------------------------ where a frame goes
    def _sort(self, key: tuple[int, bool]) -> tuple[int, FrameCodec | None]:
        """What becomes of a (non-error, non-remote) frame with this key, and the codec that
        checks it: its block's (truth, ECU input; None: one by one) or its database's (other)."""
        truth, routes = self.scorer.truth_codecs, self.routes
        if key in truth or key in routes:
            fc = truth[key] if key in truth else routes[key].codec
            return (_TRUTH if key in truth else _TO_ECU), (fc if fc.block is not None else None)
        if key in self.db.by_id:
            return _COPY, self.db.by_id[key]
        self.unknown_ids.add(key)
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

    def checks(self, fc: FrameCodec, payloads: list[bytearray]) -> BlockChecks | None:
        """The block checks of a chunk's payloads of one message (fc.check_block)."""
        return fc.check_block(payloads)

    # ------------------------------------------------------------ reading
    def _load(self) -> bool:
        """Sort out the next chunk that has frames to hand on (False: the trace has ended)."""
        copy, live = self.copy_to is not None, self.live
        kind_of, count_other, speed = self._kind, self._count_other, self.speed
        while self._chunks is not None:
            buf = next(self._chunks, None)
            if not buf:
                self._chunks = None
                return False
            self.last_ns = buf[-1][0]
            if live:  # all onto the player bus at their due times
                self._times = [int(t_ns / speed) for t_ns, _ in buf]
                self._msgs = [msg for _, msg in buf]
                self._i = 0
                return True
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
                block = self.checks(fc, payloads)
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

    # ------------------------------------------------------------ releasing
    def release(self, now_ns: int) -> int | None:
        """Hand on (or send) every frame due by now_ns; the time of the next one (None: end)."""
        i, times, msgs = self._i, self._times, self._msgs
        kinds, checks, at = self._kinds, self._checks, self._at
        live = self.live
        receive, on_truth, tally, copy_to = (self.ecu.receive, self.scorer.on_truth, self.tally,
                                             self.copy_to)
        while True:
            if i >= len(times):
                if not self._load():
                    self._finish()
                    return None
                i, times, msgs = 0, self._times, self._msgs
                kinds, checks, at = self._kinds, self._checks, self._at
            t_ns = times[i]
            if t_ns > now_ns:
                self._i = i
                return max(now_ns + 1, t_ns)
            msg = msgs[i]
            if live:
                self._send_live(msg, t_ns)
            else:
                kind, block = kinds[i], checks[i]
                if kind == _TO_ECU:  # its rx counters: accepted / ignored / why not
                    receive(msg, t_ns, block[at[i]] if block is not None else None)
                elif kind == _TRUTH:
                    tally.truth += 1
                    on_truth(msg, t_ns, block[at[i]][1] if block is not None else None)
            if copy_to is not None:
                copy_to.on_message_received(msg)
            i += 1

    def _send_live(self, msg: can.Message, due_ns: int) -> None:
        assert self.player is not None and self.clock is not None
        try:
            self.player.send(msg)
        except can.CanError as exc:
            self.tally.decode_errors["send_failed"] = self.tally.decode_errors.get(
                "send_failed", 0) + 1
            log.warning("replay: send failed: %s", exc)
        self.schedule_error.record(self.clock.now_ns() - due_ns)
