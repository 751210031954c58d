"""Fault kinds and what each does (vecu.faults holds the sites and the injector).

- Signal faults map a healthy physical value to the faulty one: dead, short to supply, stuck,
  offset, gain, noise, drift, quantisation (`apply(value, t_ns)`).
- Frame faults act on a message's frames in the plant's send stage: frames stop, dropout, delay,
  wrong alive counter, bad CRC, burst, babbling node, bus error frames (`FrameFault`).

Each kind is one `FaultKind` member holding its record (`KindSpec`: FI_Kind code, value
meaning, default, bounds, behaviour), as the restbus disturbances are `KINDS` entries
(vecu.restbus.disturb); the two share FI_EvKind's 5-bit code space (tests/test_fault_kinds.py).
`make_fault` builds a signal fault from its kind and value; every random draw comes from the
injector's seeded generator.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import can
import numpy as np

from vecu.errors import BadArgumentError

if TYPE_CHECKING:
    from vecu.codec import FrameCodec

# ---------------------------------------------------------------------------- behaviours
# A signal kind's law maps the healthy value to the faulty one (None: no frame); a frame kind's
# `frames` turns one outgoing frame into what goes on the bus now, its `per_tick` adds frames
# each 1 ms tick. Every random draw comes from the fault's (the injector's seeded) generator.

def _dead(f: SignalFault, value: float, t_ns: int) -> float | None:
    """Open circuit: the input is pulled to 0 (gain G = 0)."""
    return 0.0


def _short_supply(f: SignalFault, value: float, t_ns: int) -> float | None:
    return f.supply


def _stuck(f: SignalFault, value: float, t_ns: int) -> float | None:
    """Output frozen at the first value seen after activation."""
    if f.held is None:
        f.held = value
    return f.held


def _no_frame(f: SignalFault, value: float, t_ns: int) -> float | None:
    """The sensor stops transmitting (on the part fast path: no frame)."""
    return None


def _offset(f: SignalFault, value: float, t_ns: int) -> float | None:
    return value + f.value  # in the signal's unit (V for the TPS)


def _gain(f: SignalFault, value: float, t_ns: int) -> float | None:
    """Sensor model Y = G * Y0 with 0 <= G <= 1 (G = 0: dead)."""
    return f.value * value


def _noise(f: SignalFault, value: float, t_ns: int) -> float | None:
    return value + f.value * float(f.rng.standard_normal())


def _drift(f: SignalFault, value: float, t_ns: int) -> float | None:
    """Offset growing linearly from the activation time: rate per second."""
    return value + f.value * (t_ns - f.t0_ns) * 1e-9


def _quantise(f: SignalFault, value: float, t_ns: int) -> float | None:
    """Coarse ADC: the value rounded to a multiple of the step."""
    q = value / f.value
    return round(q) * f.value if math.isfinite(q) else value  # a step below resolution


def _stop_frames(f: FrameFault, msg: can.Message) -> list[can.Message]:
    return []


def _pass(f: FrameFault, msg: can.Message) -> list[can.Message]:
    """The frame unchanged (delay: the injector holds it back; babble, error frames: per tick)."""
    return [msg]


def _dropout(f: FrameFault, msg: can.Message) -> list[can.Message]:
    return [] if f.rng.random() < f.value else [msg]


def _burst(f: FrameFault, msg: can.Message) -> list[can.Message]:
    return [msg] * max(1, round(f.value))


def _bad_crc(f: FrameFault, msg: can.Message) -> list[can.Message]:
    if f.value >= 1.0 or f.rng.random() < f.value:
        data = bytearray(msg.data)
        data[f.codec.e2e.crc_byte] ^= 0xFF  # type: ignore[union-attr]  # E2E kinds: checked
        return [with_data(msg, data)]
    return [msg]


def _wrong_counter(f: FrameFault, msg: can.Message) -> list[can.Message]:
    """The alive counter frozen at its value when the fault began."""
    fc = f.codec
    e2e = fc.e2e
    assert e2e is not None  # E2E kinds: checked by the injector
    values = fc.decode(msg.data)
    if f.held_counter is None:
        f.held_counter = int(values[e2e.counter_signal])
    values[e2e.counter_signal] = f.held_counter
    return [with_data(msg, fc.encode(values))]


def _babble(f: FrameFault, t_ns: int) -> list[can.Message]:
    """A babbling node: garbage frames with the message's ID."""
    fc = f.codec
    payloads = f.rng.integers(0, 256, size=(_per_tick_count(f.value, t_ns), fc.length),
                              dtype=np.uint8)
    return [can.Message(timestamp=t_ns * 1e-9, arbitration_id=fc.frame_id,
                        is_extended_id=fc.is_extended, data=bytes(p), check=False)
            for p in payloads]


def _error_frames(f: FrameFault, t_ns: int) -> list[can.Message]:
    return [can.Message(timestamp=t_ns * 1e-9, is_error_frame=True, check=False)
            for _ in range(_per_tick_count(f.value, t_ns))]


# ---------------------------------------------------------------------------- the kinds
UNBOUNDED = (-math.inf, math.inf)


@dataclass(frozen=True)
class KindSpec:
    """Every fact of one fault kind: its FI_Kind / FI_EvKind code (dbc/vecu.dbc), what its
    value means (symbol: its name in a refusal, default: meaning), default and bounds (open_low:
    the lower bound itself refused), and its behaviour: a signal law, or a frame kind's
    `frames` / `per_tick` (e2e: it needs the message's E2E CRC and alive counter)."""

    code: int
    law: Callable[[SignalFault, float, int], float | None] | None = None
    frames: Callable[[FrameFault, can.Message], list[can.Message]] | None = None
    per_tick: Callable[[FrameFault, int], list[can.Message]] | None = None
    meaning: str = ""
    symbol: str = ""
    default: float = 0.0
    bounds: tuple[float, float] = UNBOUNDED
    open_low: bool = False
    e2e: bool = False


class FaultKind(enum.IntEnum):
    """Every fault kind, one record each (KindSpec): the member's value is its FI_Kind code.
    The restbus disturbances hold FI_EvKind codes 17..29 (vecu.restbus.disturb.KINDS)."""

    _spec: KindSpec

    if not TYPE_CHECKING:  # to a type checker FaultKind(code) is the plain IntEnum look-up
        def __new__(cls, spec):
            self = int.__new__(cls, spec.code)  # the enum's own member, as Python's docs build one
            self._value_ = spec.code
            self._spec = spec
            return self

    CLEAR = KindSpec(0)
    DEAD = KindSpec(1, _dead)
    STUCK = KindSpec(2, _stuck)
    FRAMES_STOP = KindSpec(3, _no_frame, _stop_frames)
    OFFSET = KindSpec(4, _offset, meaning="added offset", default=0.5)
    GAIN = KindSpec(5, _gain, meaning="gain G in [0, 1]", symbol="G", default=0.5, bounds=(0.0, 1.0))
    NOISE = KindSpec(6, _noise, meaning="noise sigma", symbol="sigma", default=0.3,
                     bounds=(0.0, math.inf))
    SHORT_SUPPLY = KindSpec(7, _short_supply,
                            meaning="supply level (default: TPS 5 V, else the DBC maximum)")
    DRIFT = KindSpec(8, _drift, meaning="drift rate per second", default=0.5)
    QUANTISE = KindSpec(9, _quantise, meaning="quantisation step", symbol="step", default=0.1,
                        bounds=(0.0, math.inf), open_low=True)
    DELAY = KindSpec(10, frames=_pass, meaning="delay in ms", default=20.0, bounds=(0.0, 10_000.0))
    DROPOUT = KindSpec(11, frames=_dropout, meaning="probability a frame is lost", default=0.5,
                       bounds=(0.0, 1.0))
    WRONG_COUNTER = KindSpec(12, frames=_wrong_counter, e2e=True)
    BAD_CRC = KindSpec(13, frames=_bad_crc, meaning="fraction of frames with a bad CRC",
                       default=1.0, bounds=(0.0, 1.0), e2e=True)
    BURST = KindSpec(14, frames=_burst, meaning="copies of each frame", default=3.0,
                     bounds=(1.0, 100.0))
    BABBLE = KindSpec(15, frames=_pass, per_tick=_babble, meaning="garbage frames per ms",
                      default=5.0, bounds=(0.0, 100.0))
    ERROR_FRAMES = KindSpec(16, frames=_pass, per_tick=_error_frames,
                            meaning="error frames per ms", default=1.0, bounds=(0.0, 100.0))

    @property
    def spec(self) -> KindSpec:
        """This kind's record."""
        return self._spec

    @property
    def label(self) -> str:
        """The kind's name in scenarios, commands and messages (FI_Kind's VAL_ name)."""
        return self.name.lower()

    @property
    def is_frame(self) -> bool:
        """A frame kind: it acts on a message's frames in the plant's send stage."""
        return self.spec.frames is not None

    @property
    def default(self) -> float:
        return self.spec.default

    def checked(self, value: float | None) -> float:
        """`value` (None: the default) if this kind admits it, else BadArgumentError."""
        spec = self.spec
        v = spec.default if value is None else value
        if not math.isfinite(v):
            raise BadArgumentError(f"{self.label} fault: the value must be a finite number, "
                                   f"got {v}")
        lo, hi = spec.bounds
        if (v <= lo if spec.open_low else v < lo) or v > hi:
            what = spec.symbol or spec.meaning
            rule = (f"> {lo:g}" if spec.open_low else f">= {lo:g}") if hi == math.inf \
                else f"in [{lo:g}, {hi:g}]"
            raise BadArgumentError(f"{self.label} fault: {what} must be {rule}, got {v}")
        return v


# the frame stage's kinds, and those that need the message's E2E protection (views of FaultKind)
FRAME_KINDS = frozenset(k for k in FaultKind if k.is_frame)
E2E_KINDS = frozenset(k for k in FaultKind if k.spec.e2e)
SUPPLY_V = 5.0


class Fault(Protocol):
    kind: FaultKind

    def apply(self, value: float, t_ns: int = 0) -> float | None: ...


@dataclass
class SignalFault:
    """A signal fault (or frames stop, for the part fast path): its kind's law on each value."""

    kind: FaultKind
    value: float
    rng: np.random.Generator
    t0_ns: int = 0
    supply: float = SUPPLY_V
    held: float | None = None

    def apply(self, value: float, t_ns: int = 0) -> float | None:
        return self.kind.spec.law(self, value, t_ns)  # type: ignore[misc]  # signal kinds have a law


@dataclass
class FrameFault:
    """Transforms one message's outgoing frames; `process` returns what goes on the bus now."""

    kind: FaultKind
    value: float
    codec: FrameCodec
    rng: np.random.Generator
    held_counter: int | None = field(default=None, repr=False)

    def process(self, msg: can.Message) -> list[can.Message]:
        return self.kind.spec.frames(self, msg)  # type: ignore[misc]  # frame kinds have frames

    def per_tick(self, t_ns: int) -> list[can.Message]:
        """Frames a babbling node or a disturbed bus adds each 1 ms tick."""
        more = self.kind.spec.per_tick
        return [] if more is None else more(self, t_ns)


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
    """A signal fault (or frames stop, for the part fast path) of `kind`, its value checked
    (None: the kind's default)."""
    if kind.spec.law is None:
        raise ValueError(f"no signal fault of kind {kind.label!r}")
    return SignalFault(kind, kind.checked(value), rng, t_ns, supply)


def check_value(kind: FaultKind, value: float | None) -> None:
    """Raise BadArgumentError unless `value` (None: the kind's default) suits `kind`."""
    if kind != FaultKind.CLEAR:
        kind.checked(value)
