"""The restbus node: every planned message on its own task of the shared scheduler.

Each message is a chained task released on absolute deadlines (release k at k x its cycle;
a disturbance may stretch the cycle); a release encodes the signals' values at that time (start
values or VALUES.toml sources, the next multiplexer selection), writes the E2E counter and
protects the payload with the message's profile (vecu.e2e, autosar-e2e), passes it through the
active disturbances and sends it. On-change messages are polled at their cycle and sent when
their payload changes (and once at the start); if-active messages are sent at their cycle while
a signal differs from its start value. Disturbance starts and ends go on the bus as FI_Event
frames (dbc/vecu.dbc), the same record vecu's own faults leave.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import Any, Protocol

import can
import numpy as np
from can.util import CAN_FD_DLC, dlc2len, len2dlc

from vecu.can_message import message
from vecu.codec import FrameCodec
from vecu.e2e import E2EProtection
from vecu.errors import BadArgumentError
from vecu.faults import FAULT_SOURCES, ScheduledFault
from vecu.restbus import disturb
from vecu.restbus.values import Source

NS_PER_S = 1_000_000_000
SEND_TYPES = ("cyclic", "on_change", "if_active")
_log = logging.getLogger("vecu.restbus")


@dataclass(frozen=True)
class MessagePlan:
    """One message of a restbus: what to send, how often, with which protection."""

    codec: FrameCodec
    period_ns: int
    send_type: str                       # one of SEND_TYPES
    e2e: E2EProtection | None
    sources: dict[str, Source]           # every signal's value(t_s)
    start: dict[str, float]              # start values (if-active compares against them)
    offset_ns: int = 0                   # first release (a stagger spreads the bus load)
    e2e_source: str = "none"             # E2E.toml | ARXML (category) | vecu layout | none[: why]

    @property
    def name(self) -> str:
        return self.codec.name


@dataclass
class MessageState:
    counter: int = 0
    mux: int = 0
    sent: int = 0
    skipped: int = 0  # releases skipped on the wall clock (late by a whole cycle)
    last: bytes | None = None
    active: dict[str, disturb.Disturbance] = field(default_factory=dict)
    times_ns: list[int] | None = None  # send times (kept when the node records them)


@dataclass(frozen=True)
class DisturbanceEvent:
    t_ns: int
    message: str
    signal: str | None
    kind: str
    value: float | None
    active: bool
    source: str


class TaskScheduler(Protocol):  # vecu.scheduler.Scheduler, as far as the restbus uses it
    def chain(self, first_ns: int, fn: Callable[[int], int | None], *, name: str,
              priority: int = 0) -> Any: ...

    def at(self, t_ns: int, fn: Callable[[int], None], *, name: str,
           priority: int = 0) -> Any: ...


class RestbusNode:
    """Sends the plans' frames through `send`; disturb() / clear() from code, a scenario or a
    live command. fi_event (vecu's FI_Event codec), when given, records each start and end."""

    def __init__(self, plans: list[MessagePlan], send: Callable[[can.Message], bool],
                 rng: np.random.Generator, fi_event: FrameCodec | None = None,
                 keep_times: bool = False, clock: Any = None) -> None:
        self.plans = plans
        self.states = [MessageState(times_ns=[] if keep_times else None) for _ in plans]
        self._send = send
        # now_ns() stamps the kept send times (else the release time); on a wall clock a
        # message late by a whole cycle skips the releases it missed (as Scheduler.every)
        self._clock = clock
        self._rng = rng
        self._fi_event = fi_event
        self._sched: TaskScheduler | None = None
        self._by_name = {p.name: i for i, p in enumerate(plans)}
        self._protect = [None if p.e2e is None else p.e2e.protector() for p in plans]
        self.events: list[DisturbanceEvent] = []
        self.frames_sent = 0
        self.encode_errors = 0
        self.skipped = 0  # releases skipped on the wall clock (a stall longer than a cycle)

    # ------------------------------------------------------------------ schedule
    def schedule(self, sched: TaskScheduler, priority: int = 0, start_ns: int = 0) -> None:
        self._sched = sched
        for i, plan in enumerate(self.plans):
            sched.chain(start_ns + plan.offset_ns, self._release_fn(i),
                        name=f"restbus-{plan.name}", priority=priority)

    def _release_fn(self, i: int) -> Callable[[int], int | None]:
        plan, st = self.plans[i], self.states[i]

        def release(t_ns: int) -> int:
            period = plan.period_ns
            delay = 0
            for d in st.active.values():
                period = d.period(period)
                delay = max(delay, d.delay_ns)
            msg = self._frame(i, t_ns)
            if msg is not None:
                if delay and self._sched is not None:
                    msg.timestamp = (t_ns + delay) / NS_PER_S
                    self._sched.at(t_ns + delay, partial(self._delayed, st, msg),
                                   name=f"restbus-delayed-{plan.name}")
                else:
                    self._out(st, msg, t_ns)
            for kind in [k for k, d in st.active.items() if d.done]:
                self._end(t_ns, i, kind, "api")
            nxt = t_ns + period
            clock = self._clock
            if clock is not None and clock.realtime:  # late by a whole cycle: skip, no burst
                now = clock.now_ns()
                if now > nxt:
                    missed = (now - nxt) // period + 1
                    nxt += missed * period
                    self.skipped += missed
                    st.skipped += missed
            return nxt
        return release

    def _delayed(self, st: MessageState, msg: can.Message, t_ns: int) -> None:
        """A delayed frame's own task (the delay disturbance)."""
        self._out(st, msg, t_ns)

    def _out(self, st: MessageState, msg: can.Message, t_ns: int) -> None:
        if self._send(msg):
            self.frames_sent += 1
            st.sent += 1
            if st.times_ns is not None:
                st.times_ns.append(self._clock.now_ns() if self._clock is not None else t_ns)

    # -------------------------------------------------------------------- frames
    def _frame(self, i: int, t_ns: int) -> can.Message | None:
        plan, st = self.plans[i], self.states[i]
        t_s = t_ns / NS_PER_S
        fc = plan.codec
        values = {name: src(t_s) for name, src in plan.sources.items()}
        if fc.mux_selections:
            values.update(fc.mux_selections[st.mux % len(fc.mux_selections)])
            st.mux += 1
        active = st.active.values()
        for d in active:
            d.values(values)
        if plan.send_type == "if_active" and all(
                values[k] == v for k, v in plan.start.items() if k in values):
            return None
        try:
            buf = bytearray(fc.encode(values))
        except Exception as exc:  # noqa: BLE001 - cantools refused the values: counted
            self.encode_errors += 1
            if self.encode_errors <= 10:
                _log.warning("restbus: %s not encoded: %s", fc.name, exc)
            return None
        if plan.send_type == "on_change":
            key = bytes(buf)
            if key == st.last:
                return None
            st.last = key
        if not all(d.gate() for d in list(active)):
            return None
        prot = plan.e2e
        if prot is not None:
            modulo = prot.counter_modulo
            c = st.counter % modulo
            for d in active:
                c = d.counter(c, modulo)
            prot.set_counter(buf, c)
            self._protect[i](buf)  # type: ignore[misc]  # set wherever plan.e2e is
            step = 1
            for d in active:
                a = d.advance()
                if a != 1:
                    step = a
            st.counter = (st.counter + step) % modulo
        for d in active:
            buf = d.payload(buf, prot)
        if fc.is_fd and len(buf) not in CAN_FD_DLC:  # e.g. 10 bytes: padded to 12, a valid length
            buf += bytes(dlc2len(len2dlc(len(buf))) - len(buf))
        return message(t_s, fc.frame_id, fc.is_extended, buf, fc.is_fd)

    # ---------------------------------------------------------------- disturbances
    def resolve(self, target: str) -> tuple[int, str | None]:
        """'MESSAGE', 'MESSAGE.SIGNAL' or a CAN ID ('0x1B0') -> (plan index, signal)."""
        text = target.strip()
        msg, _, sig = text.partition(".")
        i = self._by_name.get(msg)
        if i is None:
            try:
                can_id = int(text, 0)
            except ValueError:
                can_id = None
            i = next((j for j, p in enumerate(self.plans) if p.codec.frame_id == can_id), None)
            sig = ""
        if i is None:
            raise BadArgumentError(f"restbus disturbance target {target!r}: no such message in "
                                   "the restbus (names or CAN IDs of the messages it sends)")
        if sig and sig not in self.plans[i].sources:
            raise BadArgumentError(f"restbus disturbance target {target!r}: message "
                                   f"{self.plans[i].name} has no signal {sig!r}")
        return i, sig or None

    def check(self, target: str, kind: str, value: float | None = None) -> None:
        """Raise BadArgumentError unless `kind` (with `value`) can act on `target`."""
        i, sig = self.resolve(target)
        k = disturb.KINDS.get(kind)
        plan = self.plans[i]
        if k is not None and k.needs == "e2e" and plan.e2e is None:
            why = plan.e2e_source.removeprefix("none").removeprefix(": ")
            raise BadArgumentError(f"restbus disturbance {kind} on {target!r}: message "
                                   f"{plan.name} has no E2E protection ({why + '; ' if why else ''}"
                                   "give it an [[e2e]] entry in E2E.toml)")
        disturb.make(kind, value, self._rng, sig)

    def disturb(self, t_ns: int, target: str, kind: str, value: float | None = None,
                source: str = "api") -> None:
        self.check(target, kind, value)
        i, sig = self.resolve(target)
        d = disturb.make(kind, value, self._rng, sig)
        self.states[i].active[kind] = d
        self._record(t_ns, i, sig, kind, d.value, True, source)

    def clear(self, t_ns: int, target: str, kind: str | None = None,
              source: str = "api") -> None:
        i, _ = self.resolve(target)
        for k in [k for k in self.states[i].active if kind is None or k == kind]:
            self._end(t_ns, i, k, source)

    def _end(self, t_ns: int, i: int, kind: str, source: str) -> None:
        d = self.states[i].active.pop(kind)
        self._record(t_ns, i, d.signal, kind, d.value, False, source)

    def _record(self, t_ns: int, i: int, sig: str | None, kind: str, value: float,
                active: bool, source: str) -> None:
        plan = self.plans[i]
        self.events.append(DisturbanceEvent(t_ns, plan.name, sig, kind, value, active, source))
        if self._fi_event is None:
            return
        names = [s.name for s in plan.codec.signals]
        self._send(self._fi_event.frame({
            "FI_EvMessageId": plan.codec.frame_id & 0xFFFF,
            "FI_EvSignal": names.index(sig) + 1 if sig in names else 0,
            "FI_EvKind": disturb.KINDS[kind].code, "FI_EvActive": int(active),
            "FI_EvSource": FAULT_SOURCES.get(source, 3),
            "FI_EvValue": max(-1e6, min(1e6, value))}, t_ns / NS_PER_S))

    def summary(self) -> dict[str, Any]:
        return {"messages": len(self.plans), "frames_sent": self.frames_sent,
                "encode_errors": self.encode_errors, "skipped_releases": self.skipped,
                "per_message": {p.name: s.sent for p, s in zip(self.plans, self.states)},
                "e2e": {p.name: (f"{p.e2e.profile} from {p.e2e_source}" if p.e2e is not None
                                 else p.e2e_source) for p in self.plans},
                "disturbances": [{"t_s": e.t_ns / NS_PER_S, "message": e.message,
                                  "signal": e.signal, "kind": e.kind, "value": e.value,
                                  "active": e.active, "source": e.source}
                                 for e in self.events]}


def schedule_disturbances(sched: TaskScheduler, node: RestbusNode,
                          timeline: tuple[ScheduledFault, ...], priority: int = -1,
                          source: str = "scenario") -> None:
    """Start (and end) each timeline entry; each is checked against the restbus now."""
    for d in timeline:
        node.check(d.target, d.kind, d.value)
        start: Callable[[int], None] = partial(_start, node, d, source)
        sched.at(round(d.start_s * NS_PER_S), start, name=f"disturb-{d.kind}-{d.target}",
                 priority=priority)
        if d.end_s is not None:
            end: Callable[[int], None] = partial(_end, node, d, source)
            sched.at(round(d.end_s * NS_PER_S), end, name=f"undisturb-{d.kind}-{d.target}",
                     priority=priority)


def _start(node: RestbusNode, d: ScheduledFault, source: str, t_ns: int) -> None:
    node.disturb(t_ns, d.target, d.kind, d.value, source)


def _end(node: RestbusNode, d: ScheduledFault, source: str, t_ns: int) -> None:
    node.clear(t_ns, d.target, d.kind, source)
