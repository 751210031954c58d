"""Frame routes: a frame matched on the source bus is copied, payload untouched (so its E2E
protection still passes the receiver's check, as a frame gateway must leave it: AUTOSAR PduR
I-PDU routing), to the target bus, optionally under a new CAN ID, after the route's processing
delay. With min_interval the route sends at most one frame per interval, the latest received
winning (AUTOSAR PduR's last-is-best buffer); the frames it replaces are dropped and counted.
With e2e_check (check-and-forward) a frame whose E2E check fails (the protection its source
database names, checked by autosar-e2e) is dropped and counted instead of passed on."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

import can

from vecu.can_message import message
from vecu.codec import DbcCodec
from vecu.gateway.route_stats import RouteStats
from vecu.gateway.routes import FrameRoute
from vecu.gateway.signal_routes import source_protection


class FrameRouter:
    """One frame route: offer() each frame it matches, tick() each 1 ms."""

    def __init__(self, route: FrameRoute, source: DbcCodec | None = None) -> None:
        self.route = route
        self.stats = RouteStats()
        self._checks: dict[tuple[int, bool], Callable[[bytes | bytearray], bool]] = {}
        if route.e2e_check and source is not None:  # the protection its database names
            for key in route.ids:
                prot = source_protection(source.by_id[key]) if key in source.by_id else None
                if prot is not None:
                    self._checks[key] = prot.checker()
        self._queue: deque[tuple[int, can.Message]] = deque()  # (arrival ns, frame)
        self._last_out_ns: int | None = None

    def source_ids(self) -> frozenset[tuple[int, bool]]:
        """The (CAN ID, 29-bit) the route takes by ID (id/mask routes match on their own)."""
        return self.route.ids

    def out_id(self) -> int:
        """The CAN ID the route sends (its first, by value)."""
        r = self.route
        if r.new_id is not None:
            return r.new_id
        return min(i for i, _ in r.ids) if r.ids else (r.id_mask or (0, 0))[0]

    def out_keys(self) -> set[tuple[int, bool]]:
        """The (CAN ID, 29-bit) it sends (an id/mask route without a new ID: none known)."""
        r = self.route
        return {(r.new_id, r.new_id > 0x7FF)} if r.new_id is not None else set(r.ids)

    def offer(self, msg: can.Message, now_ns: int) -> None:
        """A frame the route matches (the engine looks it up), arrived at now_ns."""
        self.stats.frames_in += 1
        if self._checks:
            check = self._checks.get((msg.arbitration_id, msg.is_extended_id))
            if check is not None and not check(msg.data):
                self.stats.drop("e2e")
                return
        q = self._queue
        if self.route.min_interval_ns and q:  # last is best: the newer replaces the waiting
            q.pop()
            self.stats.drop("rate_limit")
        q.append((now_ns, msg))
        self.stats.queued(len(q))

    def tick(self, now_ns: int) -> list[can.Message]:
        """The frames this route sends at now_ns (channel: the target bus's name)."""
        r, q, out = self.route, self._queue, []
        while q and q[0][0] + r.delay_ns <= now_ns:
            if (r.min_interval_ns and self._last_out_ns is not None
                    and now_ns - self._last_out_ns < r.min_interval_ns):
                break
            arrived, msg = q.popleft()
            out.append(message(now_ns / 1e9, msg.arbitration_id if r.new_id is None else r.new_id,
                               msg.is_extended_id if r.new_id is None else r.new_id > 0x7FF,
                               bytearray(msg.data), msg.is_fd, r.target, False,
                               bitrate_switch=msg.bitrate_switch))
            self.stats.sent(now_ns - arrived)
            self._last_out_ns = now_ns
        return out
