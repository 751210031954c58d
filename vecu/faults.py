"""Sensor faults and the injector that schedules them.

A fault is a small object that maps the healthy sensor value to the faulty one, or to None when
the sensor's frame must not be sent at all. The injector holds at most one active fault per
target, takes commands from code, the CLI (scheduled) or the FI_Command CAN frame, and keeps a
log of every change for the run summary.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Protocol

import numpy as np


class FaultKind(enum.IntEnum):
    """Values match FI_Kind in dbc/vecu.dbc."""

    CLEAR = 0
    DEAD = 1
    STUCK = 2
    FRAMES_STOP = 3
    OFFSET = 4
    GAIN = 5
    NOISE = 6
    SHORT_SUPPLY = 7


class FaultTarget(enum.IntEnum):
    """Values match FI_Target in dbc/vecu.dbc."""

    TPS = 1
    SWA = 2


DEFAULT_VALUES = {FaultKind.OFFSET: 0.5, FaultKind.GAIN: 0.5, FaultKind.NOISE: 0.3}
SUPPLY_V = 5.0


class Fault(Protocol):
    kind: FaultKind

    def apply(self, value: float) -> float | None: ...


@dataclass
class Dead:
    """Open circuit: the input is pulled to 0 V (gain G = 0)."""

    kind: FaultKind = FaultKind.DEAD

    def apply(self, value: float) -> float | None:
        return 0.0


@dataclass
class ShortToSupply:
    kind: FaultKind = FaultKind.SHORT_SUPPLY

    def apply(self, value: float) -> float | None:
        return SUPPLY_V


@dataclass
class Stuck:
    """Output frozen at the first value seen after activation."""

    held: float | None = None
    kind: FaultKind = FaultKind.STUCK

    def apply(self, value: float) -> float | None:
        if self.held is None:
            self.held = value
        return self.held


@dataclass
class FramesStop:
    kind: FaultKind = FaultKind.FRAMES_STOP

    def apply(self, value: float) -> float | None:
        return None


@dataclass
class Offset:
    volts: float
    kind: FaultKind = FaultKind.OFFSET

    def apply(self, value: float) -> float | None:
        return value + self.volts


@dataclass
class Gain:
    """Sensor model Y = G * Y0 with 0 <= G <= 1 (G = 0: dead)."""

    gain: float
    kind: FaultKind = FaultKind.GAIN

    def __post_init__(self) -> None:
        if not 0.0 <= self.gain <= 1.0:
            raise ValueError(f"gain fault: G must be in [0, 1], got {self.gain}")

    def apply(self, value: float) -> float | None:
        return self.gain * value


@dataclass
class Noise:
    sigma_v: float
    rng: np.random.Generator
    kind: FaultKind = FaultKind.NOISE

    def apply(self, value: float) -> float | None:
        return value + self.sigma_v * float(self.rng.standard_normal())


def make_fault(kind: FaultKind, value: float | None, rng: np.random.Generator) -> Fault:
    """Build a fault; value is the offset (V), the gain G, or the noise sigma (V)."""
    if value is None:
        value = DEFAULT_VALUES.get(kind, 0.0)
    if kind == FaultKind.DEAD:
        return Dead()
    if kind == FaultKind.SHORT_SUPPLY:
        return ShortToSupply()
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
            raise ValueError(f"noise fault: sigma must be >= 0, got {value}")
        return Noise(value, rng)
    raise ValueError(f"no fault of kind {kind!r}")


def parse_kind(name: str) -> FaultKind:
    try:
        return FaultKind[name.strip().upper().replace("-", "_")]
    except KeyError:
        names = ", ".join(k.name.lower() for k in FaultKind if k != FaultKind.CLEAR)
        raise ValueError(f"unknown fault kind {name!r} (known: {names})") from None


@dataclass(frozen=True)
class FaultEvent:
    t_ns: int
    target: FaultTarget
    kind: FaultKind
    value: float | None
    source: str  # "api", "schedule" or "can"


class FaultInjector:
    """Active faults per target; apply() is called on every sensor sample."""

    def __init__(self, rng: np.random.Generator) -> None:
        self._rng = rng
        self._active: dict[FaultTarget, Fault] = {}
        self.events: list[FaultEvent] = []
        self.rejected_commands = 0

    def inject(self, t_ns: int, target: FaultTarget, kind: FaultKind,
               value: float | None = None, source: str = "api") -> None:
        if kind == FaultKind.CLEAR:
            self._active.pop(target, None)
        else:
            self._active[target] = make_fault(kind, value, self._rng)
        self.events.append(FaultEvent(t_ns, target, kind, value, source))

    def on_command(self, t_ns: int, target: int, kind: int, value: float) -> bool:
        """FI_Command frame; returns False (and counts) for an unknown target/kind or bad value."""
        try:
            self.inject(t_ns, FaultTarget(int(target)), FaultKind(int(kind)), value, source="can")
        except ValueError:
            self.rejected_commands += 1
            return False
        return True

    def apply(self, target: FaultTarget, value: float) -> float | None:
        fault = self._active.get(target)
        return value if fault is None else fault.apply(value)

    def active(self, target: FaultTarget) -> FaultKind | None:
        fault = self._active.get(target)
        return None if fault is None else fault.kind

    def first_fault_ns(self, target: FaultTarget) -> int | None:
        for ev in self.events:
            if ev.target == target and ev.kind != FaultKind.CLEAR:
                return ev.t_ns
        return None
