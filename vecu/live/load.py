"""Extra bus load for throughput tests: copies of the plant's current ESC_Motion frame."""

from __future__ import annotations

from vecu.clock import NS_PER_S
from vecu.codec import DbcCodec
from vecu.plant.node import PlantNode
from vecu.units import MPS_PER_KMH


class ExtraLoad:
    """Sends copies of the current ESC_Motion frame at a mean rate, spread over the 1 ms ticks
    (needs the plant's longitudinal part)."""

    def __init__(self, codec: DbcCodec, plant: PlantNode, per_s: float) -> None:
        if plant.longitudinal is None:
            raise ValueError("extra load sends ESC_Motion copies: the plant needs its speed part")
        self._msg = codec["ESC_Motion"]
        self._part = plant.longitudinal
        self._send = plant.send
        self._per_tick = per_s / 1000.0
        self._owed = 0.0
        self.sent = 0

    def tick(self, t_ns: int) -> None:
        self._owed += self._per_tick
        n = int(self._owed)
        if n <= 0:
            return
        self._owed -= n
        part = self._part
        frame = self._msg.frame({"ESC_WheelSpeed": part.wheel / MPS_PER_KMH,
                                 "ESC_LongAccel": part.accel}, t_ns / NS_PER_S)
        for _ in range(n):
            self.sent += self._send(frame)
