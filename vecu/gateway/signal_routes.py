"""Signal routes: signals unpacked from source messages (one database) and repacked into one
target message (another database), as AUTOSAR Com's signal gateway does (ComGwMapping).

- Values travel as physical values: the source decoded (scale, offset), converted between the
  units the two databases name (routes_config.UNIT_CONVERSIONS), saturated to the target
  signal's range (each clipped value counted), encoded with the target's scale and offset.
  Choices map by name; multiplexed sources give their signals when their selector does, and a
  multiplexed target is sent with the selector value its mapped signals need.
- E2E: a source message whose database names a protection (an ARXML's E2E properties, else
  vecu's `<prefix>_CRC` / `_AliveCounter` layout) is checked (autosar-e2e through vecu.e2e: the
  CRC and what else the profile's header holds, then its alive counter: a repeated counter is a
  stale frame); a frame that fails is dropped and counted, its values unused.
  The target is protected with the route's own profile (AUTOSAR E2E, the gateway as its new
  sender), the counter advancing by one per frame sent.
- Sending: cyclic (the target's database cycle time), on_change (a frame when a value changed)
  or both; min_interval limits either (the latest values win). A frame's latency is the age of
  the newest source frame it carries (a cyclic repeat with nothing new: none recorded). A source message silent for
  timeout_ms: its target signals take the target's initial (start) value until it returns.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

import can

from vecu.can_message import message
from vecu.codec import DbcCodec, FrameCodec
from vecu.e2e import AliveCounterCheck, E2EConfigError, E2EProtection
from vecu.gateway.route_stats import RouteStats
from vecu.gateway.routes import SignalMap, SignalRoute
from vecu.restbus.spec import arxml_protection


class SignalRouter:
    """One signal route: offer() each frame of its source messages, tick() each 1 ms."""

    def __init__(self, route: SignalRoute, source: DbcCodec, target: DbcCodec) -> None:
        self.route = route
        self.stats = RouteStats()
        self.target = fc = target[route.message]
        self._sources: dict[int, tuple[FrameCodec, list[SignalMap]]] = {}
        self._checks: dict[int, Callable[[bytes | bytearray], bool]] = {}
        self._counters: dict[int, tuple[E2EProtection, AliveCounterCheck]] = {}
        for m in route.signals:
            sfc = source[m.message]
            self._sources.setdefault(sfc.frame_id, (sfc, []))[1].append(m)
            prot = source_protection(sfc)
            if prot is not None:
                self._checks[sfc.frame_id] = prot.checker()
                # a repeated counter is a stale frame (E2E status REPEATED); a jump is frames
                # lost on the way (OK, some lost): its data is fresh and is used
                self._counters[sfc.frame_id] = (prot, AliveCounterCheck(
                    prot.counter_modulo, max_delta=prot.counter_modulo - 1))
        self._initial = {m.target: fc.start_values[m.target] for m in route.signals}
        self.values: dict[str, float] = dict(fc.start_values)
        self.values.update({name: float(v) for name, v in route.mux})
        self._ranges = {m.target: _bounds(fc, m.target) for m in route.signals}
        self._queue: deque[tuple[int, can.Message]] = deque()  # (arrival ns, frame)
        self._last_seen: dict[str, int] = {}      # source message -> last frame's arrival
        self._timed_out: set[str] = set()
        self._fresh: int | None = None            # arrival of the newest input not yet sent
        self._changed = False
        self._next_cycle: int | None = None
        self._last_out: int | None = None
        self._protect = route.e2e.protector() if route.e2e is not None else None
        self._counter = 0

    def source_ids(self) -> frozenset[tuple[int, bool]]:
        """The (CAN ID, 29-bit) of its source messages."""
        return frozenset((fc.frame_id, fc.is_extended) for fc, _ in self._sources.values())

    def out_id(self) -> int:
        """The CAN ID the route sends: its target message's."""
        return self.target.frame_id

    def out_keys(self) -> set[tuple[int, bool]]:
        return {(self.target.frame_id, self.target.is_extended)}

    def offer(self, msg: can.Message, now_ns: int) -> None:
        """A frame of one of its source messages (the engine looks it up), arrived at now_ns."""
        self.stats.frames_in += 1
        self._queue.append((now_ns, msg))
        self.stats.queued(len(self._queue))

    def tick(self, now_ns: int) -> list[can.Message]:
        r, q = self.route, self._queue
        while q and q[0][0] + r.delay_ns <= now_ns:
            self._take(*q.popleft())
        if r.timeout_ns:
            self._check_timeouts(now_ns)
        if self._next_cycle is None:
            self._next_cycle = now_ns
        due = (r.send != "on_change" and now_ns >= self._next_cycle) or (
            r.send != "cyclic" and self._changed)
        if not due or (r.min_interval_ns and self._last_out is not None
                       and now_ns - self._last_out < r.min_interval_ns):
            return []
        if r.send != "on_change" and now_ns >= self._next_cycle:
            self._next_cycle += r.cycle_ns * max(1, -(-(now_ns + 1 - self._next_cycle)
                                                      // r.cycle_ns))
        data = bytearray(self.target.encode(self.values))
        if r.e2e is not None and self._protect is not None:
            r.e2e.set_counter(data, self._counter)
            self._protect(data)
            self._counter = (self._counter + 1) % r.e2e.counter_modulo
        self.stats.sent(None if self._fresh is None else now_ns - self._fresh)
        self._fresh, self._changed, self._last_out = None, False, now_ns
        fc = self.target
        return [message(now_ns / 1e9, fc.frame_id, fc.is_extended, data, fc.is_fd, r.target,
                        False)]

    def _take(self, arrived: int, msg: can.Message) -> None:
        sfc, maps = self._sources[msg.arbitration_id]
        if len(msg.data) != sfc.length:
            self.stats.drop("length")
            return
        check = self._checks.get(msg.arbitration_id)
        if check is not None:
            if not check(msg.data):
                self.stats.drop("e2e")
                return
            prot, alive = self._counters[msg.arbitration_id]
            if not alive.check(prot.counter(msg.data)):
                self.stats.drop("e2e_repeated")
                return
        try:
            decoded = sfc.decode(msg.data)
        except Exception:  # noqa: BLE001 - whatever cantools raises for a payload it cannot read
            self.stats.drop("decode")
            return
        self._last_seen[sfc.name] = arrived
        self._timed_out.discard(sfc.name)
        used = False
        for m in maps:
            if m.signal not in decoded:  # a multiplexed signal its selector did not carry
                continue
            value = self._convert(m, sfc, decoded[m.signal])
            if value is None:
                continue
            used = True
            if value != self.values[m.target]:
                self.values[m.target] = value
                self._changed = True
        if used:
            self._fresh = arrived

    def _convert(self, m: SignalMap, sfc: FrameCodec, raw: float) -> float | None:
        choices = sfc.choices.get(m.signal)
        if choices is not None:  # by name
            name = choices.get(int(raw))
            by_name = {v: k for k, v in self.target.choices[m.target].items()}
            if name is None or name not in by_name:
                self.stats.drop("choice")
                return None
            return float(by_name[name])
        value = raw * m.factor + m.offset
        lo, hi = self._ranges[m.target]
        if not lo <= value <= hi:
            self.stats.saturated[m.target] += 1
            value = lo if not value >= lo else hi
        return value

    def _check_timeouts(self, now_ns: int) -> None:
        for name, seen in self._last_seen.items():
            if name in self._timed_out or now_ns - seen < self.route.timeout_ns:
                continue
            self._timed_out.add(name)
            self.stats.timeouts += 1
            for m in self.route.signals:
                if m.message == name and self.values[m.target] != self._initial[m.target]:
                    self.values[m.target] = self._initial[m.target]
                    self._changed = True


def _bounds(fc: FrameCodec, name: str) -> tuple[float, float]:
    """The range the target signal carries: its database minimum / maximum (else unbounded;
    encode() clips to what the bits hold)."""
    lo, hi = fc.ranges[name]
    return (-float("inf") if lo is None else lo, float("inf") if hi is None else hi)


def source_protection(fc: FrameCodec) -> E2EProtection | None:
    """The protection a source message's database names: its ARXML E2E properties (as the
    restbus reads them; properties vecu cannot apply: none), else vecu's E2E layout."""
    try:
        prot = arxml_protection(fc)
    except E2EConfigError:
        prot = None
    if prot is None and fc.e2e is not None:
        prot = fc.e2e.protection
    return prot
