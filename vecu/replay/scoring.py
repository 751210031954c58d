"""Score a trace from frames alone: the ECU's estimate frames against the plant's debug truth
frames (vecu/dbc/vecu_truth.dbc) recorded in the same trace.

Pairing: an estimate at time t is compared with the newest truth frame at or before t, if that
truth is at most one period of its message old (throttle 1 ms, speed 2 ms, steering 10 ms, manifold:
the engine event the ECU last processed, at most 50 ms old). Estimates without truth are counted
as unmatched, not scored.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import can

from vecu.clock import NS_PER_MS
from vecu.codec import DbcCodec, FrameCodec
from vecu.replay.summary import ReplayScore, ScoreSection
from vecu.stats import RunningStats

SPEED_BURN_IN_NS = 500 * NS_PER_MS  # as the live probe: the filter starts at rest
SOURCE_ESTIMATE = 1


@dataclass(frozen=True)
class _Pair:
    """One estimate signal scored against one truth signal."""

    key: str
    estimate_signal: str
    truth_signal: str
    only_when: tuple[str, int] | None = None  # (signal, value) the estimate frame must carry


@dataclass(frozen=True)
class _Channel:
    estimate: str   # ECU message
    truth: str      # truth message
    max_age_ns: int
    pairs: tuple[_Pair, ...]
    burn_in_ns: int = 0


CHANNELS = (
    _Channel("ECU_ThrottleEstimate", "TRUTH_Throttle", NS_PER_MS, (
        _Pair("broadcast_error_deg", "THR_Angle", "TRU_ThrottleAngle"),
        _Pair("estimate_error_deg", "THR_AngleEst", "TRU_ThrottleAngle"),
        _Pair("fallback_error_deg", "THR_Angle", "TRU_ThrottleAngle", ("THR_Source", SOURCE_ESTIMATE)),
    )),
    _Channel("ECU_SpeedEstimate", "TRUTH_Speed", 2 * NS_PER_MS, (
        _Pair("speed_error_kmh", "SPD_VehSpeed", "TRU_VehSpeed"),
        _Pair("accel_error_mps2", "SPD_VehAccel", "TRU_VehAccel"),
    ), burn_in_ns=SPEED_BURN_IN_NS),
    _Channel("ECU_SteeringEstimate", "TRUTH_Steering", 10 * NS_PER_MS, (
        _Pair("swa_broadcast_error_deg", "STE_SwAngle", "TRU_SwAngle"),
        _Pair("swa_estimate_error_deg", "STE_SwAngleEst", "TRU_SwAngle"),
        _Pair("side_slip_error_deg", "STE_SideSlip", "TRU_SideSlip"),
        _Pair("swa_fallback_error_deg", "STE_SwAngle", "TRU_SwAngle", ("STE_Source", SOURCE_ESTIMATE)),
    )),
    _Channel("ECU_ManifoldEstimate", "TRUTH_Manifold", 50 * NS_PER_MS, (
        _Pair("map_error_kpa", "MFD_Pressure", "TRU_MAP"),
        _Pair("imt_error_k", "MFD_Temperature", "TRU_IMT"),
        _Pair("cac_error_mg", "MFD_CAC", "TRU_CAC"),
    )),
)
GROUP = {"ECU_ThrottleEstimate": "throttle", "ECU_SpeedEstimate": "speed",
         "ECU_SteeringEstimate": "steering", "ECU_ManifoldEstimate": "manifold"}


class TruthScorer:
    """Feed truth frames with on_truth() as they are read and ECU estimate frames with
    on_estimate() as they are sent; summary() gives error statistics per function."""

    def __init__(self, codec: DbcCodec, keep_series: bool = False) -> None:
        # per channel rows (t_s, estimate, truth or NaN) of its first pair, for plots
        self.series: dict[str, list[tuple[float, float, float]]] | None = (
            {GROUP[ch.estimate]: [] for ch in CHANNELS} if keep_series else None)
        self._truth_codecs: dict[tuple[int, bool], FrameCodec] = {}
        self._est: dict[tuple[int, bool], tuple[FrameCodec, _Channel]] = {}
        for ch in CHANNELS:
            if ch.truth in codec and ch.estimate in codec:
                t, e = codec[ch.truth], codec[ch.estimate]
                self._truth_codecs[(t.frame_id, t.is_extended)] = t
                self._est[(e.frame_id, e.is_extended)] = (e, ch)
        self.truth_ids = frozenset(self._truth_codecs)
        self.truth_codecs: Mapping[tuple[int, bool], FrameCodec] = self._truth_codecs
        self._latest: dict[str, tuple[int, dict[str, float]]] = {}
        self.stats = {ch.estimate: {p.key: RunningStats() for p in ch.pairs} for ch in CHANNELS}
        self.unmatched = {ch.estimate: 0 for ch in CHANNELS}
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

    def on_estimate(self, msg: can.Message, t_ns: int) -> None:
        if not self.truth_frames and self.series is None:
            return
        entry = self._est.get((msg.arbitration_id, msg.is_extended_id))
        if entry is None:
            return
        fc, ch = entry
        latest = self._latest.get(ch.truth)
        matched = latest is not None and 0 <= t_ns - latest[0] <= ch.max_age_ns
        scored = matched and t_ns >= ch.burn_in_ns  # matched: truth frames seen
        if self.truth_frames and not matched:
            self.unmatched[ch.estimate] += 1
        if not scored and self.series is None:
            return
        est = fc.decode(msg.data)
        if self.series is not None:
            first = ch.pairs[0]
            self.series[GROUP[ch.estimate]].append(
                (t_ns / 1e9, est[first.estimate_signal],
                 latest[1][first.truth_signal] if matched else math.nan))
        if not scored:
            return
        truth = latest[1]
        stats = self.stats[ch.estimate]
        for p in ch.pairs:
            if p.only_when is not None and int(est[p.only_when[0]]) != p.only_when[1]:
                continue
            stats[p.key].add(est[p.estimate_signal] - truth[p.truth_signal])

    def summary(self) -> ReplayScore:
        sections = {}
        for ch in CHANNELS:
            stats = self.stats[ch.estimate]
            if any(s.n for s in stats.values()) or self.unmatched[ch.estimate]:
                sections[GROUP[ch.estimate]] = ScoreSection(
                    {k: s.summary() for k, s in stats.items()}, self.unmatched[ch.estimate])
        return ReplayScore(self.truth_frames, self.bad_truth_frames, sections)
