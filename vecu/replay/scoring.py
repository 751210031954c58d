"""Score a trace from frames alone: the ECU's estimate frames against the plant's debug truth
frames (vecu/dbc/vecu_truth.dbc) recorded in the same trace.

Pairing: an estimate at time t is compared with the newest truth frame at or before t, if that
truth is at most one period of its message old (each function's TruthChannel in its registry
entry, vecu.functions: its max_age_ns). Estimates without truth are counted as unmatched, not
scored. Estimates their validity signal (TruthChannel.validity, vecu.ecu.validity) flags init or
invalid are counted (`not_valid_estimates`), not scored: the ECU said they mean nothing.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import can

from vecu import functions
from vecu.codec import DbcCodec, FrameCodec
from vecu.ecu.validity import SCORED
from vecu.functions.base import TruthChannel
from vecu.replay.summary import ReplayScore, ScoreSection
from vecu.stats import RunningStats

PENDING = 4096  # estimate frames of one message decoded and scored at a time


def channels() -> list[tuple[str, TruthChannel]]:
    """(function, its truth channel) of every registered function that has one."""
    return [(spec.name, spec.truth) for spec in functions.specs() if spec.truth is not None]


class TruthScorer:
    """Feed truth frames with on_truth() as they are read and ECU estimate frames with
    on_estimate() as they are sent; summary() gives error statistics per function."""

    def __init__(self, codec: DbcCodec, keep_series: bool = False) -> None:
        # per channel rows (t_s, estimate, truth or NaN) of its first pair, for plots
        self.channels = channels()
        self._group = {ch.estimate: name for name, ch in self.channels}
        self.series: dict[str, list[tuple[float, float, float]]] | None = (
            {name: [] for name, _ in self.channels} if keep_series else None)
        self._truth_codecs: dict[tuple[int, bool], FrameCodec] = {}
        self._est: dict[tuple[int, bool], tuple[FrameCodec, TruthChannel]] = {}
        # messages that carry another estimate message's validity: (codec, its signal)
        self._validity_msgs: dict[tuple[int, bool], tuple[FrameCodec, str]] = {}
        self._validity: dict[str, int] = {}  # validity message -> its latest validity
        for _, ch in self.channels:
            if ch.truth in codec and ch.estimate in codec:
                t, e = codec[ch.truth], codec[ch.estimate]
                self._truth_codecs[(t.frame_id, t.is_extended)] = t
                self._est[(e.frame_id, e.is_extended)] = (e, ch)
                v = ch.validity
                if v is not None and v[0] != ch.estimate and v[0] in codec:
                    vc = codec[v[0]]
                    self._validity_msgs[(vc.frame_id, vc.is_extended)] = (vc, v[1])
        self.truth_ids = frozenset(self._truth_codecs)
        self.truth_codecs: Mapping[tuple[int, bool], FrameCodec] = self._truth_codecs
        self._latest: dict[str, tuple[int, dict[str, float]]] = {}
        self.stats = {ch.estimate: {p.key: RunningStats() for p in ch.pairs}
                      for _, ch in self.channels}
        self.unmatched = {ch.estimate: 0 for _, ch in self.channels}
        self.not_valid = {ch.estimate: 0 for _, ch in self.channels}
        self.truth_frames = 0
        self.bad_truth_frames = 0
        # per estimate message, its frames not scored yet: (t_ns, payload, the truth values
        # paired with it or None, scored?, the validity another message gave it)
        self._pending: dict[str, list[tuple[int, bytearray, dict[str, float] | None, bool,
                                            int | None]]] = {
            ch.estimate: [] for _, ch in self.channels}

    @property
    def active(self) -> bool:
        return self.truth_frames > 0

    def on_truth(self, msg: can.Message, t_ns: int,
                 values: dict[str, float] | None = None) -> None:
        """A truth frame; `values`: its decoded values when the caller decoded it already."""
        fc = self._truth_codecs[(msg.arbitration_id, msg.is_extended_id)]
        if values is None:
            try:
                values = fc.decode(msg.data)
            except Exception:  # noqa: BLE001 - a corrupt truth frame is counted, not fatal
                self.bad_truth_frames += 1
                return
        self.truth_frames += 1
        self._latest[fc.name] = (t_ns, values)

    def on_estimate(self, msg: can.Message, t_ns: int) -> None:
        """An estimate frame sent at t_ns: paired now with the newest truth (and validity), its
        payload decoded and scored later, PENDING at a time per message (flush())."""
        if not self.truth_frames and self.series is None:
            return
        key = (msg.arbitration_id, msg.is_extended_id)
        entry = self._est.get(key)
        if entry is None:
            flag = self._validity_msgs.get(key)
            if flag is not None:
                self._validity[flag[0].name] = int(flag[0].decode(msg.data)[flag[1]])
            return
        fc, ch = entry
        latest = self._latest.get(ch.truth)
        matched = latest is not None and 0 <= t_ns - latest[0] <= ch.max_age_ns
        scored = matched and t_ns >= ch.burn_in_ns  # matched: truth frames seen
        if self.truth_frames and not matched:
            self.unmatched[ch.estimate] += 1
        if not scored and self.series is None:
            return
        v = ch.validity
        pending = self._pending[ch.estimate]
        pending.append((t_ns, msg.data, latest[1] if matched else None, scored,  # type: ignore[index]  # matched: latest is set
                        self._validity.get(v[0]) if v is not None and v[0] != ch.estimate
                        else None))
        if len(pending) >= PENDING:
            self._score(fc, ch, pending)
            pending.clear()

    def flush(self) -> None:
        """Score the estimates still pending (summary() does it too)."""
        for fc, ch in self._est.values():
            pending = self._pending[ch.estimate]
            if pending:
                self._score(fc, ch, pending)
                pending.clear()

    def _score(self, fc: FrameCodec, ch: TruthChannel,
               pending: list[tuple[int, bytearray, dict[str, float] | None, bool, int | None]]
               ) -> None:
        """The estimates of one message in the order sent: decoded in a block (FrameCodec.
        check_block: decode()'s values) when their payloads allow, then scored one by one."""
        payloads: list[bytes | bytearray] = [p[1] for p in pending]
        block = (fc.check_block(payloads) if all(len(d) == fc.length for d in payloads)
                 else None)
        # est[col[signal]]: a block's rows are tuples in its names' order, decode()'s dicts
        rows: list[Any]
        col: dict[str, Any]
        if block is not None and block.names:
            rows, col = block.rows, {name: i for i, name in enumerate(block.names)}
        else:
            rows, col = [fc.decode(d) for d in payloads], {s.name: s.name for s in fc.signals}
        stats = self.stats[ch.estimate]
        pairs = [(stats[p.key], col[p.estimate_signal], p.truth_signal,
                  None if p.only_when is None else (col[p.only_when[0]], p.only_when[1]))
                 for p in ch.pairs]
        series = None if self.series is None else self.series[self._group[ch.estimate]]
        first = ch.pairs[0]
        first_est, first_truth = col[first.estimate_signal], first.truth_signal
        v = ch.validity
        own_validity = col[v[1]] if v is not None and v[0] == ch.estimate else None
        not_valid = 0
        for (t_ns, _, truth, scored, other_validity), est in zip(pending, rows):
            if series is not None:
                series.append((t_ns / 1e9, est[first_est],
                               truth[first_truth] if truth is not None else math.nan))
            if not scored:
                continue
            if v is not None:
                validity = est[own_validity] if own_validity is not None else other_validity
                if validity is not None and int(validity) not in SCORED:
                    not_valid += 1
                    continue
            for stat, est_i, truth_signal, only_when in pairs:
                if only_when is not None and int(est[only_when[0]]) != only_when[1]:
                    continue
                stat.add(est[est_i] - truth[truth_signal])  # type: ignore[index]  # scored: matched
        self.not_valid[ch.estimate] += not_valid

    def summary(self) -> ReplayScore:
        self.flush()
        sections = {}
        for name, ch in self.channels:
            stats = self.stats[ch.estimate]
            if (any(s.n for s in stats.values()) or self.unmatched[ch.estimate]
                    or self.not_valid[ch.estimate]):
                sections[name] = ScoreSection(
                    {k: s.summary() for k, s in stats.items()}, self.unmatched[ch.estimate],
                    self.not_valid[ch.estimate])
        return ReplayScore(self.truth_frames, self.bad_truth_frames, sections)
