"""One restbus on its own: the plans on a scheduler, on the simulated clock (exact periods,
byte-identical reruns) or on a live bus paced by the wall clock on absolute deadlines; its
timeline of disturbances; an optional log; a summary. `vecu restbus` and the bench call it."""

from __future__ import annotations

import gc
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import can

from vecu.bus import SimLane, open_bus, resolve_bus_config, virtual_channel_in_use
from vecu.clock import NS_PER_S, SimClock, Stopwatch, WallClock
from vecu.codec import shared_codec
from vecu.faults import ScheduledFault
from vecu.recorder import Recorder
from vecu.restbus.commands import CommandListener
from vecu.restbus.node import RestbusNode, schedule_disturbances
from vecu.restbus.spec import NO_CYCLE, TOO_LONG, RestbusConfig, build_plans
from vecu.rng import rng_streams
from vecu.scheduler import Scheduler


@dataclass(frozen=True)
class RestbusRun:
    config: RestbusConfig
    duration_s: float | None = 10.0  # None: until interrupted (live)
    realtime: bool = False
    interface: str | None = None
    channel: str | None = None
    bitrate: int | None = None
    log_path: str | None = None
    disturbances: tuple[ScheduledFault, ...] = ()
    commands: bool = False    # obey RB_Command frames (`vecu inject --restbus`; live: always)
    keep_times: bool = False  # the send time of every frame, per message (timing figures)
    spin_us: int = 50  # final busy-wait before each deadline, as the live processes (docs/live.md)
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass
class RestbusResult:
    summary: dict[str, Any]
    node: RestbusNode


def run_restbus(run: RestbusRun, on_second: Callable[[float], None] | None = None
                ) -> RestbusResult:
    """Build (every check first), then send until duration_s (or KeyboardInterrupt)."""
    plans, skipped, _ = build_plans(run.config)
    bus_args: dict[str, Any] = {"interface": run.interface, "channel": run.channel,
                                "bitrate": run.bitrate}
    clock = WallClock(spin_ns=run.spin_us * 1000) if run.realtime else SimClock()
    sched = Scheduler(clock)
    lane = None
    if not run.realtime:
        cfg = resolve_bus_config(**bus_args)
        if cfg["interface"] == "virtual" and not virtual_channel_in_use(cfg["channel"]):
            lane = SimLane(str(cfg["channel"]))
    buses: list[can.BusABC] = []

    def bus(edge: bool = False) -> can.BusABC:
        own: dict[str, Any] = {"receive_own_messages": False} if edge else {}
        b = lane.bus(edge=edge) if lane is not None else open_bus(**bus_args, **own)
        buses.append(b)
        return b

    recorder = None
    interrupted = False
    try:
        if run.log_path:
            recorder = Recorder(bus(edge=True), run.log_path)
        out = bus()
        errors = [0]

        def send(msg: can.Message) -> bool:
            try:
                out.send(msg)
                return True
            except can.CanError:
                errors[0] += 1
                return False

        node = RestbusNode(plans, send, rng_streams(run.config.seed, ("restbus.faults",))[
            "restbus.faults"], shared_codec()["FI_Event"], keep_times=run.keep_times,
            clock=clock)
        node.schedule(sched)
        schedule_disturbances(sched, node, run.disturbances)
        listener = None
        if run.commands or run.realtime:  # live: drain the bus, obey RB_Command
            listener = CommandListener(node, out)
            sched.every(10_000_000, listener.poll, name="restbus-commands", priority=-2)
        if recorder is not None:
            sched.every(10_000_000, recorder.drain, name="recorder", priority=100)
        if run.realtime:  # set-up objects out of the garbage collector's way (as vecu run)
            gc.collect()
            gc.freeze()
        watch = Stopwatch()
        clock.start()
        end_ns = None if run.duration_s is None else round(run.duration_s * NS_PER_S)
        t = 0
        try:
            while end_ns is None or t < end_ns:
                nxt = t + NS_PER_S if end_ns is None else min(t + NS_PER_S, end_ns)
                sched.run_until(nxt)
                t = nxt
                if on_second is not None:
                    on_second(t / NS_PER_S)
        except KeyboardInterrupt:
            interrupted = True
            t = min(clock.now_ns(), t + NS_PER_S)
        wall = watch.elapsed()
        if recorder is not None:
            recorder.drain(t, before_ns=t)
        summary = {"databases": list(run.config.databases), "duration_s": t / NS_PER_S,
                   "wall_s": round(wall, 4), "clock": "wall" if run.realtime else "simulated",
                   "interrupted": interrupted,
                   "skipped_no_cycle_time": [n for n, why in skipped.items() if why == NO_CYCLE],
                   "refused_too_long": [n for n, why in skipped.items()
                                        if why.startswith(TOO_LONG)],
                   "skipped": skipped,  # every message of the databases not sent: its reason
                   "send_errors": errors[0], "overruns": sched.overruns,
                   "logged": recorder.frames if recorder else None, **node.summary(),
                   "commands": None if listener is None else {
                       "applied": listener.applied, "rejected": listener.rejected,
                       "handler_errors": listener.handler_errors}}
    finally:
        if recorder is not None:
            recorder.close()
        for b in buses:
            b.shutdown()
    return RestbusResult(summary, node)
