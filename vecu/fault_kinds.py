"""Fault kinds and what each does (vecu.faults holds the sites and the injector).

- Signal faults map a healthy physical value to the faulty one: dead, short to supply, stuck,
  offset, gain, noise, drift, quantisation (`apply(value, t_ns)`).
- Frame faults act on a message's frames in the plant's send stage: frames stop, dropout, delay,
  wrong alive counter, bad CRC, burst, babbling node, bus error frames (`FrameFault`).
`make_fault` builds one from its kind and value; every random draw comes from the injector's
seeded generator.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import can
import numpy as np

from vecu.errors import BadArgumentError

if TYPE_CHECKING:
    from vecu.codec import FrameCodec

class FaultKind(enum.IntEnum):
    """Values match FI_Kind / FI_EvKind in vecu/dbc/vecu.dbc."""

    CLEAR = 0
    DEAD = 1
    STUCK = 2
    FRAMES_STOP = 3
    OFFSET = 4
    GAIN = 5
    NOISE = 6
    SHORT_SUPPLY = 7
    DRIFT = 8
    QUANTISE = 9
    DELAY = 10
    DROPOUT = 11
    WRONG_COUNTER = 12
    BAD_CRC = 13
    BURST = 14
    BABBLE = 15
    ERROR_FRAMES = 16


FRAME_KINDS = frozenset({FaultKind.FRAMES_STOP, FaultKind.DELAY, FaultKind.DROPOUT,
                         FaultKind.WRONG_COUNTER, FaultKind.BAD_CRC, FaultKind.BURST,
                         FaultKind.BABBLE, FaultKind.ERROR_FRAMES})
E2E_KINDS = frozenset({FaultKind.WRONG_COUNTER, FaultKind.BAD_CRC})


# value meaning per kind (units: the signal's DBC unit, e.g. V for the TPS, deg for the SWA)
DEFAULT_VALUES = {FaultKind.OFFSET: 0.5, FaultKind.GAIN: 0.5, FaultKind.NOISE: 0.3,
                  FaultKind.DRIFT: 0.5, FaultKind.QUANTISE: 0.1, FaultKind.DELAY: 20.0,
                  FaultKind.DROPOUT: 0.5, FaultKind.BAD_CRC: 1.0, FaultKind.BURST: 3.0,
                  FaultKind.BABBLE: 5.0, FaultKind.ERROR_FRAMES: 1.0}
VALUE_MEANING = {FaultKind.OFFSET: "added offset", FaultKind.GAIN: "gain G in [0, 1]",
                 FaultKind.NOISE: "noise sigma", FaultKind.DRIFT: "drift rate per second",
                 FaultKind.QUANTISE: "quantisation step", FaultKind.DELAY: "delay in ms",
                 FaultKind.DROPOUT: "probability a frame is lost",
                 FaultKind.BAD_CRC: "fraction of frames with a bad CRC",
                 FaultKind.BURST: "copies of each frame", FaultKind.BABBLE: "garbage frames per ms",
                 FaultKind.ERROR_FRAMES: "error frames per ms",
                 FaultKind.SHORT_SUPPLY: "supply level (default: TPS 5 V, else the DBC maximum)"}
SUPPLY_V = 5.0
FRAME_VALUE_LIMITS = {FaultKind.DROPOUT: (0.0, 1.0), FaultKind.BAD_CRC: (0.0, 1.0),
                      FaultKind.DELAY: (0.0, 10_000.0), FaultKind.BURST: (1.0, 100.0),
                      FaultKind.BABBLE: (0.0, 100.0), FaultKind.ERROR_FRAMES: (0.0, 100.0)}


class Fault(Protocol):
    kind: FaultKind

    def apply(self, value: float, t_ns: int = 0) -> float | None: ...


@dataclass
class Dead:
    """Open circuit: the input is pulled to 0 (gain G = 0)."""

    kind: FaultKind = FaultKind.DEAD

    def apply(self, value: float, t_ns: int = 0) -> float | None:
        return 0.0


@dataclass
class ShortToSupply:
    level: float = SUPPLY_V
    kind: FaultKind = FaultKind.SHORT_SUPPLY

    def apply(self, value: float, t_ns: int = 0) -> float | None:
        return self.level


@dataclass
class Stuck:
    """Output frozen at the first value seen after activation."""

    held: float | None = None
    kind: FaultKind = FaultKind.STUCK

    def apply(self, value: float, t_ns: int = 0) -> float | None:
        if self.held is None:
            self.held = value
        return self.held


@dataclass
class FramesStop:
    """The sensor stops transmitting (a frame fault; on the part fast path: no frame)."""

    kind: FaultKind = FaultKind.FRAMES_STOP

    def apply(self, value: float, t_ns: int = 0) -> float | None:
        return None


@dataclass
class Offset:
    volts: float  # in the signal's unit (V for the TPS)
    kind: FaultKind = FaultKind.OFFSET

    def apply(self, value: float, t_ns: int = 0) -> float | None:
        return value + self.volts


@dataclass
class Gain:
    """Sensor model Y = G * Y0 with 0 <= G <= 1 (G = 0: dead)."""

    gain: float
    kind: FaultKind = FaultKind.GAIN

    def __post_init__(self) -> None:
        if not 0.0 <= self.gain <= 1.0:
            raise BadArgumentError(f"gain fault: G must be in [0, 1], got {self.gain}")

    def apply(self, value: float, t_ns: int = 0) -> float | None:
        return self.gain * value


@dataclass
class Noise:
    sigma_v: float
    rng: np.random.Generator
    kind: FaultKind = FaultKind.NOISE

    def apply(self, value: float, t_ns: int = 0) -> float | None:
        return value + self.sigma_v * float(self.rng.standard_normal())


@dataclass
class Drift:
    """Offset growing linearly from the activation time: rate per second."""

    rate: float
    t0_ns: int
    kind: FaultKind = FaultKind.DRIFT

    def apply(self, value: float, t_ns: int = 0) -> float | None:
        return value + self.rate * (t_ns - self.t0_ns) * 1e-9


@dataclass
class Quantise:
    """Coarse ADC: the value rounded to a multiple of `step`."""

    step: float
    kind: FaultKind = FaultKind.QUANTISE

    def apply(self, value: float, t_ns: int = 0) -> float | None:
        q = value / self.step
        return round(q) * self.step if math.isfinite(q) else value  # a step below resolution


# ---------------------------------------------------------------------------- frame faults
@dataclass
class FrameFault:
    """Transforms one message's outgoing frames; `process` returns what goes on the bus now."""

    kind: FaultKind
    value: float
    codec: FrameCodec
    rng: np.random.Generator
    _held_counter: int | None = field(default=None, repr=False)

    def process(self, msg: can.Message) -> list[can.Message]:
        kind = self.kind
        if kind == FaultKind.FRAMES_STOP:
            return []
        if kind == FaultKind.DROPOUT:
            return [] if self.rng.random() < self.value else [msg]
        if kind == FaultKind.BURST:
            return [msg] * max(1, round(self.value))
        if kind == FaultKind.BAD_CRC:
            if self.value >= 1.0 or self.rng.random() < self.value:
                data = bytearray(msg.data)
                data[self.codec.e2e.crc_byte] ^= 0xFF
                return [with_data(msg, data)]
            return [msg]
        if kind == FaultKind.WRONG_COUNTER:  # counter frozen at its value when the fault began
            fc = self.codec
            values = fc.decode(msg.data)
            if self._held_counter is None:
                self._held_counter = int(values[fc.e2e.counter_signal])
            values[fc.e2e.counter_signal] = self._held_counter
            return [with_data(msg, fc.encode(values))]
        return [msg]  # DELAY is handled by the injector; BABBLE / ERROR_FRAMES act per tick

    def per_tick(self, t_ns: int) -> list[can.Message]:
        """Frames a babbling node or a disturbed bus adds each 1 ms tick."""
        n = _per_tick_count(self.value, t_ns)
        if self.kind == FaultKind.BABBLE:
            fc = self.codec
            payloads = self.rng.integers(0, 256, size=(n, fc.length), dtype=np.uint8)
            return [can.Message(timestamp=t_ns * 1e-9, arbitration_id=fc.frame_id,
                                is_extended_id=fc.is_extended, data=bytes(p), check=False)
                    for p in payloads]
        if self.kind == FaultKind.ERROR_FRAMES:
            return [can.Message(timestamp=t_ns * 1e-9, is_error_frame=True, check=False)
                    for _ in range(n)]
        return []


def _per_tick_count(rate_per_ms: float, t_ns: int) -> int:
    """Whole frames per 1 ms tick for a (possibly fractional) rate, spread evenly in time."""
    k = t_ns // 1_000_000
    return int(math.floor((k + 1) * rate_per_ms) - math.floor(k * rate_per_ms))


def with_data(msg: can.Message, data: bytes | bytearray) -> can.Message:
    return can.Message(timestamp=msg.timestamp, arbitration_id=msg.arbitration_id,
                       is_extended_id=msg.is_extended_id, data=bytes(data), is_fd=msg.is_fd,
                       check=False)


def make_fault(kind: FaultKind, value: float | None, rng: np.random.Generator,
               t_ns: int = 0, supply: float = SUPPLY_V) -> Fault:
    """Build a signal fault (or FramesStop, for the part fast path); see DEFAULT_VALUES."""
    if value is None:
        value = DEFAULT_VALUES.get(kind, 0.0)
    if not math.isfinite(value):
        raise BadArgumentError(f"{kind.name.lower()} fault: the value must be a finite number, "
                               f"got {value}")
    if kind == FaultKind.DEAD:
        return Dead()
    if kind == FaultKind.SHORT_SUPPLY:
        return ShortToSupply(supply)
    if kind == FaultKind.STUCK:
        return Stuck()
    if kind == FaultKind.FRAMES_STOP:
        return FramesStop()
    if kind == FaultKind.OFFSET:
        return Offset(value)
    if kind == FaultKind.GAIN:
        return Gain(value)
    if kind == FaultKind.NOISE:
        if value < 0:
            raise BadArgumentError(f"noise fault: sigma must be >= 0, got {value}")
        return Noise(value, rng)
    if kind == FaultKind.DRIFT:
        return Drift(value, t_ns)
    if kind == FaultKind.QUANTISE:
        if not value > 0:
            raise BadArgumentError(f"quantise fault: step must be > 0, got {value}")
        return Quantise(value)
    raise ValueError(f"no signal fault of kind {kind.name.lower()!r}")


def check_value(kind: FaultKind, value: float | None) -> None:
    """Raise BadArgumentError unless `value` (None: the kind's default) suits `kind`."""
    if kind in FRAME_KINDS:
        check_frame_value(kind, DEFAULT_VALUES.get(kind, 0.0) if value is None else value)
    elif kind != FaultKind.CLEAR:
        make_fault(kind, value, np.random.default_rng(0))


def check_frame_value(kind: FaultKind, value: float) -> None:
    lo, hi = FRAME_VALUE_LIMITS.get(kind, (-math.inf, math.inf))
    if not lo <= value <= hi:
        raise BadArgumentError(f"{kind.name.lower()} fault: {VALUE_MEANING[kind]} must be in "
                               f"[{lo:g}, {hi:g}], got {value}")
