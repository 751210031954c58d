"""Wire plant, fault injector, ECU and recorder onto one bus and one scheduler, run, summarise."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import can

from vecu import functions, kernels, warmup
from vecu.assembly import (
    PRIO_ECU,
    PRIO_PLANT,
    PRIO_PROBE,
    PRIO_RECORD,
    TICK_NS,
    EcuFunctions,
    EstimatorFactory,
    build_functions,
    build_plant,
    plant_part,
    schedule_ecu,
    schedule_plant,
)
from vecu.bus import (
    BusNode,
    SimLane,
    open_bus,
    resolve_bus_config,
    virtual_channel_in_use,
)
from vecu.clock import NS_PER_MS, NS_PER_S, SimClock, Stopwatch, WallClock, monotonic_ns
from vecu.codec import DbcCodec
from vecu.config import RunConfig, validate_tree
from vecu.ecu.node import EcuNode
from vecu.errors import Interrupted
from vecu.estimators.registry import make_throttle_estimator
from vecu.faults import FaultInjector, ScheduledFault, parse_kind
from vecu.functions.base import Kill
from vecu.plant.node import PlantNode
from vecu.probes import Probe
from vecu.recorder import Recorder
from vecu.restbus.node import RestbusNode, schedule_disturbances
from vecu.restbus.spec import build_plans
from vecu.rng import rng_streams
from vecu.scheduler import Scheduler, TaskStats
from vecu.summary import FrameCounts, RunSummary, to_json
from vecu.uds.server import UdsServer, attach_uds
from vecu.uds.tester import SimTester
from vecu.xcp.server import XcpServer, attach_xcp
from vecu.xcp.tester import SimXcpMaster, layout_of

__all__ = ["RunConfig", "RunResult", "run"]
PRIO_CALIBRATE = PRIO_ECU + 1  # a timed set acts from the ECU's next tick, as an XCP write


@dataclass(frozen=True)
class RunResult:
    report: RunSummary  # typed; `summary` is its JSON form
    series: dict[str, Any]  # per function (keep_series): its probe's series (None: not kept)

    def series_of(self, name: str) -> Any:
        """Function name's series (None: not kept, or the run had no such function)."""
        return self.series.get(name)

    # the first function's series (the throttle's: `vecu run --plot`, scenario reports)
    throttle_series = property(lambda self: self.series_of("throttle"))

    @cached_property
    def summary(self) -> dict[str, Any]:
        """The summary as a user sees it (`vecu run --summary`): to_json(report)."""
        return to_json(self.report)


@dataclass
class Pipeline:
    """A built run: clock and scheduler, buses, plant, ECU, probes, servers and testers, each
    made with its hooks (build()); schedule() puts their tasks on the scheduler, execute() runs
    it, summarise() reads the result; close() shuts the buses (and the log)."""

    config: RunConfig
    clock: SimClock | WallClock
    sched: Scheduler
    n_ticks: int
    lane: SimLane | None
    buses: list[can.BusABC]
    recorder: Recorder | None = None
    injector: FaultInjector | None = None
    plant: PlantNode | None = None
    ecu: EcuNode | None = None
    fns: EcuFunctions | None = None
    probes: dict[str, Probe] = field(default_factory=dict)  # by function, in registry order
    uds: UdsServer | None = None
    xcp: XcpServer | None = None
    xcp_master: SimXcpMaster | None = None
    tester: SimTester | None = None
    restbus: RestbusNode | None = None
    ecu_task: TaskStats | None = None

    @property
    def end_ns(self) -> int:
        return self.n_ticks * TICK_NS

    def close(self) -> None:
        if self.recorder is not None:
            self.recorder.close()
        for bus in self.buses:
            bus.shutdown()


def run(config: RunConfig, progress: Callable[[float, float], None] | None = None, *,
        make_estimator: EstimatorFactory = make_throttle_estimator) -> RunResult:
    """Run plant + injector + ECU (+ recorder) for config.duration_s on one scheduler;
    progress(t_s, duration_s), when given, is called after each simulated second;
    make_estimator builds the ECU's throttle estimator (benches pass a timed one)."""
    config.validate()
    clock = WallClock() if config.realtime else SimClock()
    pipeline = Pipeline(config, clock, Scheduler(clock), round(config.duration_s * 1000),
                        _sim_lane(config), [])
    try:
        build(pipeline, make_estimator)
        schedule(pipeline)
        if config.realtime:
            warm_up(config)
        # one-time: loading (on a fresh install compiling) the kernels is not the run's speed
        kernel_load_s = ensure_kernels(config)
        watch = Stopwatch()
        try:
            wall = execute(pipeline, progress)
        except KeyboardInterrupt:
            raise interrupted(pipeline, watch.elapsed(), kernel_load_s) from None
        summary = summarise(pipeline, wall, kernel_load_s)
    finally:
        pipeline.close()
    return RunResult(summary, {name: probe.series() for name, probe in pipeline.probes.items()})


def build(p: Pipeline, make_estimator: EstimatorFactory = make_throttle_estimator) -> None:
    """Open the buses and make every node of p.config's run, each with its hooks."""
    config = p.config
    codec = functions.function_codec(config.params.ecu.instance, config)  # once per process
    rngs = rng_streams(config.seed, ("throttle.input", "throttle.plant", "faults"))
    bus_args = {"interface": config.interface, "channel": config.channel, "bitrate": config.bitrate}
    n_ticks = p.n_ticks

    def node_bus(edge: bool = False) -> can.BusABC:
        if p.lane is not None:
            bus = p.lane.bus(edge=edge)
        else:  # a recorder (edge) listens only
            bus = open_bus(**bus_args, **({"receive_own_messages": False} if edge else {}))
        p.buses.append(bus)
        return bus

    if config.log_path:  # open first so it sees every frame
        p.recorder = Recorder(node_bus(edge=True), config.log_path)
    plant_bus = node_bus()
    ecu_bus = node_bus()
    p.injector = FaultInjector(rngs["faults"])
    p.plant = plant = build_plant(config, codec, plant_bus, p.injector,
                                  truth=config.truth and p.recorder is not None)
    p.fns = fns = build_functions(config, codec, make_estimator)
    for spec in functions.enabled(config):  # each function's truth-vs-output probe
        part, fn = plant_part(plant, spec.part_name), fns.get(spec.name)
        if spec.probe is not None and fn is not None and (part is not None
                                                          or spec.part_name is None):
            p.probes[spec.name] = spec.probe(part, fn, config, n_ticks)
    p.ecu = ecu = EcuNode(ecu_bus, codec, fns.enabled(), rx_budget=config.params.ecu.rx)
    p.uds = attach_uds(ecu, config.params.ecu.uds, config.seed)
    p.xcp = attach_xcp_server(ecu, config)
    for _, path, value in config.calibrations:  # a bad one is a user error before the run
        _check_calibration(p.xcp, path, value)
    if config.xcp_steps:  # a scenario's XCP master
        p.xcp_master = _xcp_master(node_bus(), p.xcp, config)
    if config.uds_steps:  # a scenario's tester
        p.tester = SimTester(node_bus(), config.params.ecu.uds, config.uds_steps)
    for f in config.faults:  # the timeline's targets checked against the DBC
        p.injector.check(f.target, parse_kind(f.kind), f.value)
    if config.restbus is not None:  # the user's bus on the same lane and clock
        p.restbus = _restbus_node(p.clock, config, codec, node_bus())


def schedule(p: Pipeline) -> None:
    """Every task of the built pipeline on its scheduler, in a fixed order (ties at one time
    and priority run in this order)."""
    config, sched = p.config, p.sched
    assert p.plant is not None and p.ecu is not None and p.injector is not None
    for at_s, path, value in config.calibrations:  # timed sets, as an XCP write would act
        _schedule_calibration(sched, p.xcp, at_s, path, value)
    if p.xcp_master is not None:  # before the ECU in each tick
        sched.every(TICK_NS, p.xcp_master.tick, name="xcp-master", priority=PRIO_PLANT + 6)
    if p.tester is not None:  # before the ECU in each tick
        sched.every(TICK_NS, p.tester.tick, name="uds-tester", priority=PRIO_PLANT + 5)
    schedule_plant(sched, p.plant)
    p.ecu_task = schedule_ecu(sched, p.ecu)
    for name, probe in p.probes.items():
        sched.every(probe.period_ns, probe.tick, name=functions.spec(name).probe_task,
                    priority=PRIO_PROBE)
    if p.recorder is not None:
        sched.every(TICK_NS, p.recorder.drain, name="recorder", priority=PRIO_RECORD)
    for spec in functions.enabled(config):  # the sensor kills of the run's own options
        kill = spec.kill(config) if spec.kill is not None else None
        if kill is not None:
            _schedule_kill(sched, p.injector, kill)
    for f in config.faults:  # the scenario timeline
        _schedule_fault(sched, p.injector, f)
    if p.restbus is not None:
        p.restbus.schedule(sched, priority=PRIO_PLANT)
        schedule_disturbances(sched, p.restbus, config.restbus_disturbances,
                              priority=PRIO_PLANT - 1)


def execute(p: Pipeline, progress: Callable[[float, float], None] | None = None) -> float:
    """Run the scheduled pipeline to its end; the wall seconds the run loop took."""
    sched, end_ns = p.sched, p.end_ns
    watch = Stopwatch()
    p.clock.start()  # set-up time must not count against the first deadlines
    if progress is None:
        sched.run_until(end_ns)
    else:
        for chunk_end in range(NS_PER_S, end_ns + NS_PER_S, NS_PER_S):
            sched.run_until(min(chunk_end, end_ns))
            progress(min(chunk_end, end_ns) / NS_PER_S, p.config.duration_s)
    wall = watch.elapsed()
    assert p.ecu is not None and p.ecu_task is not None
    p.ecu.overruns = p.ecu_task.overruns
    if p.recorder is not None:  # frames sent after the ECU's last tick: stamped before end
        p.recorder.drain(end_ns, before_ns=end_ns)
    return wall


def interrupted(p: Pipeline, wall: float, kernel_load_s: float) -> Interrupted:
    """Ctrl-C part-way through execute(): the summary of the ticks that ran (the log keeps
    their frames), as an Interrupted for the command line (--summary, exit 130)."""
    planned = p.n_ticks
    p.n_ticks = min(planned, p.clock.now_ns() // TICK_NS)
    if p.ecu is not None and p.ecu_task is not None:
        p.ecu.overruns = p.ecu_task.overruns
    if p.recorder is not None:
        p.recorder.drain(p.end_ns, before_ns=p.end_ns)
    summary = summarise(p, wall, kernel_load_s)
    return Interrupted(f"{p.n_ticks / 1000:g} of {planned / 1000:g} s simulated",
                       to_json(summary))


def summarise(p: Pipeline, wall: float, kernel_load_s: float) -> RunSummary:
    """The run's typed summary after execute()."""
    config, sched, plant, ecu, n_ticks = p.config, p.sched, p.plant, p.ecu, p.n_ticks
    assert plant is not None and ecu is not None and p.injector is not None
    restbus, uds, tester, xcp, xcp_master = p.restbus, p.uds, p.tester, p.xcp, p.xcp_master
    frames_sent = plant.frames_sent + ecu.frames_sent + (
        restbus.frames_sent if restbus is not None else 0)
    ranked = sorted(p.probes, key=lambda name: functions.spec(name).report_rank)
    sections = {name: p.probes[name].summary() for name in ranked}
    return RunSummary(
        config=config.summary(), ticks=n_ticks, overruns=sched.overruns,
        tasks={t.name: {"runs": t.runs, "overruns": t.overruns, "skipped": t.skipped,
                        "max_lateness_ms": round(t.max_lateness_ns / NS_PER_MS, 3)}
               for t in sched.stats},
        sim_time_s=n_ticks / 1000.0, wall_time_s=round(wall, 4),
        x_realtime=round(n_ticks / 1000.0 / wall, 2) if wall > 0 else None,
        kernels=kernels.backend(), throttle=sections.pop("throttle"),
        frames=FrameCounts(
            sent=frames_sent, plant_sent=plant.frames_sent, ecu_sent=ecu.frames_sent,
            send_errors=plant.send_errors + ecu.send_errors, received=ecu.rx.received,
            rejected=ecu.rx.rejected, ecu_rx=ecu.rx.as_dict(),
            logged=p.recorder.frames if p.recorder else None,
            rejected_fault_commands=p.injector.rejected_commands,
            handler_errors={f"{n.node_name}: {h}": c for n in (plant, ecu)
                            for h, c in n.handler_errors.items()}),
        fault_events=_fault_events(p.injector),
        kernel_load_s=round(kernel_load_s, 3),
        bus="vecu lane" if p.lane is not None else type(ecu.bus).__name__,
        diagnostics={**{name: mon.report() for name, mon in ecu.monitors.items()},
                     "bus": {"dtc": ecu.bus_dtc.state.name.lower(),
                             "confirmations": ecu.bus_dtc.confirmations}},
        restbus=restbus.summary() if restbus is not None else None,
        uds=uds.summary() if uds is not None else None,
        uds_steps=tester.summary() if tester is not None else None,
        xcp=xcp.summary() if xcp is not None else None,
        xcp_steps=xcp_master.summary() if xcp_master is not None else None,
        functions=sections)


def _schedule_kill(sched: Scheduler, injector: FaultInjector, kill: Kill) -> None:
    kind = parse_kind(kill.kind)
    sched.at(kill.at_ns, lambda t: injector.inject(t, kill.target, kind, kill.value,
                                                   source="schedule"),
             name=kill.task, priority=PRIO_PLANT - 1)


def attach_restbus(sched: Scheduler, config: RunConfig, codec: DbcCodec,
                   bus: can.BusABC) -> RestbusNode:
    """The restbus of config.restbus on its own bus node, on `sched` (see _restbus_node)."""
    node = _restbus_node(sched.clock, config, codec, bus)
    node.schedule(sched, priority=PRIO_PLANT)
    schedule_disturbances(sched, node, config.restbus_disturbances, priority=PRIO_PLANT - 1)
    return node


def _restbus_node(clock: SimClock | WallClock, config: RunConfig, codec: DbcCodec,
                  bus: can.BusABC) -> RestbusNode:
    """The restbus of config.restbus on its own bus node: every message the databases give the
    chosen nodes except those vecu's plant and ECU send themselves, released with the plant, its
    disturbance timeline (FI_Event frames, as vecu's faults)."""
    from dataclasses import replace

    assert config.restbus is not None
    cfg = replace(config.restbus, exclude=frozenset(codec.by_id), seed=config.seed)
    plans, _, _ = build_plans(cfg)
    sender = BusNode(bus, "restbus")
    return RestbusNode(plans, sender.send, rng_streams(config.seed, ("restbus.faults",))[
        "restbus.faults"], codec["FI_Event"], clock=clock)


def _sim_lane(config: RunConfig) -> SimLane | None:
    """The in-process lane (vecu.bus.SimLane) for a simulated-clock run on python-can's
    `virtual` interface, unless a bus of this process already listens on that channel (then
    python-can's channel, so that the listener hears the run); a wall-clock run or any other
    interface keeps python-can end to end."""
    if config.realtime:
        return None
    cfg = resolve_bus_config(interface=config.interface, channel=config.channel,
                             bitrate=config.bitrate)
    if cfg["interface"] != "virtual" or virtual_channel_in_use(cfg["channel"]):
        return None
    return SimLane(str(cfg["channel"]))


def attach_xcp_server(ecu: EcuNode, config: RunConfig) -> XcpServer | None:
    """The XCP slave on `ecu` (docs/xcp.md): the working page is config's ecu.* tree, the
    reference page the defaults; a calibration is checked as `--set` is (validate_tree)."""
    from dataclasses import replace

    return attach_xcp(ecu, config.params.ecu.xcp, config.params.ecu, config.default_params().ecu,
                      config.seed, lambda ecu_tree: validate_tree(replace(config.params,
                                                                          ecu=ecu_tree)))


def _xcp_master(bus: can.BusABC, xcp: XcpServer | None, config: RunConfig) -> SimXcpMaster:
    """The scenario's XCP master on the slave's A2L names (an unknown name: a user error)."""
    from vecu.errors import ConfigError

    if xcp is None:
        raise ConfigError("[[xcp]] steps need the XCP slave (ecu.xcp.enabled = true)")
    layout = layout_of(xcp)
    for i, step in enumerate(config.xcp_steps):
        for name in (step.write, step.read):
            if name is not None and name not in layout:
                raise ConfigError(f"xcp[{i}]: no characteristic or measurement {name!r} in the "
                                  f"A2L (`vecu a2l` lists them)")
    return SimXcpMaster(bus, config.params.ecu.xcp, layout, config.xcp_steps)


def _check_calibration(xcp: XcpServer | None, path: str, value: Any) -> None:
    """A timed set's leaf and value, checked as an XCP write's (a user error before the run)."""
    if xcp is None:
        raise ValueError("timed calibrations need the XCP slave (ecu.xcp.enabled)")
    xcp.check_calibration([(path.removeprefix("ecu."), value)])


def _schedule_calibration(sched: Scheduler, xcp: XcpServer | None, at_s: float, path: str,
                          value: Any) -> None:
    """A timed set of an ecu.* leaf: taken at at_s after the ECU's tick, so that it acts from
    the next tick, as an XCP write handled in the tick at at_s does."""
    assert xcp is not None  # _check_calibration
    rel = path.removeprefix("ecu.")
    sched.at(round(at_s * NS_PER_S), lambda t: xcp.calibrate([(rel, value)], t),
             name="calibrate", priority=PRIO_CALIBRATE)


def _schedule_fault(sched: Scheduler, injector: FaultInjector, f: ScheduledFault) -> None:
    """Start (and end) one timeline fault (its target checked against the DBC by build())."""
    kind = parse_kind(f.kind)
    sched.at(round(f.start_s * NS_PER_S),
             lambda t: injector.inject(t, f.target, kind, f.value, source="scenario"),
             name=f"fault-{f.kind}-{f.target}", priority=PRIO_PLANT - 1)
    if f.end_s is not None:
        sched.at(round(f.end_s * NS_PER_S),
                 lambda t: injector.clear(t, f.target, kind, source="scenario"),
                 name=f"end-{f.kind}-{f.target}", priority=PRIO_PLANT - 1)


def _run_briefly(config: RunConfig) -> None:
    """0.3 s of the whole simulated pipeline of config on a private virtual channel, nothing
    written: first numpy / cantools calls and the compiled kernels' loading (or, on a fresh
    checkout, compiling) happen here instead of in a timed run."""
    from dataclasses import replace

    run(replace(config, duration_s=0.3, kill_tps_at_s=None, kill_swa_at_s=None, realtime=False,
                interface="virtual", channel=f"vecu-warm-up-{monotonic_ns()}",
                log_path=None, keep_series=False, faults=()))


def ensure_kernels(config: RunConfig) -> float:
    """Under the numba backend, the first call in a process loads (on a fresh install: compiles,
    ~40 s) the kernels of config's pipeline by a brief run of it; returns the seconds that took,
    0.0 afterwards and under the python backend (vecu.warmup)."""
    return warmup.ensure_kernels("run", lambda: _run_briefly(config))


def load_kernels() -> None:
    """Under the numba backend, load every compiled kernel now, outside any timed run."""
    ensure_kernels(RunConfig())


def warm_up(config: RunConfig) -> None:
    """Before a wall-clock run: a brief run of the same pipeline, then the set-up objects are
    frozen out of the garbage collector's way, so the first ticks keep time."""
    warmup.warm_up("run", lambda: _run_briefly(config))


def _fault_events(injector: FaultInjector) -> list[dict[str, Any]]:
    return [{"t_s": e.t_ns / NS_PER_S, "target": e.target.name, "kind": e.kind.name.lower(),
             "value": e.value, "source": e.source,
             "ended": [k.name.lower() for k in e.cleared]} for e in injector.events]
