"""Fault library and the injector that schedules faults on sensor signals and frames.

Two levels, one injector:

- **Signal faults** map a healthy physical value to the faulty one (dead, short to supply, stuck,
  offset, gain, noise, drift, quantisation). On the TPS and SWA sensors the plant parts apply them
  before encoding (`apply()`, the fast path); on any other DBC signal the plant's send stage
  decodes the targeted frame, applies the fault and re-encodes it (E2E CRC recomputed: the fault
  sits in the sensor, before the protection).
- **Frame faults** act on a message's frames in the plant's send stage: frames stop, intermittent
  dropout, delay, wrong alive counter, bad CRC, burst (each frame repeated), babbling node
  (garbage frames with the message's ID) and bus error frames.

The injector holds at most one signal fault per signal and one frame fault per message, takes
commands from code, scenarios, the CLI or the FI_Command CAN frame, and logs every change
(`events`); the plant announces each change on the bus as an FI_Event frame (dbc/vecu.dbc).
With no frame-stage fault active the plant's send path is untouched (`frame_stage_active`).
"""

from __future__ import annotations

import enum
import heapq
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import can
import numpy as np

if TYPE_CHECKING:
    from vecu.codec import DbcCodec, FrameCodec


class FaultKind(enum.IntEnum):
    """Values match FI_Kind / FI_EvKind in dbc/vecu.dbc."""

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


class FaultTarget(enum.IntEnum):
    """Values match FI_Target in dbc/vecu.dbc (the FI_Command frame's short names)."""

    TPS = 1
    SWA = 2
    WHEEL = 3
    ACCEL = 4


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


@dataclass(frozen=True)
class FaultSite:
    """Where a fault acts: a DBC message and, for signal faults, one of its signals."""

    message: str
    signal: str | None = None

    @property
    def name(self) -> str:
        alias = _ALIAS_OF.get(self)
        if alias:
            return alias
        return self.message if self.signal is None else f"{self.message}.{self.signal}"

    @property
    def frame(self) -> FaultSite:
        return FaultSite(self.message)


SITE_ALIASES = {"tps": FaultSite("TPS_Sensor", "TPS_Voltage"),
                "swa": FaultSite("SWA_Sensor", "SWA_Angle"),
                "wheel": FaultSite("ESC_Motion", "ESC_WheelSpeed"),
                "accel": FaultSite("ESC_Motion", "ESC_LongAccel")}
_ALIAS_OF = {site: name for name, site in SITE_ALIASES.items()}
TARGET_SITES = {t: SITE_ALIASES[t.name.lower()] for t in FaultTarget}
# signals the plant parts fault themselves before encoding (fast path, see module docstring)
_PART_SITES = {SITE_ALIASES["tps"]: FaultTarget.TPS, SITE_ALIASES["swa"]: FaultTarget.SWA}
_PART_MESSAGES = {site.message: target for site, target in _PART_SITES.items()}


def _part_target(site: FaultSite, kind: FaultKind | None) -> FaultTarget | None:
    """The part that applies this fault itself: its sensor signal's signal faults, and frames
    stop on its message (the sensor stops sending; its alive counter does not advance)."""
    if kind == FaultKind.FRAMES_STOP:
        return _PART_MESSAGES.get(site.message)
    if kind is None or kind not in FRAME_KINDS:
        return _PART_SITES.get(site)
    return None


def parse_site(text: str | FaultSite | FaultTarget) -> FaultSite:
    """'tps', 'swa', 'wheel', 'accel', 'Message' or 'Message.Signal' (checked against the DBC
    when the injector resolves it)."""
    if isinstance(text, FaultSite):
        return text
    if isinstance(text, FaultTarget):
        return TARGET_SITES[text]
    alias = SITE_ALIASES.get(text.strip().lower())
    if alias is not None:
        return alias
    parts = text.strip().split(".")
    if len(parts) > 2 or not all(parts):
        raise ValueError(f"bad fault target {text!r}: expected tps, swa, wheel, accel, "
                         "MESSAGE or MESSAGE.SIGNAL")
    return FaultSite(parts[0], parts[1] if len(parts) == 2 else None)


def parse_kind(name: str) -> FaultKind:
    try:
        return FaultKind[name.strip().upper().replace("-", "_")]
    except KeyError:
        names = ", ".join(k.name.lower() for k in FaultKind if k != FaultKind.CLEAR)
        raise ValueError(f"unknown fault kind {name!r} (known: {names})") from None


# --------------------------------------------------------------------------- signal faults
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
            raise ValueError(f"gain fault: G must be in [0, 1], got {self.gain}")

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
        return round(value / self.step) * self.step


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
                return [_with_data(msg, data)]
            return [msg]
        if kind == FaultKind.WRONG_COUNTER:  # counter frozen at its value when the fault began
            fc = self.codec
            values = fc.decode(msg.data)
            if self._held_counter is None:
                self._held_counter = int(values[fc.e2e.counter_signal])
            values[fc.e2e.counter_signal] = self._held_counter
            return [_with_data(msg, fc.encode(values))]
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


def _with_data(msg: can.Message, data: bytes | bytearray) -> can.Message:
    return can.Message(timestamp=msg.timestamp, arbitration_id=msg.arbitration_id,
                       is_extended_id=msg.is_extended_id, data=bytes(data), is_fd=msg.is_fd,
                       check=False)


def make_fault(kind: FaultKind, value: float | None, rng: np.random.Generator,
               t_ns: int = 0, supply: float = SUPPLY_V) -> Fault:
    """Build a signal fault (or FramesStop, for the part fast path); see DEFAULT_VALUES."""
    if value is None:
        value = DEFAULT_VALUES.get(kind, 0.0)
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
            raise ValueError(f"noise fault: sigma must be >= 0, got {value}")
        return Noise(value, rng)
    if kind == FaultKind.DRIFT:
        return Drift(value, t_ns)
    if kind == FaultKind.QUANTISE:
        if not value > 0:
            raise ValueError(f"quantise fault: step must be > 0, got {value}")
        return Quantise(value)
    raise ValueError(f"no signal fault of kind {kind.name.lower()!r}")


def check_frame_value(kind: FaultKind, value: float) -> None:
    limits = {FaultKind.DROPOUT: (0.0, 1.0), FaultKind.BAD_CRC: (0.0, 1.0),
              FaultKind.DELAY: (0.0, 10_000.0), FaultKind.BURST: (1.0, 100.0),
              FaultKind.BABBLE: (0.0, 100.0), FaultKind.ERROR_FRAMES: (0.0, 100.0)}
    lo, hi = limits.get(kind, (-math.inf, math.inf))
    if not lo <= value <= hi:
        raise ValueError(f"{kind.name.lower()} fault: {VALUE_MEANING[kind]} must be in "
                         f"[{lo:g}, {hi:g}], got {value}")


@dataclass(frozen=True)
class FaultEvent:
    t_ns: int
    target: FaultSite
    kind: FaultKind  # CLEAR when faults ended; `cleared` then names them
    value: float | None
    source: str  # "api", "schedule", "scenario" or "can"
    cleared: tuple[FaultKind, ...] = ()


@dataclass(frozen=True)
class ScheduledFault:
    """One timeline entry: `kind` on `target` from start_s to end_s (None: to the end)."""

    target: str
    kind: str
    start_s: float
    end_s: float | None = None
    value: float | None = None


class FaultInjector:
    """Active faults; `apply()` is called by the TPS/SWA parts on every sample, `process()` /
    `per_tick()` by the plant's send stage while `frame_stage_active`."""

    def __init__(self, rng: np.random.Generator, codec: DbcCodec | None = None) -> None:
        self._rng = rng
        self._codec = codec
        self._active: dict[FaultTarget, Fault] = {}  # part fast path
        self._signal: dict[tuple[int, bool], dict[str, Fault]] = {}  # frame stage, by CAN ID
        self._frame: dict[tuple[int, bool], FrameFault] = {}
        self._delayed: list[tuple[int, int, can.Message]] = []
        self._seq = 0
        self.events: list[FaultEvent] = []
        self.rejected_commands = 0
        self.now_ns = 0  # set by the plant each tick (drift faults read it)
        self.frame_stage_active = False

    def bind(self, codec: DbcCodec) -> None:
        self._codec = codec

    def _message(self, site: FaultSite) -> FrameCodec:
        if self._codec is None:
            from vecu.codec import DbcCodec
            self._codec = DbcCodec()
        if site.message not in self._codec:
            raise ValueError(f"fault target {site.name!r}: no message {site.message!r} in the DBC")
        fc = self._codec[site.message]
        if site.signal is not None and site.signal not in fc.ranges:
            raise ValueError(f"fault target {site.name!r}: message {site.message} has no signal "
                             f"{site.signal!r}")
        return fc

    def check(self, target: str | FaultSite | FaultTarget, kind: FaultKind,
              value: float | None = None) -> FaultSite:
        """Raise ValueError unless `kind` (with `value`) can act on `target`; return the site."""
        site = parse_site(target)
        fc = self._message(site)
        if kind == FaultKind.CLEAR:
            return site
        if kind in E2E_KINDS and fc.e2e is None:
            raise ValueError(f"fault {kind.name.lower()} on {site.name!r}: message "
                             f"{site.message} has no E2E CRC/alive counter")
        if kind in FRAME_KINDS:
            check_frame_value(kind, DEFAULT_VALUES.get(kind, 0.0) if value is None else value)
        else:
            if site.signal is None:
                raise ValueError(f"signal fault {kind.name.lower()} needs MESSAGE.SIGNAL, "
                                 f"got {site.name!r}")
            make_fault(kind, value, self._rng)  # validates the value
        return site

    def inject(self, t_ns: int, target: str | FaultSite | FaultTarget, kind: FaultKind,
               value: float | None = None, source: str = "api") -> None:
        if kind == FaultKind.CLEAR:
            self.clear(t_ns, target, None, source)
            return
        site = self.check(target, kind, value)
        self.now_ns = max(self.now_ns, t_ns)
        fc = self._message(site)
        key = (fc.frame_id, fc.is_extended)
        part = _part_target(site, kind)
        if part is not None and kind == FaultKind.FRAMES_STOP:
            self._active[part] = FramesStop()
        elif kind in FRAME_KINDS:
            v = DEFAULT_VALUES.get(kind, 0.0) if value is None else value
            self._frame[key] = FrameFault(kind, v, fc, self._rng)
        else:
            supply = SUPPLY_V if site == SITE_ALIASES["tps"] else fc.ranges[site.signal][1]
            fault = make_fault(kind, value, self._rng, t_ns,
                               SUPPLY_V if supply is None else supply)
            if part is not None:
                self._active[part] = fault
            else:
                self._signal.setdefault(key, {})[site.signal] = fault
        self.events.append(FaultEvent(t_ns, site, kind, value, source))
        self._update_stage()

    def clear(self, t_ns: int, target: str | FaultSite | FaultTarget,
              kind: FaultKind | None = None, source: str = "api") -> None:
        """End the fault of `kind` on target (None: every fault on it and on its message)."""
        site = parse_site(target)
        fc = self._message(site)
        key = (fc.frame_id, fc.is_extended)
        ended: list[FaultKind] = []
        if kind is None or kind in FRAME_KINDS:
            frame = self._frame.get(key)
            if frame is not None and (kind is None or frame.kind == kind):
                ended.append(self._frame.pop(key).kind)
        part = (_PART_MESSAGES.get(site.message) if kind is None
                else _part_target(site, kind))
        if part is not None and part in self._active and (
                kind is None or self._active[part].kind == kind):
            ended.append(self._active.pop(part).kind)
        if kind is None and site.signal is None:
            ended.extend(f.kind for f in self._signal.pop(key, {}).values())
        if ((kind is None or kind not in FRAME_KINDS) and site.signal is not None
                and site.signal in self._signal.get(key, {})):
            ended.append(self._signal[key].pop(site.signal).kind)
            if not self._signal[key]:
                del self._signal[key]
        self.events.append(FaultEvent(t_ns, site, FaultKind.CLEAR, None, source, tuple(ended)))
        self._update_stage()

    def _update_stage(self) -> None:
        self.frame_stage_active = bool(self._frame or self._signal or self._delayed)

    def on_command(self, t_ns: int, target: int, kind: int, value: float) -> bool:
        """FI_Command frame; returns False (and counts) for an unknown target/kind or bad value."""
        try:
            self.inject(t_ns, FaultTarget(int(target)), FaultKind(int(kind)), value, source="can")
        except ValueError:
            self.rejected_commands += 1
            return False
        return True

    # ------------------------------------------------------------------ fast path
    def apply(self, target: FaultTarget, value: float) -> float | None:
        fault = self._active.get(target)
        return value if fault is None else fault.apply(value, self.now_ns)

    def active(self, target: FaultTarget) -> FaultKind | None:
        fault = self._active.get(target)
        if fault is not None:
            return fault.kind
        site = TARGET_SITES[target]
        fc = self._message(site)
        frame = self._frame.get((fc.frame_id, fc.is_extended))
        return None if frame is None else frame.kind

    def first_fault_ns(self, target: FaultTarget | FaultSite | str) -> int | None:
        """Start of the first fault on the target's message (signal or frame fault)."""
        message = parse_site(target).message
        for ev in self.events:
            if ev.target.message == message and ev.kind != FaultKind.CLEAR:
                return ev.t_ns
        return None

    # ---------------------------------------------------------------- frame stage
    def process(self, msg: can.Message) -> list[can.Message]:
        """Frames to send now for one outgoing frame (signal faults, then the frame fault)."""
        key = (msg.arbitration_id, msg.is_extended_id)
        signals = self._signal.get(key)
        if signals:
            fc = self._codec.by_id[key]
            values = fc.decode(msg.data)
            for name, fault in signals.items():
                v = fault.apply(values[name], self.now_ns)
                if v is None:
                    return []
                values[name] = v
            msg = _with_data(msg, fc.encode(values))
        frame = self._frame.get(key)
        if frame is None:
            return [msg]
        if frame.kind == FaultKind.DELAY:
            due = self.now_ns + round(frame.value * 1e6)
            self._seq += 1
            heapq.heappush(self._delayed, (due, self._seq, msg))
            self.frame_stage_active = True
            return []
        return frame.process(msg)

    def per_tick(self, t_ns: int) -> list[can.Message]:
        """Delayed frames now due, babble and error frames; call once per plant tick."""
        out: list[can.Message] = []
        delayed = self._delayed
        while delayed and delayed[0][0] <= t_ns:
            _, _, msg = heapq.heappop(delayed)
            msg.timestamp = t_ns * 1e-9
            out.append(msg)
        for frame in self._frame.values():
            if frame.kind in (FaultKind.BABBLE, FaultKind.ERROR_FRAMES):
                out.extend(frame.per_tick(t_ns))
        if not delayed:
            self._update_stage()
        return out


FAULT_SOURCES = {"api": 0, "schedule": 1, "scenario": 1, "can": 2}


def fault_event_signals(codec: DbcCodec, site: FaultSite, kind: int, active: int, source: str,
                        value: float | None) -> dict[str, float]:
    """FI_Event signals for one fault start (active=1) or end (active=0); see dbc/vecu.dbc."""
    fc = codec[site.message] if site.message in codec else None  # noqa: SIM401
    index = 0
    if fc is not None and site.signal is not None:
        names = [s.name for s in fc.message.signals]
        index = names.index(site.signal) + 1 if site.signal in names else 0
    if value is None:
        value = DEFAULT_VALUES.get(FaultKind(kind), 0.0) if kind in FaultKind._value2member_map_ \
            else 0.0
    return {"FI_EvMessageId": fc.frame_id & 0xFFFF if fc is not None else 0,
            "FI_EvSignal": index, "FI_EvKind": kind, "FI_EvActive": active,
            "FI_EvSource": FAULT_SOURCES.get(source, 3), "FI_EvValue": value}
