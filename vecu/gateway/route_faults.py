"""Faults on a gateway route (a scenario's `[[faults]]` with target = a route's key, e.g.
`routes[1]`): what a test does on purpose to the frames a route sends, with the restbus
disturbances' records and behaviour (vecu.restbus.disturb `KINDS`: drop the next N frames, stop,
delay each frame by N ms, corrupt a data byte) applied to the route's output, after the route's
own figures. Each start and end goes on the first bus as an FI_Event frame, as vecu's other faults
do: FI_EvMessageId the CAN ID the route sends (its first), FI_EvKind the disturbance's code."""

from __future__ import annotations

import can
import numpy as np

from vecu.codec import FrameCodec
from vecu.errors import BadArgumentError
from vecu.faults import FAULT_SOURCES
from vecu.restbus import disturb

ROUTE_KINDS = ("drop", "stop", "delay", "corrupt")


def check(kind: str, value: float | None) -> None:
    """Raise BadArgumentError unless `kind` (with `value`) can act on a route."""
    if kind not in ROUTE_KINDS:
        raise BadArgumentError(f"a route fault is one of {', '.join(ROUTE_KINDS)}, got {kind!r}")
    disturb.make(kind, value, np.random.default_rng(0))


class RouteFaults:
    """The active faults of one route; apply() each tick to the frames it sends."""

    def __init__(self, key: str, out_id: int, rng: np.random.Generator) -> None:
        self.key, self.out_id, self._rng = key, out_id, rng
        self.active: dict[str, disturb.Disturbance] = {}
        self._held: list[tuple[int, can.Message]] = []  # (due ns, frame) of a delay
        self.dropped = 0

    def start(self, kind: str, value: float | None) -> disturb.Disturbance:
        check(kind, value)
        d = self.active[kind] = disturb.make(kind, value, self._rng)
        return d

    def end(self, kind: str) -> disturb.Disturbance | None:
        return self.active.pop(kind, None)

    def apply(self, frames: list[can.Message], now_ns: int
              ) -> tuple[list[can.Message], int, list[disturb.Disturbance]]:
        """The frames that go out now (delayed ones when due), how many this call dropped, and
        the faults that ended themselves (drop N)."""
        dropped = 0
        for msg in frames:
            ds = list(self.active.values())
            gates = [d.gate() for d in ds]  # every gate sees the frame (drop N counts it)
            if not all(gates):
                dropped += 1
                continue
            for d in ds:
                msg.data = d.payload(bytearray(msg.data), None)
                msg.dlc = len(msg.data)
            delay = max((d.delay_ns for d in ds), default=0)
            self._held.append((now_ns + delay, msg))
        ended = [self.active.pop(k) for k in [k for k, d in self.active.items() if d.done]]
        out = [m for due, m in self._held if due <= now_ns]
        self._held = [(due, m) for due, m in self._held if due > now_ns]
        for m in out:
            m.timestamp = now_ns / 1e9
        self.dropped += dropped
        return out, dropped, ended

    def event(self, fi_event: FrameCodec, now_ns: int, kind: str, value: float, active: bool,
              source: str = "scenario") -> can.Message:
        """The FI_Event frame of a start (active) or end."""
        return fi_event.frame({"FI_EvMessageId": self.out_id & 0xFFFF, "FI_EvSignal": 0,
                               "FI_EvKind": disturb.KINDS[kind].code, "FI_EvActive": int(active),
                               "FI_EvSource": FAULT_SOURCES.get(source, 3),
                               "FI_EvValue": max(-1e6, min(1e6, value))}, now_ns / 1e9)
