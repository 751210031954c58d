"""The frame-by-frame oracle of the replay feeder's block checks (tests only): the same feeder,
its frames handed on unchecked, so that the ECU and the scorer decode each one themselves."""

from __future__ import annotations

from vecu.codec import FrameCodec
from vecu.replay.feeder import Feeder


class FrameByFrame(Feeder):
    """The oracle of the block checks: a Feeder that hands every frame on unchecked, so that
    the ECU (EcuNode.receive) and the scorer (TruthScorer.on_truth) decode it one by one."""

    def checks(self, fc: FrameCodec, payloads: list[bytearray]) -> None:
        return None
