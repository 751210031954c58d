"""The routing engine between CAN buses (docs/gateway.md "Routing between buses"): the firewall,
then every frame route and signal route of the config, driven by the caller's clock.

receive(bus, frame, now_ns) for each frame a bus delivers, tick(now_ns) every 1 ms: the frames to
send, each as (target bus name, frame). A frame finds its routes by one dict lookup on (bus, CAN
ID, 29-bit flag); only id/mask routes are tried one by one. Nothing here reads a clock or opens a bus, so on the
simulated clock a route's latency is exactly its configured delay (default 0)."""

from __future__ import annotations

from typing import Any

import can
import numpy as np

from vecu.codec import shared_codec
from vecu.gateway.firewall import Firewall
from vecu.gateway.frame_routes import FrameRouter
from vecu.gateway.route_faults import RouteFaults
from vecu.gateway.routes import RoutingConfig
from vecu.gateway.signal_routes import SignalRouter


class RoutingEngine:
    def __init__(self, config: RoutingConfig) -> None:
        self.config = config
        self.firewall = Firewall(config.deny)
        self.routes: list[FrameRouter | SignalRouter] = [
            FrameRouter(r, config.bus(r.source).codec) for r in config.frame_routes]
        self.routes += [SignalRouter(r, config.bus(r.source).codec, config.bus(r.target).codec)
                        for r in config.signal_routes]
        self.routes.sort(key=lambda r: int(r.route.key[len("routes["):-1]))
        self.first = config.buses[0].name if config.buses else ""
        self._faults: dict[str, RouteFaults] = {}   # route key -> its faults (once any started)
        self._events: list[can.Message] = []        # FI_Event frames for the next tick
        self.fault_log: list[dict[str, Any]] = []   # route faults' starts and ends
        self._fi_event = shared_codec()["FI_Event"]
        Key = tuple[str, int, bool]
        self._by_id: dict[Key, list[FrameRouter | SignalRouter]] = {}  # (bus, ID, 29-bit)
        self._masked: dict[str, list[FrameRouter]] = {}                # bus -> id/mask routes
        for r in self.routes:
            for can_id, extended in r.source_ids():
                self._by_id.setdefault((r.route.source, can_id, extended), []).append(r)
            if isinstance(r, FrameRouter) and r.route.id_mask is not None:
                self._masked.setdefault(r.route.source, []).append(r)

    def receive(self, bus: str, msg: can.Message, now_ns: int) -> None:
        """A frame `bus` delivered at now_ns (error and remote frames are not routed)."""
        if msg.is_error_frame or msg.is_remote_frame:
            return
        can_id, extended = msg.arbitration_id, msg.is_extended_id
        if self.firewall.blocks(bus, can_id):
            return
        routes = self._by_id.get((bus, can_id, extended))
        if routes is not None:
            for route in routes:
                route.offer(msg, now_ns)
        for masked in self._masked.get(bus, ()):
            if masked.route.matches(can_id, extended) and (
                    routes is None or masked not in routes):
                masked.offer(msg, now_ns)

    def sends(self, bus: str) -> set[tuple[int, bool]]:
        """The (CAN ID, 29-bit) the routes send on `bus` (an id/mask route without a new ID:
        none known)."""
        out: set[tuple[int, bool]] = set()
        for r in self.routes:
            if r.route.target == bus:
                out |= r.out_keys()
        return out

    def disturb(self, now_ns: int, key: str, kind: str, value: float | None = None,
                active: bool = True, source: str = "scenario") -> None:
        """Start (active) or end a fault (vecu.gateway.route_faults) on the route `key`
        ("routes[i]"); its FI_Event frame goes on the first bus with the next tick's frames."""
        route = next((r for r in self.routes if r.route.key == key), None)
        if route is None:
            raise KeyError(key)
        faults = self._faults.get(key)
        if faults is None:
            faults = self._faults[key] = RouteFaults(key, route.out_id(), np.random.default_rng(0))
        d = faults.start(kind, value) if active else faults.end(kind)
        if d is not None:
            self.fault_log.append({"t_s": now_ns / 1e9, "route": key, "kind": kind,
                                   "value": d.value, "active": active})
            self._events.append(faults.event(self._fi_event, now_ns, kind, d.value, active,
                                             source))

    def tick(self, now_ns: int) -> list[tuple[str, can.Message]]:
        """Every route's frames due at now_ns, in the file's route order (a fault's FI_Event
        frames first, on the first bus)."""
        out: list[tuple[str, can.Message]] = []
        if self._events:
            out += [(self.first, m) for m in self._events]
            self._events.clear()
        faults = self._faults
        for route in self.routes:
            frames = route.tick(now_ns)
            f = faults.get(route.route.key) if faults else None
            if f is not None:
                frames, dropped, ended = f.apply(frames, now_ns)
                if dropped:
                    route.stats.frames_out -= dropped
                    route.stats.drop("fault", dropped)
                for d in ended:
                    self.fault_log.append({"t_s": now_ns / 1e9, "route": route.route.key,
                                           "kind": d.kind, "value": d.value, "active": False})
                    out.append((self.first, f.event(self._fi_event, now_ns, d.kind, d.value,
                                                    False)))
            out += [(route.route.target, m) for m in frames]
        return out

    def summary(self) -> dict[str, Any]:
        """Per route (by its place in the file: "routes[i] a->b"), and the firewall's drops."""
        return {"routes": {f"{r.route.key} {r.route.source}->{r.route.target}": r.stats.summary()
                           for r in self.routes},
                "denied": self.firewall.summary(),
                **({"faults": self.fault_log} if self.fault_log else {})}
