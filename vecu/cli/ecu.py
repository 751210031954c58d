"""`vecu ecu`: the virtual ECU alone in its process on a python-can bus, paced by the wall clock."""

from __future__ import annotations

import argparse
from collections import deque
from typing import Any

from vecu import argtypes
from vecu.cli import (
    add_fmu_options,
    add_set_option,
    configure_logging,
    param_sets,
    with_fmu,
)
from vecu.estimators.registry import ESTIMATORS  # names only: imports nothing heavy
from vecu.instances import FRAME_STRIDE, MAX_INSTANCE
from vecu.live.args import add_live_arguments, function_switches, live_options

MAX_STATUS_CHANGES = 64
HOST_GAP_MS = 100.0  # longer than the stalls of a loaded machine, short for a lost sender


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("ecu", help="run the virtual ECU alone, live, on a CAN bus",
                       description="The virtual ECU in its own process: 1 ms base tick on the wall "
                                   "clock, estimates broadcast on the bus (see docs/live.md). "
                                   "It serves UDS on ISO-TP: requests on 0x7E0 (functional "
                                   "0x7DF), responses on 0x7E8; --set ecu.uds.request_id=... "
                                   "moves them (docs/uds.md). It is an XCP-on-CAN slave: "
                                   "commands on 0x7F0, responses and DAQ on 0x7F1 (ecu.xcp.*), "
                                   "described by `vecu a2l` (docs/xcp.md). --instance N moves "
                                   "all of these IDs and the ECU's frames, so that several "
                                   "ECUs share a bus (docs/live.md).")
    add_live_arguments(p)
    p.add_argument("--instance", type=argtypes.bounded(0, MAX_INSTANCE, integer=True), default=None,
                   metavar="N", help=f"ECU instance 0..{MAX_INSTANCE} (ecu.instance): UDS on "
                   "0x7E0+N / 0x7E8+N, XCP on 0x7F0+2N / 0x7F1+2N, the ECU's frames at "
                   f"their DBC ID + N*0x{FRAME_STRIDE:X} (default 0: the DBC's IDs)")
    p.add_argument("--estimator", default=None, help="throttle estimator (default production)")
    add_set_option(p, "ecu.*")
    add_fmu_options(p)
    p.add_argument("--manifold-filter", default=None, choices=ESTIMATORS["manifold"].names,
                   help="manifold filter (default sdkf)")
    p.add_argument("--sync-timeout", type=argtypes.bounded(0.0, 3600.0), default=10.0, metavar="S",
                   help="wait up to S s for the plant's ETB_Wattmeter frames to put the 1 ms grid "
                        "just after their arrival; 0: start at once, unaligned (default 10)")
    p.add_argument("--sync-margin-us", type=argtypes.bounded(0.0, 1000.0, unit="us"), default=150.0, metavar="US",
                   help="start each tick US after the late edge of the arrivals, 0..1000 (default 150)")
    p.add_argument("--tps-timeout-cycles", type=argtypes.bounded(1, 10_000, integer=True), metavar="N",
                   help="TPS frames missing for N periods is a timeout fault (default: the "
                        "monitor's, 3); raise it on a machine that stalls processes")
    p.add_argument("--host-gap-ms", type=argtypes.bounded(0.0, 10_000.0, unit="ms"),
                   default=HOST_GAP_MS, metavar="MS",
                   help="a silence of every frame on the bus shorter than MS is a stalled sender "
                        "(the host), not a silent sensor: no timeout, the estimate is broadcast; "
                        f"0: off (default {HOST_GAP_MS:g}; docs/live.md)")
    p.add_argument("--security-seed", type=argtypes.seed, default=None, metavar="N",
                   help="draw UDS security access seeds from N, reproducibly (for tests); "
                        "default: the OS's entropy, a new seed sequence on every start")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    configure_logging(args.quiet)

    from vecu.assembly import build_functions, schedule_ecu
    from vecu.config import RunConfig
    from vecu.ecu.node import EcuNode
    from vecu.ecu.sensor_monitor import SOURCE_SENSOR, SensorStatus
    from vecu.functions import function_codec
    from vecu.live.process import LiveProcess
    from vecu.live.sync import PhaseSync, sync_to_trigger
    from vecu.runner import attach_xcp_server, warm_up
    from vecu.stats import RunningStats
    from vecu.uds.server import attach_uds

    sets = param_sets(args, only="ecu.")
    if args.instance is not None:
        sets.insert(0, ("ecu.instance", args.instance))
    if args.tps_timeout_cycles is not None:
        sets.append(("ecu.throttle.tps_monitor.timeout_cycles", args.tps_timeout_cycles))
    config = with_fmu(RunConfig(
        duration_s=args.duration or 1.0, seed=args.seed, kill_tps_at_s=None,
        **function_switches(args),  # type: ignore[arg-type]  # the functions' bool switches
    ), args).with_params(sets, noise_scale=args.noise_scale, estimator=args.estimator,
                                     manifold_filter=args.manifold_filter)
    codec = function_codec(config.params.ecu.instance, config)  # + plug-ins' and an FMU's DBCs
    config.validate()
    fns = build_functions(config, codec)
    proc = LiveProcess(live_options(args, "ecu"), codec, "VECU",
                       latency=("ETB_Wattmeter", "ECU_ThrottleEstimate"))
    summary: dict[str, Any] | None = None
    try:
        ecu = EcuNode(proc.bus, codec, fns.enabled(), host_gap_ms=args.host_gap_ms,
                      rx_budget=config.params.ecu.rx)
        # a tester's UDS (docs/uds.md); security seeds from the OS's entropy unless asked for
        uds = attach_uds(ecu, config.params.ecu.uds, args.security_seed)
        xcp = attach_xcp_server(ecu, config)  # measurement and calibration (docs/xcp.md)
        proc.consume_only(ecu.consumed_ids)
        thr = fns.throttle
        accuracy = RunningStats()
        meter = proc.meter("ecu")
        node_tick = ecu.tick
        ok = SensorStatus.OK

        changes: deque[tuple[int, str]] = deque(maxlen=MAX_STATUS_CHANGES)
        last = [ok]

        def tick(t_ns: int) -> None:
            node_tick(t_ns)
            status = thr.status
            if status is not last[0]:
                last[0] = status
                changes.append((t_ns, status.name.lower()))
            if thr.source == SOURCE_SENSOR and status == ok:
                accuracy.add(thr.estimator.theta_deg - thr.angle)

        ecu.tick = meter.wrap(tick)  # type: ignore[method-assign]  # the live meter times each tick (a wrapper, not a patch of the class)
        task = meter.stats = schedule_ecu(proc.sched, ecu)
        proc.sched.every(10_000_000, lambda t: setattr(ecu, "overruns", task.overruns),
                         name="overrun-count", priority=45)  # ECU_Status reports them
        proc.status_lines = lambda: [(
            f"  throttle: {'sensor' if thr.source == SOURCE_SENSOR else 'ESTIMATE'}, TPS "
            f"{thr.status.name.lower()}, DTC {thr.monitor.dtc.name.lower()}, host gaps "
            f"{thr.monitor.host_gaps}; rx accepted "
            f"{ecu.rx.accepted}, rejected {ecu.rx.rejected}, ignored {ecu.rx.ignored}")] + (
            [] if uds is None else [(
                f"  uds: {uds.stats.requests} requests ({uds.stats.negative} negative), session "
                f"{uds.session}, security {'unlocked' if uds.security.unlocked else 'locked'}, "
                f"broadcast {'on' if ecu.broadcast_enabled else 'OFF'}")]) + (
            [] if xcp is None else [(
                f"  xcp: {xcp.proc.stats.commands} commands ({xcp.proc.stats.negative} refused), "
                f"{'connected' if xcp.proc.connected else 'no master'}, "
                f"{xcp.proc.stats.calibrations} calibrations, {xcp.daq.stats.odts_sent} DAQ ODTs "
                f"({xcp.daq.stats.odts_lost} lost)")])
        warm_up(config)
        proc.signal_ready()
        sync = PhaseSync(0, None, None, args.sync_margin_us, None)
        if args.sync_timeout > 0:
            watt = codec["ETB_Wattmeter"]
            sync = sync_to_trigger(proc.bus, (watt.frame_id, watt.is_extended),
                                   timeout_s=args.sync_timeout, margin_us=args.sync_margin_us,
                                   arrival_timestamps=proc.bus.latency.arrival_timestamps,
                                   stop=lambda: proc.stop.is_set)
        try:
            proc.run(sync.start_at_perf_ns)
        finally:
            ecu.overruns = task.overruns
            summary = proc.summary(_ecu_summary(proc, ecu, fns, accuracy, sync, changes))
            if uds is not None:
                summary["uds"] = uds.summary()
            if xcp is not None:
                summary["xcp"] = xcp.summary()
            proc.write_summary(summary)
    finally:
        proc.close()
    if not args.quiet and summary is not None:
        print(format_ecu_summary(summary))
    return LiveProcess.end(summary)


def _ecu_summary(proc, ecu, fns, accuracy, sync, changes) -> dict[str, Any]:
    from vecu.clock import NS_PER_S
    from vecu.ecu.sensor_monitor import DtcState
    from vecu.instances import ECU_NODE

    thr = fns.throttle
    mon = thr.monitor
    meter = proc.meters[0]
    releases = (meter.stats.runs + meter.stats.skipped) if meter.stats else 0
    elapsed = max(proc.elapsed_s, 1e-9)
    first = mon.first_fault_ns
    lat = proc.bus.latency
    estimates = {f.name: f.estimates_sent for f in fns.enabled()}
    return {
        # which ECU this is on the bus: its instance and the CAN ID of each of its frames on it
        # (vecu.instances; the left-out functions' frames too)
        "instance": ecu.codec.instance,
        "can_ids": {fc.name: f"0x{fc.frame_id:X}"
                    for fc in sorted((ecu.codec.by_id[k] for k in ecu.codec.sent_by(ECU_NODE)),
                                     key=lambda fc: fc.frame_id)},
        "sync": sync.as_dict(),
        "latency_us": {
            **lat.hist.summary(),
            "measures": ("ETB_Wattmeter " + ("kernel receive timestamp" if lat.arrival_timestamps
                                             else "taken from the bus by the ECU")
                         + " -> return of send() of the next ECU_ThrottleEstimate"),
        },
        "rx": ecu.rx.as_dict(),  # rx.shed: frames past ecu.rx.frames_per_tick, dropped (a flood)
        # requests a diagnostic server could not handle (counted, answered or dropped; docs/live.md)
        "handler_errors": ecu.handler_errors,
        "rx_peak_per_tick": ecu.rx_peak,  # the most frames read in one tick (ecu.rx.* bound it)
        # what the host did (issue 29): this ECU not running, and what the sensor frames'
        # sender reported of its own skipped / late ticks (PLANT_Host)
        # every DTC confirmation, per monitored sensor: epoch seconds (bench: false DTCs)
        "dtc_confirmed_epoch_s": {
            name: [None if proc.start_epoch_s is None
                   else round(proc.start_epoch_s + t / NS_PER_S, 3)
                   for t, state in mon.dtc_item.history if state == DtcState.CONFIRMED]
            for name, mon in ecu.monitors.items()},
        # every kept timeout with who dropped the frames as far as the host can tell
        # (sender-host / ecu-host / sensor: SensorMonitor.timeout_causes)
        "timeout_causes": {
            name: [{**e, "epoch_s": None if proc.start_epoch_s is None
                    else round(proc.start_epoch_s + e["t_s"], 3)} for e in mon.timeout_causes()]
            for name, mon in ecu.monitors.items()},
        "host": {"ecu_stalled_ms": round(ecu.host.stalled_ns / 1e6, 1),
                 "sender_skipped_sends": ecu.host.sender_skipped,
                 "sender_late_sends": ecu.host.sender_late},
        "frames": {"ecu_sent": ecu.frames_sent, "send_errors": ecu.send_errors,
                   "decoded": ecu.rx.accepted,
                   "decoded_per_s": round(ecu.rx.accepted / elapsed, 1),
                   "answered_per_s": round(ecu.frames_sent / elapsed, 1)},
        "estimates": estimates,
        # 1 ms releases without an ECU_ThrottleEstimate (skipped after a stall, or send failed)
        "lost_throttle_estimates": releases - thr.estimates_sent,
        "throttle": {
            "estimator": thr.estimator.name,
            "estimator_resets": thr.estimator.resets,
            "estimator_faults": thr.estimator_faults,
            "estimate_vs_sensor_deg": accuracy.as_dict(),
            "first_fault_s": None if first is None else first / NS_PER_S,
            "first_fault_epoch_s": (None if first is None or proc.start_epoch_s is None
                                    else proc.start_epoch_s + first / NS_PER_S),
            "detected_as": mon.first_fault_status.name.lower() if mon.first_fault_status else None,
            # silences past the TPS deadline the host caused (the ECU not running, or every
            # frame silent for < --host-gap-ms): no timeout, the estimate broadcast meanwhile
            "host_gaps": mon.host_gaps,
            "ecu_stalled_ms": round(ecu.host.stalled_ns / 1e6, 1),
            "dtc": mon.dtc.name.lower(),
            "final_source": "sensor" if thr.source == 0 else "estimate",
            "final_status": thr.status.name.lower(),
            # the last TPS status changes: [ECU time s, epoch s, status]
            "status_changes": [[t / NS_PER_S, None if proc.start_epoch_s is None
                                else round(proc.start_epoch_s + t / NS_PER_S, 6), name]
                               for t, name in changes],
        },
    }


def format_ecu_summary(s: dict[str, Any]) -> str:
    t = s["ticks"]["ecu"]
    j, lat, th = t["jitter_us"], s["latency_us"], s["throttle"]
    fault = ("none" if th["first_fault_s"] is None
             else f"first {th['detected_as']} at {th['first_fault_s']:.3f} s")
    lines = [
        (f"vecu ecu{' instance ' + str(s['instance']) if s.get('instance') else ''}: "
         f"{s['elapsed_s']:.1f} s on {s['interface']} {s['channel']}, stopped by "
         f"{s['stopped_by']}; {t['releases']} ticks, {t['overruns']} overruns "
         f"({t['overrun_pct'] or 0:.3f} %), {s['lost_throttle_estimates']} throttle estimates lost"),
        (f"  tick jitter p50 {j['p50_us']} p99 {j['p99_us']} max {j['max_us']} us; frame-in -> "
         f"estimate-out p50 {lat['p50_us']} p99 {lat['p99_us']} max {lat['max_us']} us"),
        (f"  rx {s['rx']['received']} frames ({s['frames']['decoded_per_s']}/s decoded), rejected "
         f"{s['rx']['rejected']}, own echo {s['bus']['own_echo']}, foreign frames on the ECU's "
         f"IDs {s['bus']['foreign_own_id']}, rx errors "
         f"{s['bus']['rx_errors']}; sent {s['frames']['ecu_sent']}"),
        (f"  throttle: estimate - sensor {th['estimate_vs_sensor_deg']}; TPS fault {fault}; "
         f"{th['host_gaps']} host gaps (ECU not running {th['ecu_stalled_ms']} ms); "
         f"broadcasting the {th['final_source']}"),
    ]
    h = s["host"]
    if h["ecu_stalled_ms"] or h["sender_skipped_sends"] or h["sender_late_sends"]:
        lines.append(f"  host: this ECU not running {h['ecu_stalled_ms']} ms; the sensor frames' "
                     f"sender reported {h['sender_skipped_sends']} ticks skipped, "
                     f"{h['sender_late_sends']} late (PLANT_Host): timeouts in that time are the "
                     "host's doing, not a sensor's (DTC snapshots: DIDs 0x0002-0x0004)")
    lines += _timeout_lines(s.get("timeout_causes", {}))
    return "\n".join(lines)


_CAUSE_TEXT = {
    "sender-host": ("the host, not the sensor: the sender skipped {sender_skipped} and delayed "
                    "{sender_late} sends then"),
    "ecu-host": "the host, not the sensor: this ECU was not running {ecu_not_running_ms:.1f} ms of it",
    "sensor": "the sensor or its wiring: nothing on the host explains it",
}
TIMEOUT_LINES_SHOWN = 5


def _timeout_lines(causes: dict[str, list[dict]]) -> list[str]:
    """One line per sensor timeout (the first few): when, how long silent, and who dropped the
    frames as far as the host can tell."""
    events = sorted(((e["t_s"], name, e) for name, evs in causes.items() for e in evs),
                    key=lambda item: item[0])
    lines = [f"  timeout {name} at {t:.3f} s, silent {e['silent_ms']:.1f} ms: "
             + _CAUSE_TEXT[e["cause"]].format(**e)
             for t, name, e in events[:TIMEOUT_LINES_SHOWN]]
    if len(events) > TIMEOUT_LINES_SHOWN:
        lines.append(f"  … {len(events) - TIMEOUT_LINES_SHOWN} more timeouts in the summary "
                     "(timeout_causes)")
    return lines
