"""The replay's feeder: the scheduler task that hands the trace's frames to the ECU (fast mode,
in blocks: vecu.block_codec) or plays them onto a bus (live mode), and the tally of what became
of each frame."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass, field
from itertools import islice

import can

from vecu.block_codec import BlockChecks
from vecu.clock import WallClock
from vecu.codec import DbcCodec, FrameCodec
from vecu.ecu.node import Checked, EcuNode, Route
from vecu.replay.scoring import TruthScorer
from vecu.replay.source import TraceSource
from vecu.stats import DurationHistogram

log = logging.getLogger(__name__)

SCHEDULE_ERROR_LIMIT_US = 200_000  # 1 us bins up to 200 ms; beyond: counted, max kept
CHUNK = 16384  # frames read (and, fast, checked per message in blocks) at a time
# ... and without blocks (live): reading 16 k frames holds the GIL ~50-100 ms, a stall of the
# player thread's schedule; a few frames at a time spread the reader's cost between sends
SMALL_CHUNK = 16


@dataclass
class FrameTally:
    """What happened to each frame of the trace (each lands in exactly one of the bins)."""

    truth: int = 0           # debug truth frames (scoring)
    decoded_other: int = 0   # known to the trace's database, not an ECU input, decoded fine
    decode_errors: dict[str, int] = field(default_factory=dict)  # known, not decodable: reason



class Feeder:
    """Scheduler chain task: hands every frame due by now to the ECU (fast) or the bus (live).

    Frames are read CHUNK at a time with `block` (fast mode): the ECU's input frames and the
    truth frames of each chunk are checked and decoded per message in blocks (numpy,
    FrameCodec.check_block) before they are handed over one by one, in trace order, as before.
    Without (live), SMALL_CHUNK at a time."""

    def __init__(self, source: TraceSource, ecu: EcuNode, db: DbcCodec, scorer: TruthScorer,
                 tally: FrameTally, routes: dict[tuple[int, bool], Route],
                 copy_to: can.Listener | None, block: bool = False,
                 player: can.BusABC | None = None, speed: float = 1.0,
                 clock: WallClock | None = None, until_ns: int | None = None) -> None:
        """Live (player given): every frame is sent onto `player` at `speed` times its recorded
        pace, its schedule error measured on `clock` (the player's time base); else the frames
        are handed to the ECU. until_ns: the trace ends after its frames up to this time."""
        self.frames: Iterator[tuple[int, can.Message]] = iter(source)
        self.block = block
        self._chunk = CHUNK if block else SMALL_CHUNK
        self._buf: list[tuple[int, can.Message]] = []
        self._checks: list[BlockChecks | None] = []  # per frame of _buf: its block's checks
        self._at: list[int] = []  # and its place in that block
        self._i = -1
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
        self._pending = self._next()
        if self._pending is None:
            self.done = True

    def _next(self) -> tuple[int, can.Message] | None:
        """The next frame of the trace (reading and block-checking the next chunk as needed)."""
        i = self._i + 1
        if i >= len(self._buf):
            self._buf = list(islice(self.frames, self._chunk))
            if self.block:
                self._checks, self._at = self._check_block(self._buf)
            i = 0
            if not self._buf:
                self._i = 0
                return None
        self._i = i
        frame = self._buf[i]
        if self.until_ns is not None and frame[0] > self.until_ns:
            return None
        return frame

    def _check_block(self, buf: list[tuple[int, can.Message]]
                     ) -> tuple[list[BlockChecks | None], list[int]]:
        """Per frame of buf: the checks of its message's block and its place in it, for ECU
        inputs and truth frames of their message's length; None for the others (checked one
        by one when delivered)."""
        groups: dict[tuple[int, bool], tuple[FrameCodec | None, list[int], list[bytearray]]] = {}
        truth, routes = self.scorer.truth_codecs, self.routes
        for i, (_, msg) in enumerate(buf):
            key = (msg.arbitration_id, msg.is_extended_id)
            group = groups.get(key)
            if group is None:
                fc = truth[key] if key in truth else (routes[key].codec if key in routes
                                                      else None)
                group = groups[key] = (fc if fc is not None and fc.block is not None else None,
                                       [], [])
            fc = group[0]
            if fc is not None and len(msg.data) == fc.length and not (
                    msg.is_error_frame or msg.is_remote_frame):
                group[1].append(i)
                group[2].append(msg.data)
        checks: list[BlockChecks | None] = [None] * len(buf)
        at = [0] * len(buf)
        for fc, index, payloads in groups.values():
            if index:
                block = fc.check_block(payloads)  # type: ignore[union-attr]  # index set: a block-capable codec
                for j, i in enumerate(index):
                    checks[i] = block
                    at[i] = j
        return checks, at

    def release(self, now_ns: int) -> int | None:
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
                block = self._checks[self._i] if self.block else None
                self._deliver(msg, t_ns, block[self._at[self._i]] if block is not None else None)
            if self.copy_to is not None:
                self.copy_to.on_message_received(msg)
            self.last_ns = t_ns
            pending = self._next()
        self._pending = pending
        if pending is None:
            self.done = True
            return None
        return max(now_ns + 1, int(pending[0] / self.speed) if live else pending[0])

    def _deliver(self, msg: can.Message, t_ns: int, checked: Checked | None = None) -> None:
        key = (msg.arbitration_id, msg.is_extended_id)
        tally = self.tally
        if key in self.scorer.truth_ids and not msg.is_error_frame and not msg.is_remote_frame:
            tally.truth += 1
            self.scorer.on_truth(msg, t_ns, checked[1] if checked is not None else None)
            return
        if key in self.routes or key not in self.db.by_id or msg.is_error_frame \
                or msg.is_remote_frame:
            self.ecu.receive(msg, t_ns, checked)  # its rx counters: accepted / ignored / why not
            return
        fc = self.db.by_id[key]  # known, not an input: count whether it decodes
        data = msg.data
        reason = "dlc" if len(data) != fc.length else fc.decode_problem(data)
        if reason is None:
            tally.decoded_other += 1
        else:
            tally.decode_errors[reason] = tally.decode_errors.get(reason, 0) + 1

    def _send_live(self, msg: can.Message, due_ns: int) -> None:
        assert self.player is not None and self.clock is not None
        try:
            self.player.send(msg)
        except can.CanError as exc:
            self.tally.decode_errors["send_failed"] = self.tally.decode_errors.get(
                "send_failed", 0) + 1
            log.warning("replay: send failed: %s", exc)
        self.schedule_error.record(self.clock.now_ns() - due_ns)
