"""`vecu plant`: the simulated vehicle alone in its process, sending sensor frames live."""

from __future__ import annotations

import argparse
from typing import Any

from vecu import argtypes
from vecu.cli import (
    UserInputError,
    add_set_option,
    configure_logging,
    param_sets,
)
from vecu.live.args import add_live_arguments, function_switches, live_options

# without --duration the precomputed steering manoeuvre covers this much, then holds its end
STEERING_HORIZON_S = 900.0
# catch-up window: below the ECU's shortest sensor deadline (TPS: 3 x 1 ms after a frame is due
# is too short to save, ESC_Motion 3 x 2 ms, SWA 3 x 10 ms), a burst of at most ~100 frames
CATCH_UP_MS = 20.0
HOST_STATUS_NS = 100_000_000  # PLANT_Host every 100 ms


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plant", help="run the plant simulator alone, live, on a CAN bus",
                       description="The plant in its own process: sensor frames on the wall clock "
                                   "(1 ms base tick), obeying FI_Command frames (see docs/live.md).")
    add_live_arguments(p)
    add_set_option(p, "plant.*")
    p.add_argument("--truth", action="store_true",
                   help="also send the debug truth frames (vecu/dbc/vecu_truth.dbc)")
    p.add_argument("--extra-load", type=argtypes.bounded(0.0, 100_000.0), default=0.0, metavar="FRAMES_PER_S",
                   help="pad the bus with this many extra ESC_Motion frames per second (copies of "
                        "the current one), for throughput tests; needs the speed part")
    p.add_argument("--steering-horizon", type=argtypes.bounded(1.0, 86_400.0), default=STEERING_HORIZON_S, metavar="S",
                   help="kept for old command lines, no effect on the drive: the steering "
                        "manoeuvre is made as the car drives, for as long as the plant runs "
                        f"(default {STEERING_HORIZON_S:g})")
    p.add_argument("--catch-up-ms", type=argtypes.bounded(0.0, 1000.0, unit="ms"),
                   default=CATCH_UP_MS, metavar="MS",
                   help="after a stall of this process, send the frames of the missed 1 ms "
                        "ticks late, back to back, if they are at most MS old (older ones are "
                        f"skipped); 0: skip them all (default {CATCH_UP_MS:g}; docs/live.md)")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    configure_logging(args.quiet)

    from vecu.assembly import build_plant, schedule_plant
    from vecu.config import RunConfig
    from vecu.functions import function_codec
    from vecu.live.load import ExtraLoad
    from vecu.live.process import LiveProcess
    from vecu.runner import warm_up

    if args.extra_load and args.no_speed:
        raise UserInputError("--extra-load sends ESC_Motion copies: it needs the speed part")
    horizon = args.duration if args.duration is not None else args.steering_horizon
    config = RunConfig(duration_s=horizon, seed=args.seed,
                       kill_tps_at_s=None,
                       **function_switches(args),  # type: ignore[arg-type]  # the functions' bool switches
                       ).with_params(param_sets(args, only="plant."), noise_scale=args.noise_scale)
    codec = function_codec()  # vecu's DBCs and the plug-in functions' own (as run, replay)
    config.validate()
    proc = LiveProcess(live_options(args, "plant"), codec, "PLANT")
    summary: dict[str, Any] | None = None
    try:
        plant = build_plant(config, codec, proc.bus, truth=args.truth)
        proc.consume_only(plant.consumed_ids)
        extra = ExtraLoad(codec, plant, args.extra_load) if args.extra_load else None
        meter = proc.meter("plant")
        node_tick = plant.tick

        def tick(t_ns: int) -> None:
            node_tick(t_ns)
            if extra is not None:
                extra.tick(t_ns)

        plant.tick = meter.wrap(tick)  # type: ignore[method-assign]  # the live meter times each tick (a wrapper, not a patch of the class)
        schedule_plant(proc.sched, plant, catch_up_ns=round(args.catch_up_ms * 1e6))
        meter.stats = next(t for t in proc.sched.stats if t.name == "plant")
        host = HostReport(codec, plant.send, meter.stats)  # counted with the plant's frames
        proc.sched.every(HOST_STATUS_NS, host.send, name="host-status", offset_ns=HOST_STATUS_NS,
                         priority=50)
        inj = plant.injector
        proc.status_lines = lambda: [(
            f"  faults: TPS {_active(inj, 'TPS')}, SWA {_active(inj, 'SWA')}; commands "
            f"{sum(e.source == 'can' for e in inj.events)} obeyed, {inj.rejected_commands} rejected"),
            host.status_line()]
        warm_up(config)
        proc.signal_ready()
        try:
            proc.run()
        finally:
            summary = proc.summary({
                "frames": {"plant_sent": plant.frames_sent, "send_errors": plant.send_errors,
                           "extra_load_sent": extra.sent if extra else 0,
                           "sent_per_s": round(plant.frames_sent / max(proc.elapsed_s, 1e-9), 1),
                           "received": plant.frames_received, "rx_shed": plant.rx_shed},
                "handler_errors": plant.handler_errors,
                "steering_horizon_s": None if args.no_steering else horizon,
                "fault_events": [{"t_s": e.t_ns / 1e9, "target": e.target.name.lower(),
                                  "kind": e.kind.name.lower(), "value": e.value,
                                  "source": e.source} for e in inj.events],
                "rejected_fault_commands": inj.rejected_commands,
                # the host's doing, not a sensor's: ticks whose frames went out late or never
                "host": host.as_dict(),
            })
            proc.write_summary(summary)
    finally:
        proc.close()
    if not args.quiet and summary is not None:
        t = summary["ticks"]["plant"]
        print(f"vecu plant: {summary['elapsed_s']:.1f} s on {summary['interface']} "
              f"{summary['channel']}, stopped by {summary['stopped_by']}; {t['releases']} ticks, "
              f"{t['overruns']} overruns, jitter p99 {t['jitter_us']['p99_us']} us; sent "
              f"{summary['frames']['plant_sent']} frames, {len(summary['fault_events'])} fault "
              f"commands obeyed, own echo {summary['bus']['own_echo']}")
        h = summary["host"]
        if h["skipped_sends"] or h["late_sends"]:
            print(f"  host delayed this plant: {h['skipped_sends']} ticks' frames never sent, "
                  f"{h['late_sends']} sent late (max lateness {h['max_lateness_ms']} ms); the "
                  "ECU's timeouts in that time are the host's doing, not a sensor's")
    return LiveProcess.end(summary)


class HostReport:
    """The plant's own delays: in PLANT_Host frames on the bus, the status panel, the summary."""

    def __init__(self, codec, send, stats) -> None:
        self._codec = codec["PLANT_Host"] if "PLANT_Host" in codec else None  # noqa: SIM401 (no .get)
        self._send, self._stats, self._counter, self.sent = send, stats, 0, 0

    def as_dict(self) -> dict[str, Any]:
        st = self._stats
        return {"skipped_sends": st.skipped, "late_sends": st.caught_up,
                "max_lateness_ms": round(st.max_lateness_ns / 1e6, 1),
                "host_status_frames": self.sent}

    def status_line(self) -> str:
        d = self.as_dict()
        return (f"  host: {d['skipped_sends']} ticks' frames skipped, {d['late_sends']} sent "
                f"late, max lateness {d['max_lateness_ms']} ms")

    def send(self, t_ns: int) -> None:
        if self._codec is None:
            return
        d = self.as_dict()
        self._send(self._codec.frame({
            "PH_SkippedSends": min(d["skipped_sends"], 65535),
            "PH_LateSends": min(d["late_sends"], 65535),
            "PH_MaxLateness": min(d["max_lateness_ms"], 6553.5),
            "PH_Counter": self._counter}, t_ns / 1e9))
        self._counter = (self._counter + 1) & 0xF
        self.sent += 1


def _active(inj, target: str) -> str:
    from vecu.faults import FaultTarget

    kind = inj.active(FaultTarget[target])
    return "ok" if kind is None else kind.name.lower()
