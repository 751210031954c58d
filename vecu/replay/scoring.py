"""Score a trace from frames alone: the ECU's estimate frames against the plant's debug truth
frames (dbc/vecu_truth.dbc) recorded in the same trace.

Pairing: an estimate at time t is compared with the newest truth frame at or before t, if that
truth is at most one period of its message old (each function's TruthChannel in its registry
entry, vecu.functions: its max_age_ns). Estimates without truth are counted as unmatched, not
scored. Estimates their validity signal (TruthChannel.validity, vecu.ecu.validity) flags init or
invalid are counted (`not_valid_estimates`), not scored: the ECU said they mean nothing.

The scorer is one of the ECU's estimate sinks (vecu.bus.EstimateSink): it scores the values each frame
carries as the ECU's framer hands them over (what a decoder of the frame would read), so it
decodes no frame the ECU sent, only the trace's truth frames. A frame sent without its values
(a plug-in's `send(msg)`) is decoded here instead.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import can

from vecu import functions
from vecu.codec import DbcCodec, FrameCodec, Values
from vecu.ecu.validity import SCORED
from vecu.functions.base import TruthChannel
from vecu.replay.summary import ReplayScore, ScoreSection
from vecu.stats import RunningStats


def channels() -> list[tuple[str, TruthChannel]]:
    """(function, its truth channel) of every registered function that has one."""
    return [(spec.name, spec.truth) for spec in functions.specs() if spec.truth is not None]


class TruthScorer:
    """Feed truth frames with on_truth() as they are read and the ECU's frames with
    on_estimate() as they are sent (an EstimateSink); summary() gives error statistics per
    function."""

    def __init__(self, codec: DbcCodec, keep_series: bool = False) -> None:
        # per channel rows (t_s, estimate, truth or NaN) of its first pair, for plots
        self.channels = channels()
        self._group = {ch.estimate: name for name, ch in self.channels}
        self.series: dict[str, list[tuple[float, float, float]]] | None = (
            {name: [] for name, _ in self.channels} if keep_series else None)
        self._truth_codecs: dict[tuple[int, bool], FrameCodec] = {}
        # estimate messages: codec, channel, the index of each signal in the values sent
        self._est: dict[tuple[int, bool], tuple[FrameCodec, TruthChannel, dict[str, int]]] = {}
        # messages that carry another estimate message's validity: (codec, its signal's index)
        self._validity_msgs: dict[tuple[int, bool], tuple[FrameCodec, int]] = {}
        self._validity: dict[str, int] = {}  # validity message -> its latest validity
        for _, ch in self.channels:
            if ch.truth in codec and ch.estimate in codec:
                t, e = codec[ch.truth], codec[ch.estimate]
                self._truth_codecs[(t.frame_id, t.is_extended)] = t
                self._est[(e.frame_id, e.is_extended)] = (e, ch, _index(e))
                v = ch.validity
                if v is not None and v[0] != ch.estimate and v[0] in codec:
                    vc = codec[v[0]]
                    self._validity_msgs[(vc.frame_id, vc.is_extended)] = (vc, _index(vc)[v[1]])
        self.truth_ids = frozenset(self._truth_codecs)
        self.truth_codecs: Mapping[tuple[int, bool], FrameCodec] = self._truth_codecs
        self._latest: dict[str, tuple[int, dict[str, float]]] = {}
        self.stats = {ch.estimate: {p.key: RunningStats() for p in ch.pairs}
                      for _, ch in self.channels}
        self.unmatched = {ch.estimate: 0 for _, ch in self.channels}
        self.not_valid = {ch.estimate: 0 for _, ch in self.channels}
        self.truth_frames = 0
        self.bad_truth_frames = 0

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

    def on_estimate(self, values: Values | None, msg: can.Message, t_ns: int) -> None:
        """A frame the ECU sent at t_ns with the values it carries (vecu.bus.EstimateSink)."""
        if not self.truth_frames and self.series is None:
            return
        key = (msg.arbitration_id, msg.is_extended_id)
        entry = self._est.get(key)
        if entry is None:
            flag = self._validity_msgs.get(key)
            if flag is not None:
                self._validity[flag[0].name] = int(_carried(values, flag[0], msg)[flag[1]])  # type: ignore[arg-type]  # the signal is in the frame
            return
        fc, ch, at = entry
        latest = self._latest.get(ch.truth)
        matched = latest is not None and 0 <= t_ns - latest[0] <= ch.max_age_ns
        scored = matched and t_ns >= ch.burn_in_ns  # matched: truth frames seen
        if self.truth_frames and not matched:
            self.unmatched[ch.estimate] += 1
        if not scored and self.series is None:
            return
        est = _carried(values, fc, msg)
        if self.series is not None:
            first = ch.pairs[0]
            self.series[self._group[ch.estimate]].append(
                (t_ns / 1e9, est[at[first.estimate_signal]],  # type: ignore[arg-type]  # in the frame
                 latest[1][first.truth_signal] if matched else math.nan))
        if not scored:
            return
        v = ch.validity
        if v is not None:
            validity = (est[at[v[1]]] if v[0] == ch.estimate else self._validity.get(v[0]))
            if validity is not None and int(validity) not in SCORED:
                self.not_valid[ch.estimate] += 1
                return
        truth = latest[1]
        stats = self.stats[ch.estimate]
        for p in ch.pairs:
            if p.only_when is not None and int(est[at[p.only_when[0]]]) != p.only_when[1]:  # type: ignore[arg-type]  # in the frame
                continue
            stats[p.key].add(est[at[p.estimate_signal]] - truth[p.truth_signal])  # type: ignore[operator]  # in the frame

    def summary(self) -> ReplayScore:
        sections = {}
        for name, ch in self.channels:
            stats = self.stats[ch.estimate]
            if (any(s.n for s in stats.values()) or self.unmatched[ch.estimate]
                    or self.not_valid[ch.estimate]):
                sections[name] = ScoreSection(
                    {k: s.summary() for k, s in stats.items()}, self.unmatched[ch.estimate],
                    self.not_valid[ch.estimate])
        return ReplayScore(self.truth_frames, self.bad_truth_frames, sections)


def _index(fc: FrameCodec) -> dict[str, int]:
    """Each signal's place in the values a frame of fc carries (the DBC's order)."""
    return {sig.name: i for i, sig in enumerate(fc.signals)}


def _carried(values: Values | None, fc: FrameCodec, msg: can.Message) -> Values:
    """The values msg carries: as sent, or (a frame sent without them) decoded."""
    if values is not None:
        return values
    decoded = fc.decode(msg.data)
    return tuple(decoded[sig.name] for sig in fc.signals)
