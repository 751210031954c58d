"""Fault library and the injector that schedules faults on sensor signals and frames (the kinds
and what each does: vecu.fault_kinds, re-exported here).

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
from dataclasses import dataclass
from typing import TYPE_CHECKING

import can
import numpy as np

from vecu.errors import BadArgumentError
from vecu.fault_kinds import (  # noqa: F401 (re-exported: the fault library's public names)
    E2E_KINDS,
    FRAME_KINDS,
    SUPPLY_V,
    Fault,
    FaultKind,
    FrameFault,
    KindSpec,
    SignalFault,
    make_fault,
    with_data,
)

if TYPE_CHECKING:
    from vecu.codec import DbcCodec, FrameCodec


class FaultTarget(enum.IntEnum):
    """Values match FI_Target in dbc/vecu.dbc (the FI_Command frame's short names)."""

    TPS = 1
    SWA = 2
    WHEEL = 3
    ACCEL = 4




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
        raise BadArgumentError(f"bad fault target {text!r}: expected tps, swa, wheel, accel, "
                               "MESSAGE or MESSAGE.SIGNAL")
    return FaultSite(parts[0], parts[1] if len(parts) == 2 else None)


def parse_kind(name: str) -> FaultKind:
    try:
        return FaultKind[name.strip().upper().replace("-", "_")]
    except KeyError:
        names = ", ".join(k.name.lower() for k in FaultKind if k != FaultKind.CLEAR)
        raise BadArgumentError(f"unknown fault kind {name!r} (known: {names})") from None


# --------------------------------------------------------------------------- signal faults
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
            raise BadArgumentError(f"fault target {site.name!r}: no message {site.message!r} in "
                                   "the DBC")
        fc = self._codec[site.message]
        if site.signal is not None and site.signal not in fc.ranges:
            raise BadArgumentError(f"fault target {site.name!r}: message {site.message} has no "
                                   f"signal {site.signal!r}")
        return fc

    def check(self, target: str | FaultSite | FaultTarget, kind: FaultKind,
              value: float | None = None) -> FaultSite:
        """Raise BadArgumentError unless `kind` (with `value`) can act on `target`; return the
        site."""
        site = parse_site(target)
        fc = self._message(site)
        if kind == FaultKind.CLEAR:
            return site
        if kind in E2E_KINDS and fc.e2e is None:
            raise BadArgumentError(f"fault {kind.name.lower()} on {site.name!r}: message "
                                   f"{site.message} has no E2E CRC/alive counter")
        if kind in FRAME_KINDS:
            kind.checked(value)
        else:
            if site.signal is None:
                raise BadArgumentError(f"signal fault {kind.name.lower()} needs MESSAGE.SIGNAL, "
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
            self._active[part] = make_fault(kind, value, self._rng)
        elif kind in FRAME_KINDS:
            self._frame[key] = FrameFault(kind, kind.checked(value), fc, self._rng)
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
                values[name] = fc.fit(name, v)  # wrapped (counters) or saturated
            msg = with_data(msg, fc.encode(values))
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
    fc = codec[site.message] if site.message in codec else None  # noqa: SIM401 (no .get)
    index = 0
    if fc is not None and site.signal is not None:
        names = [s.name for s in fc.signals]
        index = names.index(site.signal) + 1 if site.signal in names else 0
    if value is None:
        value = FaultKind(kind).default if kind in FaultKind._value2member_map_ else 0.0
    return {"FI_EvMessageId": fc.frame_id & 0xFFFF if fc is not None else 0,
            "FI_EvSignal": index, "FI_EvKind": kind, "FI_EvActive": active,
            "FI_EvSource": FAULT_SOURCES.get(source, 3), "FI_EvValue": value}
