"""`vecu run --gateway GATEWAY.toml`: the routing engine beside the plant and the ECU on the
simulated clock. The plant and the ECU sit on the first bus the file names; every bus is an
in-process lane named after its bus (vecu.bus.SimLane), the gateway an endpoint on each, ticking
each 1 ms after the ECU and before the recorder, so a route's latency is exactly its configured
delay and a run is deterministic. `--log` holds every bus, each frame's channel its bus name (in
formats whose channels are numbers, ASC and BLF: the bus's place in the file, 1, 2, …), in time
order (at one instant: the buses in the file's order)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from functools import partial

import can

from vecu.assembly import PRIO_ECU, PRIO_RECORD, TICK_NS
from vecu.bus import LaneBus, MergedEdges, SimLane
from vecu.clock import NS_PER_S, SimClock
from vecu.errors import ConfigError
from vecu.faults import ScheduledFault
from vecu.gateway.routes import RoutingConfig
from vecu.gateway.routing import RoutingEngine
from vecu.runner import (
    Pipeline,
    RunConfig,
    RunResult,
    build,
    ensure_kernels,
    execute,
    schedule,
    summarise,
)
from vecu.scheduler import Scheduler

CHANNEL_NAME_FORMATS = (".log", ".log.gz")  # candump: a channel is a name; elsewhere a number
PRIO_GATEWAY = (PRIO_ECU + PRIO_RECORD) // 2  # after the ECU's tick, before the probes / log


class TraceGateway(can.Listener):
    """`vecu replay TRACE --gateway`: the trace's frames and the ECU's are the first bus's; the
    replay's feeder hands every trace frame here (on_message_received, at the simulated clock's
    now), the ECU's tap its frames (receive), and tick() each 1 ms after the ECU gives the routed
    frames to `write` (each frame's channel its bus name). `copy_to` (--with-inputs): the trace's
    frames under the first bus's name."""

    def __init__(self, routing: RoutingConfig, clock: SimClock,
                 write: Callable[[can.Message, int], None],
                 copy_to: can.Listener | None) -> None:
        self.engine = RoutingEngine(routing)
        self.first = routing.buses[0].name
        self.clock, self.write, self.copy_to = clock, write, copy_to

    def on_message_received(self, msg: can.Message) -> None:
        self.engine.receive(self.first, msg, self.clock.now_ns())
        if self.copy_to is not None:
            msg.channel = self.first
            self.copy_to.on_message_received(msg)

    def receive(self, msg: can.Message, now_ns: int) -> None:
        self.engine.receive(self.first, msg, now_ns)

    def tick(self, now_ns: int) -> None:
        for _, msg in self.engine.tick(now_ns):
            msg.is_rx = True  # as a recorder on that bus sees it (the run's --log)
            self.write(msg, now_ns)


class GatewayNode:
    """The routing engine with one endpoint on each bus's lane."""

    def __init__(self, engine: RoutingEngine, endpoints: dict[str, LaneBus]) -> None:
        self.engine = engine
        self.endpoints = endpoints
        self._queues = [(name, bus.queue) for name, bus in endpoints.items()]  # no filters set

    def tick(self, now_ns: int) -> None:
        receive = self.engine.receive
        for name, q in self._queues:  # each lane endpoint's deque (LaneBus.recv without a call)
            while q:
                receive(name, q.popleft(), now_ns)
        for name, msg in self.engine.tick(now_ns):
            self.endpoints[name].send(msg)


def schedule_route_faults(sched: Scheduler, engine: RoutingEngine,
                          faults: tuple[ScheduledFault, ...]) -> None:
    """Start (and end) each fault on its route, just before the gateway's tick then."""
    for f in faults:
        start = partial(_disturb, engine, f, True)
        sched.at(round(f.start_s * NS_PER_S), start, name=f"route-fault-{f.kind}-{f.target}",
                 priority=PRIO_GATEWAY - 1)
        if f.end_s is not None:
            end = partial(_disturb, engine, f, False)
            sched.at(round(f.end_s * NS_PER_S), end, name=f"route-unfault-{f.kind}-{f.target}",
                     priority=PRIO_GATEWAY - 1)


def _disturb(engine: RoutingEngine, f: ScheduledFault, active: bool, t_ns: int) -> None:
    engine.disturb(t_ns, f.target, f.kind, f.value, active)


def run_with_gateway(config: RunConfig, routing: RoutingConfig,
                     progress: Callable[[float, float], None] | None = None,
                     faults: tuple[ScheduledFault, ...] = ()) -> RunResult:
    """runner.run(config) with the gateway of `routing` beside plant and ECU; `faults`: each
    on the route its target names ("routes[i]", vecu.gateway.route_faults)."""
    if config.realtime:
        raise ConfigError("--gateway runs on the simulated clock (no --realtime)")
    if config.interface not in (None, "virtual"):
        raise ConfigError("--gateway runs its buses in-process: no --interface")
    first = routing.buses[0].name
    config = replace(config, channel=first)
    config.validate()
    clock = SimClock()
    p = Pipeline(config, clock, Scheduler(clock), round(config.duration_s * 1000),
                 SimLane(first), [])
    assert p.lane is not None
    try:
        build(p)
        lanes = {first: p.lane, **{b.name: SimLane(b.name) for b in routing.buses[1:]}}
        endpoints = {name: lane.bus() for name, lane in lanes.items()}
        p.buses += endpoints.values()
        if p.recorder is not None:  # the first lane's log endpoint, then one per other lane
            first_edge = p.recorder.bus
            assert isinstance(first_edge, LaneBus)
            edges = [first_edge] + [lane.bus(edge=True) for lane in list(lanes.values())[1:]]
            p.buses += edges[1:]
            named = config.log_path is not None and config.log_path.lower().endswith(
                CHANNEL_NAME_FORMATS)
            p.recorder.bus = merged = MergedEdges(edges, numbered=not named)
            p.buses.append(merged)
        node = GatewayNode(RoutingEngine(routing), endpoints)
        schedule(p)
        p.sched.every(TICK_NS, node.tick, name="gateway", priority=PRIO_GATEWAY)
        schedule_route_faults(p.sched, node.engine, faults)
        kernel_load_s = ensure_kernels(config)
        wall = execute(p, progress)
        summary = replace(summarise(p, wall, kernel_load_s), gateway=node.engine.summary())
    finally:
        p.close()
    return RunResult(summary, {name: probe.series() for name, probe in p.probes.items()})
