"""Restbus disturbances: what a test does to one message's frames on purpose, one for one with
CANoe's ILNodeDisturbCounter / ILNodeDisturbChecksum and beyond.

Each kind is one entry of `KINDS` (its FI_EvKind code, default value, bounds, what it needs and
means) and one class with the hooks it uses, called by the restbus for every release of its
message (vecu.restbus.node):

    gate()                 False: nothing goes out this release (stop, drop)
    values(values)         signal values before encoding (override)
    counter(n, modulo)     the E2E counter to send, given the nominal one (freeze, skip, ...)
    advance()              how many steps the nominal counter moves after this frame
    payload(buf, prot)     the protected payload (CRC wrong / fixed, DLC change)
    period(ns)             this message's cycle (cycle time x k)
    delay_ns               frames go out this much later (delay)

A gateway route takes the frame-level kinds too (vecu.gateway.route_faults).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from vecu.e2e import E2EProtection
from vecu.errors import BadArgumentError


@dataclass
class Disturbance:
    """Base: every hook a no-op. `value` is the kind's parameter (KINDS: meaning, default)."""

    kind: ClassVar[str] = ""
    value: float
    rng: np.random.Generator
    signal: str | None = None
    delay_ns: int = 0
    done: bool = False  # a disturbance that ends itself (drop N)

    def gate(self) -> bool:
        return True

    def values(self, values: dict[str, float]) -> None:
        pass

    def counter(self, n: int, modulo: int) -> int:
        return n

    def advance(self) -> int:
        return 1

    def payload(self, buf: bytearray, prot: E2EProtection | None) -> bytearray:
        return buf

    def period(self, period_ns: int) -> int:
        return period_ns


@dataclass
class CounterFreeze(Disturbance):
    kind: ClassVar[str] = "counter_freeze"
    held: int | None = None

    def counter(self, n: int, modulo: int) -> int:
        if self.held is None:
            self.held = n
        return self.held


@dataclass
class CounterSkip(Disturbance):
    kind: ClassVar[str] = "counter_skip"

    def advance(self) -> int:
        return 1 + round(self.value)


@dataclass
class CounterRepeat(Disturbance):
    kind: ClassVar[str] = "counter_repeat"
    sent: int = 0

    def advance(self) -> int:
        self.sent += 1
        return 1 if self.sent % (1 + round(self.value)) == 0 else 0


@dataclass
class CounterOffset(Disturbance):
    kind: ClassVar[str] = "counter_offset"

    def counter(self, n: int, modulo: int) -> int:
        return (n + round(self.value)) % modulo


@dataclass
class CounterRandom(Disturbance):
    kind: ClassVar[str] = "counter_random"

    def counter(self, n: int, modulo: int) -> int:
        return int(self.rng.integers(modulo))


@dataclass
class CrcWrong(Disturbance):
    """The CRC's bits inverted, on a fraction `value` of the frames (1: all)."""

    kind: ClassVar[str] = "crc_wrong"

    def payload(self, buf: bytearray, prot: E2EProtection | None) -> bytearray:
        if prot is not None and (self.value >= 1 or self.rng.random() < self.value):
            a, b = prot.crc_span
            buf[a:b] = bytes(x ^ 0xFF for x in buf[a:b])
        return buf


@dataclass
class CrcFixed(Disturbance):
    """The CRC field holds `value` (little endian over the CRC's bytes), whatever the data."""

    kind: ClassVar[str] = "crc_fixed"

    def payload(self, buf: bytearray, prot: E2EProtection | None) -> bytearray:
        if prot is not None:
            a, b = prot.crc_span
            buf[a:b] = (int(self.value) % (1 << (8 * (b - a)))).to_bytes(b - a, "little")
        return buf


@dataclass
class Drop(Disturbance):
    """The next `value` frames are not sent; then the disturbance ends itself."""

    kind: ClassVar[str] = "drop"
    dropped: int = 0

    def gate(self) -> bool:
        if self.dropped < round(self.value):
            self.dropped += 1
            self.done = self.dropped >= round(self.value)
            return False
        self.done = True
        return True


@dataclass
class Stop(Disturbance):
    kind: ClassVar[str] = "stop"

    def gate(self) -> bool:
        return False


@dataclass
class Delay(Disturbance):
    kind: ClassVar[str] = "delay"

    def __post_init__(self) -> None:
        self.delay_ns = round(self.value * 1e6)


@dataclass
class CycleScale(Disturbance):
    kind: ClassVar[str] = "cycle"

    def period(self, period_ns: int) -> int:
        return max(1, round(period_ns * self.value))


@dataclass
class DlcChange(Disturbance):
    """The frame sent with `value` data bytes: cut, or padded with zeros."""

    kind: ClassVar[str] = "dlc"

    def payload(self, buf: bytearray, prot: E2EProtection | None) -> bytearray:
        n = round(self.value)
        return buf[:n] if n <= len(buf) else buf + bytes(n - len(buf))


@dataclass
class Corrupt(Disturbance):
    """Byte `value` of each frame has its bits inverted (past the frame's end: its last byte),
    the payload's E2E protection left as it was: the receiver's check fails."""

    kind: ClassVar[str] = "corrupt"

    def payload(self, buf: bytearray, prot: E2EProtection | None) -> bytearray:
        if buf:
            i = min(round(self.value), len(buf) - 1)
            buf[i] ^= 0xFF
        return buf


@dataclass
class Override(Disturbance):
    """Signal `signal` carries `value` (saturated into its range by the encoder)."""

    kind: ClassVar[str] = "override"

    def values(self, values: dict[str, float]) -> None:
        values[self.signal] = self.value  # type: ignore[index]  # signal: set for this kind


@dataclass(frozen=True)
class Kind:
    """One disturbance kind: class, FI_EvKind code (vecu/dbc/vecu.dbc), default value, bounds."""

    cls: type[Disturbance]
    code: int
    default: float
    bounds: tuple[float, float]
    meaning: str
    needs: str = ""  # "e2e", "signal" or ""


KINDS: dict[str, Kind] = {k.cls.kind: k for k in (
    Kind(CounterFreeze, 17, 0, (0, 0), "the E2E counter stays at its value", "e2e"),
    Kind(CounterSkip, 18, 1, (1, 1 << 16), "the counter jumps by 1 + value each frame", "e2e"),
    Kind(CounterRepeat, 19, 1, (1, 1 << 16), "each counter value sent 1 + value times", "e2e"),
    Kind(CounterOffset, 20, 1, (-(1 << 31), 1 << 31), "value added to the counter", "e2e"),
    Kind(CounterRandom, 21, 0, (0, 0), "a random counter each frame (seeded)", "e2e"),
    Kind(CrcWrong, 22, 1, (0, 1), "fraction of frames with the CRC's bits inverted", "e2e"),
    Kind(CrcFixed, 23, 0, (0, 2.0 ** 64 - 1), "the CRC field holds this value", "e2e"),
    Kind(Drop, 24, 1, (1, 1e9), "the next N frames are not sent"),
    Kind(Stop, 25, 0, (0, 0), "no frames"),
    Kind(Delay, 26, 5, (0, 1e4), "each frame sent this many ms late"),
    Kind(CycleScale, 27, 2, (0.01, 1e4), "cycle time x k"),
    Kind(DlcChange, 28, 0, (0, 64), "frames sent with this many data bytes"),
    Kind(Override, 29, 0, (-1e300, 1e300), "the signal carries this value", "signal"),
    Kind(Corrupt, 30, 0, (0, 63), "this data byte's bits inverted in every frame"),
)}


def make(kind: str, value: float | None, rng: np.random.Generator,
         signal: str | None = None) -> Disturbance:
    """A disturbance of `kind` (value None: its default), checked against its bounds."""
    k = KINDS.get(kind)
    if k is None:
        raise BadArgumentError(f"unknown restbus disturbance {kind!r} (known: "
                               f"{', '.join(KINDS)})")
    v = k.default if value is None else float(value)
    lo, hi = k.bounds
    if not math.isfinite(v) or not lo <= v <= hi:
        raise BadArgumentError(f"{kind}: {k.meaning} must be in [{lo:g}, {hi:g}], got {v!r}")
    if k.needs == "signal" and signal is None:
        raise BadArgumentError(f"{kind} needs MESSAGE.SIGNAL as its target")
    return k.cls(value=v, rng=rng, signal=signal)
