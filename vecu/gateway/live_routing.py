"""The routing engine live on the wall clock (`vecu gateway` with `[buses.NAME]` in its config):
every bus of the file opened through vecu.bus (its python-can arguments, or `--bus
NAME=INTERFACE:CHANNEL` instead), each 1 ms step taking every frame the buses hold and sending
what the routes give. A frame's latency runs from its arrival (the bus's receive timestamp, the
kernel's on SocketCAN and udp_multicast) to its send; the gateway's own echoes (interfaces that
loop a socket's frames back: udp_multicast) are dropped by the IDs its routes send there."""

from __future__ import annotations

from typing import Any

import can

from vecu.bus import open_bus
from vecu.clock import NS_PER_S, wall_time
from vecu.errors import BadArgumentError
from vecu.gateway.routes import RoutingConfig
from vecu.gateway.routing import RoutingEngine

MAX_AGE_NS = NS_PER_S  # a receive timestamp older than this (or in the future): taken as now


class LiveRouting:
    def __init__(self, routing: RoutingConfig,
                 overrides: tuple[tuple[str, str, str], ...] = ()) -> None:
        names = [b.name for b in routing.buses]
        for name, _, _ in overrides:
            if name not in names:
                raise BadArgumentError(f"--bus {name}=...: no bus {name!r} in the config "
                                       f"(buses: {', '.join(names)})")
        over = {name: (interface, channel) for name, interface, channel in overrides}
        self.engine = RoutingEngine(routing)
        self.buses: dict[str, can.BusABC] = {}
        self.send_errors = 0
        self.args: dict[str, dict[str, Any]] = {}
        try:
            for spec in routing.buses:
                args = dict(spec.args)
                if spec.name in over:
                    args["interface"], args["channel"] = over[spec.name]
                self.args[spec.name] = args
                bus = self.buses[spec.name] = open_bus(**args)
                if hasattr(bus, "skip_keys"):  # FastUdpMulticastBus: its own frames come back
                    bus.skip_keys = frozenset(self.engine.sends(spec.name))
        except BaseException:
            self.close()
            raise

    def step(self, now_ns: int) -> None:
        """Every frame the buses hold (each dated by its age now), then the routes' frames sent."""
        got: list[tuple[str, can.Message]] = []
        for name, bus in self.buses.items():
            while (msg := bus.recv(0.0)) is not None:
                got.append((name, msg))
        if got:
            receive, now_s = self.engine.receive, wall_time()
            for name, msg in got:
                age = round((now_s - msg.timestamp) * NS_PER_S)
                receive(name, msg, now_ns - age if 0 <= age < MAX_AGE_NS else now_ns)
        for name, msg in self.engine.tick(now_ns):
            try:
                self.buses[name].send(msg)
            except can.CanError:
                self.send_errors += 1

    def summary(self) -> dict[str, Any]:
        return {**self.engine.summary(), "send_errors": self.send_errors,
                "buses": {name: f"{a.get('interface')} {a.get('channel')}"
                          for name, a in self.args.items()}}

    def close(self) -> None:
        for bus in self.buses.values():
            bus.shutdown()
        self.buses = {}
