"""Trace replay: the ECU (alone, no plant) on the scheduler, fed by a recorded trace.

Fast mode (default): the simulated clock; the trace's frames reach EcuNode.receive() at their
timestamps, in order, ahead of the ECU's 1 ms tick due at the same time (as in a live run, where
the plant sends before the ECU runs), so a trace recorded by `vecu run --log` replays to the same
estimates. The ECU's last tick is the last one at or before the trace's last frame. Live mode (speed X): the wall clock; a player bus sends every frame at X times its
recorded pace onto a python-can bus, the ECU listens on its own bus; each frame's schedule error
is measured. One event loop either way: vecu.scheduler.
"""

from __future__ import annotations

import gc
import logging
import math
import sys
import threading
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from functools import cached_property
from typing import Any

import can

from vecu import functions as registry
from vecu import kernels, warmup
from vecu.assembly import PRIO_ECU, PRIO_PLANT, TICK_NS, build_functions, schedule_ecu
from vecu.bus import EstimateSink, SinkBus, open_bus
from vecu.clock import NS_PER_MS, NS_PER_S, SimClock, Stopwatch, WallClock
from vecu.codec import TRUTH_DBC, DbcCodec, builtin_dbc_path
from vecu.config import RunConfig
from vecu.ecu.node import EcuFunction, EcuNode, Route, RxCounters, native_routes
from vecu.errors import BadArgumentError, Interrupted
from vecu.fmu.binding import FmuBinding
from vecu.replay.feeder import SCHEDULE_ERROR_LIMIT_US, Feeder, FrameTally
from vecu.replay.output import OUT_CHANNEL, EstimateOut, open_writer
from vecu.replay.scoring import TruthScorer
from vecu.replay.signal_map import (
    SignalMap,
    identity_map,
    load_signal_map,
    mapped_routes,
)
from vecu.replay.source import IDLE_GAP_NS, TraceReadError, TraceSource
from vecu.replay.summary import (
    FunctionReport,
    IdleGaps,
    MapReport,
    ReplayFrames,
    ReplaySummary,
)
from vecu.scheduler import Scheduler
from vecu.summary import to_json

log = logging.getLogger(__name__)

PLAYER_SPIN_NS = 100_000
SWITCH_INTERVAL_S = 2e-5
STEP_NS = NS_PER_S // 10  # the scheduler runs this much simulated time between progress checks
PROGRESS_EVERY_S = 1.0  # wall time between progress lines
PRIO_TRACE_END = PRIO_ECU - 1  # the end-of-trace check: after the frames due, before the ECU
BRIEF_NS = 300 * NS_PER_MS  # the warm-up ECU takes this much of the trace's head


@dataclass(frozen=True)
class ReplayConfig:
    trace: str
    dbc: tuple[str, ...] = ()          # the trace's databases; default: vecu's own (+ truth)
    signal_map: str | None = None       # TOML: which message.signal feeds which ECU input
    out: str | None = None              # estimate frames (python-can writer by suffix)
    with_inputs: bool = False           # also copy the trace's frames into `out`
    speed: float | None = None          # None: fast (simulated clock); X: live at X times
    interface: str | None = None
    channel: str | None = None
    fmt: str | None = None              # reader format when the suffix does not tell
    estimator: str | None = None        # shortcut for ecu.throttle.estimator (None: default)
    manifold_filter: str | None = None  # shortcut for ecu.manifold.filter
    sets: tuple[tuple[str, Any], ...] = ()  # ecu.* calibration overrides (vecu params)
    progress: bool | None = None        # None: when stderr is a terminal
    progress_every_s: float = PROGRESS_EVERY_S  # wall time between progress lines
    idle_gap_s: float = IDLE_GAP_NS / NS_PER_S  # a longer silence is shortened to this
    keep_series: bool = False           # estimate/truth rows for a plot (ReplayResult.series)
    gateway: str | None = None          # GATEWAY.toml: the trace on its first bus, routed
    fmu: FmuBinding | None = None       # an FMU as an ECU function (docs/fmu.md)

    def validate(self) -> None:
        for path, _ in self.sets:
            if not path.startswith("ecu."):
                raise BadArgumentError(f"--set {path}: a replay takes ecu.* parameters only (the "
                                       f"car is the one that recorded the trace)")
        if self.gateway is not None and self.speed is not None:
            raise BadArgumentError("--gateway replays on the simulated clock (no --speed)")
        if self.speed is not None and not (self.speed > 0 and self.speed < 1e4):
            raise BadArgumentError(f"--speed must be in (0, 10000), got {self.speed}")
        if not (math.isfinite(self.progress_every_s) and self.progress_every_s >= 0):
            raise BadArgumentError(f"progress interval must be >= 0 s, got {self.progress_every_s}")
        if not (math.isfinite(self.idle_gap_s) and self.idle_gap_s > 0):
            raise BadArgumentError(f"idle gap must be a positive number of seconds, got "
                                   f"{self.idle_gap_s}")


@dataclass(frozen=True)
class ReplayResult:
    report: ReplaySummary  # typed; `summary` is its JSON form
    error: str | None  # a read error (the summary covers everything before it)
    series: dict[str, list[tuple[float, float, float]]] | None = None

    @cached_property
    def summary(self) -> dict[str, Any]:
        """The summary as a user sees it (`vecu replay --summary`): to_json(report)."""
        return to_json(self.report)


def replay(config: ReplayConfig, feeder_type: type[Feeder] = Feeder,
           extra_sinks: Sequence[EstimateSink] = ()) -> ReplayResult:
    """Replay config.trace through the ECU; see the module docstring. feeder_type: the feeder
    (tests pass their frame-by-frame oracle, a Feeder without block checks); extra_sinks: more estimate
    sinks, handed every frame the ECU sends with its values and time (ns on the replay's time
    base) as it is sent, after the scorer (vecu.fleet's diff against the recording)."""
    config.validate()
    routing = None
    if config.gateway is not None:  # every problem of the file before any work
        from vecu.gateway.routes_config import load_routing_config
        from vecu.gateway.sim import PRIO_GATEWAY, TraceGateway
        routing = load_routing_config(config.gateway)
        if not routing.buses:
            raise BadArgumentError(f"--gateway {config.gateway}: names no [buses.NAME] to route")
    ecu_codec, trace_db, smap, functions, routes = _ecu_parts(config)
    live = config.speed is not None
    stopped_at_s: float | None = None  # where Ctrl-C stopped the replay (replay time)
    source = TraceSource(config.trace, config.fmt,
                         idle_gap_ns=round(config.idle_gap_s * NS_PER_S))
    writer = open_writer(config.out, locked=live)
    buses: list[can.BusABC] = []
    player_bus: can.BusABC | None = None
    try:
        if live:  # first numpy / cantools calls and the compiled kernels' loading: not mid-run
            warmup.warm_up("replay", lambda: warm_up_ecu(config))
        # one-time: not in the replay's speed
        kernel_load_s = warmup.ensure_kernels("replay", lambda: warm_up_ecu(config))
        # live: the ECU thread sleeps its whole waits (no spin holding the GIL); the player spins
        # the last PLAYER_SPIN_NS (sleep overshoots ~0.1 ms here)
        clock = WallClock(spin_ns=0) if live else SimClock()
        sched = Scheduler(clock)
        scorer = TruthScorer(ecu_codec, keep_series=config.keep_series)
        if live:
            bus_args = {"interface": config.interface, "channel": config.channel}
            player_bus = open_bus(**bus_args)
            ecu_bus = open_bus(**bus_args)
            buses += [player_bus, ecu_bus]
        else:
            ecu_bus = SinkBus("replay")
        out = EstimateOut(writer, source, config.speed,
                           OUT_CHANNEL if routing is None else routing.buses[0].name)
        copy_to: can.Listener | None = writer if config.with_inputs else None
        sinks: list[EstimateSink] = [scorer, *extra_sinks]  # the ECU hands each frame it sends to these
        gateway = None
        if routing is not None:
            assert isinstance(clock, SimClock)
            copy_to = gateway = TraceGateway(routing, clock, out.write, copy_to)
            sched.every(TICK_NS, gateway.tick, name="gateway", priority=PRIO_GATEWAY)
            sinks.append(gateway)
        if writer is not None:
            sinks.append(out)
        ecu = EcuNode(ecu_bus, ecu_codec, functions, routes=routes, rx_codec=trace_db,
                      arm_on_input=True, sinks=sinks, tallied_rx=frozenset({UNKNOWN_ID}))
        tally = FrameTally()
        feeder = feeder_type(source, ecu, trace_db, scorer, tally, routes, copy_to,
                             player=player_bus, speed=config.speed or 1.0,
                             clock=clock if isinstance(clock, WallClock) else None)
        ecu_task = schedule_ecu(sched, ecu)
        trace_end = _TraceEnd(sched, feeder, live)
        sched.every(TICK_NS, trace_end, name="trace-end", priority=PRIO_TRACE_END)
        show = config.progress if config.progress is not None else sys.stderr.isatty()
        progress = _Progress(source, clock, config.speed or 1.0,
                             config.progress_every_s if show else None)
        try:
            if live:
                _run_live(sched, clock, feeder, trace_end, progress)
            else:
                sched.chain(0, feeder.release, name="trace", priority=PRIO_PLANT)
                gc.freeze()  # the set-up's objects out of the collector's way (live: _run_live)
                try:
                    end_ns = 0
                    while not trace_end.reached:
                        end_ns += STEP_NS
                        sched.run_until(end_ns)
                        progress.update()
                finally:
                    gc.unfreeze()
        except KeyboardInterrupt:  # Ctrl-C: the summary of what was replayed, then Interrupted
            stopped_at_s = clock.now_ns() / NS_PER_S
        wall = progress.watch.elapsed()
        progress.close()
        ecu.overruns = ecu_task.overruns
    finally:
        if writer is not None:
            try:
                writer.stop()
            except Exception as exc:  # noqa: BLE001 - logged; the replay's result stands
                log.error("%s: closing the output failed: %s", config.out, exc)
        for bus in buses:
            bus.shutdown()
        if not live:
            ecu_bus.shutdown()
    if ecu.rx.unknown_id:
        log.warning("%s", unknown_id_tally(config.trace, ecu.rx.unknown_id, feeder.unknown_ids))
    summary = _summary(config, source, feeder, tally, ecu, smap, functions, scorer, wall,
                       writer.frames if writer is not None else 0, kernel_load_s)
    if gateway is not None:
        summary = replace(summary, gateway=gateway.engine.summary())
    if stopped_at_s is not None:
        raise Interrupted(f"{stopped_at_s:.3f} s of the trace ({source.stats.frames_read} frames "
                          "read)", to_json(summary))
    return ReplayResult(summary, source.error, scorer.series)


# ------------------------------------------------------------------ pieces
UNKNOWN_ID = "unknown-id"  # the ECU's receive problem a replay tallies in one line
TALLY_IDS_LISTED = 5


def unknown_id_tally(trace: str, frames: int, keys: set[tuple[int, bool]]) -> str:
    """One line for the frames whose IDs no database knows (a foreign trace), instead of a
    warning per frame; the counts stay in the summary (frames.unknown_id)."""
    ids = [f"0x{i:08X}" if ext else f"0x{i:03X}" for i, ext in sorted(keys)]
    shown = ", ".join(ids[:TALLY_IDS_LISTED]) + (", ..." if len(ids) > TALLY_IDS_LISTED else "")
    which = f"{len(ids)} ID{'s' if len(ids) != 1 else ''}: {shown}; " if ids else ""
    return (f"{trace}: {frames} frame{'s' if frames != 1 else ''} with IDs not in the database "
            f"({which}--dbc names the trace's own database)")


def _ecu_parts(config: ReplayConfig) -> tuple[DbcCodec, DbcCodec, SignalMap,
                                               list[EcuFunction], dict[tuple[int, bool], Route]]:
    """The ECU's codec, the trace's database, the signal map, fresh ECU functions and their
    routes from the trace's messages."""
    run_cfg = _run_config(config)
    ecu_codec = registry.function_codec(run_cfg.params.ecu.instance, run_cfg)  # once per process
    trace_db = _trace_database(config.dbc, ecu_codec)
    smap = (load_signal_map(config.signal_map, trace_db) if config.signal_map
            else identity_map(trace_db))
    functions = [f for f in build_functions(run_cfg, ecu_codec).enabled()
                 if f.name not in smap.disabled]
    return ecu_codec, trace_db, smap, functions, _routes(config, smap, trace_db, ecu_codec,
                                                         functions)


def _run_config(config: ReplayConfig) -> RunConfig:
    run_cfg = RunConfig(kill_tps_at_s=None)
    if config.fmu is not None:
        run_cfg = run_cfg.with_fmu(config.fmu)
    return run_cfg.with_params(
        config.sets, estimator=config.estimator, manifold_filter=config.manifold_filter)


def ecu_codec_of(config: ReplayConfig) -> DbcCodec:
    """The codec of the frames the replay's ECU sends (its instance's IDs)."""
    run_cfg = _run_config(config)
    return registry.function_codec(run_cfg.params.ecu.instance, run_cfg)


def warm_up_ecu(config: ReplayConfig) -> RxCounters:
    """Load (on a fresh install: compile) the kernels the replay's ECU calls, before the timed
    replay: a throw-away ECU (its own functions, a sink bus, frames it cannot take counted,
    never logged) takes the input frames of the trace's first BRIEF_NS, one by one, and ticks
    every TICK_NS between them. Not a replay: no feeder, scorer, writer or scheduler. Returns
    that ECU's receive counters."""
    ecu_codec, trace_db, _, functions, routes = _ecu_parts(config)
    bus = SinkBus("warm-up")
    ecu = EcuNode(bus, ecu_codec, functions, routes=routes, rx_codec=trace_db,
                  arm_on_input=True, log_rx_problems=False)
    next_tick = 0
    try:
        for t_ns, msg in TraceSource(config.trace, config.fmt):
            if t_ns > BRIEF_NS:
                break
            while next_tick < t_ns:  # a frame due with a tick reaches the ECU before it
                ecu.tick(next_tick)
                next_tick += TICK_NS
            if (msg.arbitration_id, msg.is_extended_id) in routes:
                ecu.receive(msg, t_ns)
    finally:
        bus.shutdown()
    return ecu.rx


class _TraceEnd:
    """Scheduler task at every tick, after the frames due then and before the ECU's tick: stops
    the run after the ECU's last tick for the trace. Fast: the last tick at or before the last frame, so the ECU runs over the trace's
    span and no further (a run recorded by `vecu run` ends with its ECU's last tick; frames after
    it, e.g. an engine event just before the end, are received but no tick follows them, as in
    the live run). Live: the first tick after the last frame was sent, which drains it from the
    bus."""

    def __init__(self, sched: Scheduler, feeder: Feeder, live: bool) -> None:
        self.sched, self.feeder, self.live = sched, feeder, live
        self.reached = False

    def __call__(self, t_ns: int) -> None:
        feeder = self.feeder
        if not feeder.done:
            return
        if self.live:
            last_tick = (int(feeder.last_ns / feeder.speed) // TICK_NS + 1) * TICK_NS
        else:
            last_tick = feeder.last_ns // TICK_NS * TICK_NS
        if t_ns > last_tick:
            self.reached = True
            self.sched.stop()


class _Progress:
    """Progress on stderr every `every_s` of wall time (None: never): how far into the trace,
    x real time, idle time skipped. On a terminal one line rewritten in place, else lines."""

    def __init__(self, source: TraceSource, clock: SimClock | WallClock, speed: float,
                 every_s: float | None) -> None:
        self.source, self.clock, self.speed, self.every_s = source, clock, speed, every_s
        self.watch = Stopwatch()
        self.next_s = every_s
        self.shown = False
        self.end = "\r" if sys.stderr.isatty() else "\n"

    def update(self) -> None:
        if self.next_s is None or self.every_s is None:
            return
        wall = self.watch.elapsed()
        if wall < self.next_s:
            return
        self.next_s = wall + self.every_s
        source = self.source
        now_ns = int(self.clock.now_ns() * self.speed)  # the replay's time in the trace
        sim = now_ns / NS_PER_S
        trace = sim + source.skipped_before(now_ns) / NS_PER_S
        rate = f"{sim / wall:6.1f}x" if wall > 0 else ""
        skipped = source.stats.skipped_ns / NS_PER_S
        idle = f"  (idle {skipped:.1f} s skipped)" if skipped else ""
        done, size = source.bytes_read(), source.size_bytes
        if done is not None and size:
            frac = min(done / size, 1.0)
            head = f"[{'#' * int(frac * 30):<30}] {frac * 100:5.1f}%"
        else:
            head = f"{source.stats.frames_read} frames"
        line = f"{head}  {trace:8.1f} s  {rate}{idle}"
        sys.stderr.write(f"\r{line}" if self.end == "\r" else f"{line}\n")
        sys.stderr.flush()
        self.shown = True

    def close(self) -> None:
        if self.shown and self.end == "\r":
            sys.stderr.write("\n")
            sys.stderr.flush()


def _run_live(sched: Scheduler, clock: WallClock, feeder: Feeder, trace_end: _TraceEnd,
              progress: _Progress) -> None:
    """The player in its own thread on its own scheduler (same clock origin) and the ECU on this
    one: a long ECU tick does not hold back the frames due meanwhile. The GIL switch interval
    drops to SWITCH_INTERVAL_S for the run so that the player gets the GIL within that."""
    clock.start()
    player_clock = clock.sibling(spin_ns=PLAYER_SPIN_NS)
    player = Scheduler(player_clock)
    player.chain(0, feeder.release, name="trace", priority=PRIO_PLANT)
    failure: list[BaseException] = []

    def play() -> None:
        try:
            end = 0
            while not feeder.done:
                end += STEP_NS
                player.run_until(end)
        except BaseException as exc:  # noqa: BLE001 - re-raised in the caller's thread
            failure.append(exc)
            feeder.done = True

    previous = sys.getswitchinterval()
    gc.collect()
    gc.freeze()  # set-up objects out of the collector's way: no long pauses mid-run
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    thread = threading.Thread(target=play, name="vecu-replay-player", daemon=True)
    try:
        thread.start()
        end = 0
        while not trace_end.reached:
            end += STEP_NS
            sched.run_until(end)
            progress.update()
        thread.join()
    finally:  # (after Ctrl-C too: the player stops before the summary reads the feeder)
        feeder.done = True
        player.stop()
        thread.join(timeout=1.0)
        sys.setswitchinterval(previous)
        gc.unfreeze()
    if failure:
        raise failure[0]


def _trace_database(paths: tuple[str, ...], ecu_codec: DbcCodec) -> DbcCodec:
    """The user's DBCs (plus vecu's truth DBC when its IDs are free), or vecu's own."""
    if not paths:
        return ecu_codec
    db = DbcCodec(list(paths))
    truth = DbcCodec([builtin_dbc_path(TRUTH_DBC)])
    if not any(key in db.by_id for key in truth.by_id):
        db = DbcCodec([*paths, builtin_dbc_path(TRUTH_DBC)])
    return db


def _routes(config: ReplayConfig, smap: SignalMap, trace_db: DbcCodec, ecu_codec: DbcCodec,
            functions: list[EcuFunction]) -> dict[tuple[int, bool], Route]:
    if config.signal_map:
        return mapped_routes(smap, trace_db, ecu_codec, {f.name: f for f in functions})
    # vecu's own messages: the ECU's native table (E2E checks included), for the messages the
    # trace's database has
    routes = native_routes(ecu_codec, functions)
    return {k: r for k, r in routes.items() if r.codec.name in trace_db
            and (trace_db[r.codec.name].frame_id, trace_db[r.codec.name].is_extended) == k}


def _summary(config: ReplayConfig, source: TraceSource, feeder: Feeder, tally: FrameTally,
             ecu: EcuNode, smap: SignalMap, functions: list[EcuFunction], scorer: TruthScorer,
             wall_s: float, written: int, kernel_load_s: float) -> ReplaySummary:
    rx = ecu.rx.as_dict()
    sim_s = feeder.last_ns / NS_PER_S
    st = source.stats
    trace_s = sim_s + st.skipped_ns / NS_PER_S
    rejected = {k: v for k, v in rx.items()
                if k in ("dlc_errors", "crc_errors", "counter_errors", "value_errors",
                         "malformed") and v}
    rejected.update({f"decode_{k}": v for k, v in tally.decode_errors.items()})
    armed = {f.name for f in ecu.armed}
    fn_report: dict[str, FunctionReport] = {}
    for name in (spec.name for spec in registry.specs()):
        if name in smap.disabled:
            fn_report[name] = FunctionReport(False, reason=smap.disabled[name])
        else:
            fn = next((f for f in functions if f.name == name), None)
            if fn is None:  # not a function of this replay's ECU (an FMU without --fmu)
                continue
            fn_report[name] = FunctionReport(
                True, ran=name in armed, estimates_sent=getattr(fn, "estimates_sent", None),
                reason=None if name in armed else "no input frames in the trace")
    return ReplaySummary(
        trace=config.trace,
        mode="live" if config.speed is not None else "fast",
        config={k: v for k, v in asdict(config).items()
                if k not in ("progress", "progress_every_s", "keep_series")
                and not (k == "gateway" and v is None)},
        error=source.error,
        frames=ReplayFrames(
            read=st.frames_read,
            decoded=rx["accepted"] + tally.truth + tally.decoded_other,
            ignored_known=rx["ignored"], unknown_id=rx["unknown_id"],
            error_frames=rx["error_frames"], remote_frames=rx["remote_frames"],
            rejected=sum(rejected.values()), rejected_by_reason=rejected, truth=tally.truth,
            out_of_order=st.out_of_order, late=st.late, non_finite_time=st.non_finite_time,
            ecu_rx=rx),
        functions=fn_report,
        map=MapReport(config.signal_map, list(smap.notes)),
        trace_duration_s=round(trace_s, 6),
        simulated_s=round(sim_s, 6),
        idle_gaps=IdleGaps(config.idle_gap_s, st.gaps, round(st.skipped_ns / NS_PER_S, 6),
                           round(st.longest_gap_ns / NS_PER_S, 6),
                           [[round(a / NS_PER_S, 6), round(g / NS_PER_S, 6)]
                            for a, g in st.gap_list]),
        wall_time_s=round(wall_s, 4),
        x_realtime=round(sim_s / wall_s, 2) if wall_s > 0 else None,
        frames_per_s=round(st.frames_read / wall_s) if wall_s > 0 else None,
        kernels=kernels.backend(),
        frames_written=written,
        ecu_overruns=ecu.overruns,
        score=scorer.summary() if scorer.active else None,
        schedule_error=feeder.schedule_error.summary() if config.speed is not None else None,
        kernel_load_s=round(kernel_load_s, 3))


__all__ = ["SCHEDULE_ERROR_LIMIT_US", "FrameTally", "ReplayConfig", "ReplayResult", "TraceReadError",
           "ecu_codec_of", "replay", "warm_up_ecu"]
