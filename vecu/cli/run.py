"""`vecu run`: plant + fault injector + ECU on a python-can bus; summary, log, JSON and plot."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING

from vecu import argtypes
from vecu.cli import (
    add_fmu_options,
    add_set_option,
    configure_logging,
    param_sets,
)
from vecu.errors import BadArgumentError
from vecu.estimators.registry import ESTIMATORS  # names only: imports nothing heavy

if TYPE_CHECKING:
    from vecu.summary import RunSummary


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run plant, fault injector and virtual ECU on a CAN bus",
                       description="Run the throttle plant, the fault injector and the virtual ECU "
                                   "on one python-can bus (default: in-process virtual bus, "
                                   "simulated clock).")
    p.add_argument("--duration", type=argtypes.run_seconds, default=10.0, metavar="S",
                   help=f"seconds, {argtypes.TICK_S:g}..{argtypes.RUN_MAX_S:g} (default 10)")
    p.add_argument("--seed", type=argtypes.seed, default=0, help="random seed, 0..2**63-1 (default 0)")
    p.add_argument("--interface", help="python-can interface (default: python-can config, else virtual)")
    p.add_argument("--channel", help="python-can channel (default: config, else 'vecu')")
    p.add_argument("--bitrate", type=argtypes.positive_int, help="bitrate for interfaces that need one")
    p.add_argument("--kill-tps-at", type=argtypes.kill_time, default="half", metavar="T",
                   help="inject the TPS fault at T s, or 'none' (default: half the duration)")
    p.add_argument("--fault", default="dead",
                   help="dead, short_supply, stuck, frames_stop, offset, gain, noise (default dead)")
    p.add_argument("--fault-value", type=argtypes.finite, metavar="X",
                   help="offset in V (default 0.5), gain G in [0,1] (0.5), noise sigma in V (0.3)")
    p.add_argument("--kill-swa-at", type=argtypes.kill_time, default=None, metavar="T",
                   help="inject an SWA sensor fault at T s (default: none)")
    p.add_argument("--swa-fault", default="dead", metavar="KIND",
                   help="SWA fault kind, as --fault (offset/noise in deg, default dead)")
    p.add_argument("--swa-fault-value", type=argtypes.finite, metavar="X", help="SWA fault value")
    p.add_argument("--noise-scale", type=argtypes.noise_scale, default=None, metavar="A",
                   help="process-noise scale alpha of the throttle model, plant and ECU (1 = paper; "
                        f"0..{argtypes.NOISE_SCALE_MAX:g})")
    p.add_argument("--estimator", default=None, help="throttle estimator (default production; = --set ecu.throttle.estimator=NAME)")
    p.add_argument("--manifold-filter", default=None, choices=ESTIMATORS["manifold"].names,
                   help="manifold filter (default sdkf; = --set ecu.manifold.filter=NAME)")
    add_set_option(p, "plant.* and ecu.*", params_file=True)
    p.add_argument("--set-at", dest="sets_at", action="append", default=[],
                   metavar="S:ecu.PATH=VALUE",
                   help="calibrate a live ecu.* leaf at S s (acts from the next tick, as an XCP "
                        "write then; docs/xcp.md), repeatable")
    p.add_argument("--realtime", action="store_true", help="pace on the wall clock instead of simulated time")
    p.add_argument("--log", type=argtypes.out_log, metavar="FILE", help="write every frame; format by suffix (.log .asc .blf .mf4 ...)")
    p.add_argument("--no-truth", dest="truth", action="store_false",
                   help="leave the debug truth frames (vecu/dbc/vecu_truth.dbc) out of --log")
    p.add_argument("--summary", type=argtypes.out_file, metavar="FILE.json", help="write the JSON summary")
    p.add_argument("--plot", type=argtypes.out_plot, metavar="FILE.png", help="write a truth-vs-estimate plot")
    p.add_argument("--gateway", metavar="GATEWAY.toml",
                   help="route between the buses this gateway config names; plant and ECU on its "
                        "first bus (docs/gateway.md 'Routing between buses')")
    add_fmu_options(p)
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.set_defaults(func=main)


def _sets_at(items: list[str], duration: float) -> tuple[tuple[float, str, str], ...]:
    """--set-at S:ecu.PATH=VALUE as (at_s, path, value) (time, path and value are checked by
    vecu.simulation.run_config)."""
    out = []
    for item in items:
        at, sep, rest = item.partition(":")
        path, eq, value = rest.partition("=")
        try:
            at_s = float(at)
        except ValueError:
            at_s = -1.0
        if not sep or not eq:
            at_s = -1.0
        out.append((at_s, path.strip(), value.strip()))
    return tuple(out)


def main(args: argparse.Namespace) -> int:
    configure_logging(args.quiet)

    from vecu.runner import run
    from vecu.simulation import run_config

    config = run_config(  # the options as vecu.simulate takes them; checked, user errors first
        args.duration, seed=args.seed, kill_tps_at_s=args.kill_tps_at, fault=args.fault,
        fault_value=args.fault_value, realtime=args.realtime, interface=args.interface,
        channel=args.channel, bitrate=args.bitrate, log=args.log, truth=args.truth,
        keep_series=bool(args.plot), kill_swa_at_s=args.kill_swa_at, swa_fault=args.swa_fault,
        swa_fault_value=args.swa_fault_value, noise_scale=args.noise_scale,
        estimator=args.estimator, manifold_filter=args.manifold_filter, sets=param_sets(args),
        set_at=_sets_at(args.sets_at, args.duration), fmu=args.fmu, fmu_map=args.fmu_map)
    if args.gateway:
        from vecu.gateway.routes_config import load_routing_config
        from vecu.gateway.sim import run_with_gateway

        routing = load_routing_config(args.gateway)  # every problem before any bus opens
        if args.channel or args.interface:
            raise BadArgumentError("--gateway runs the buses its file names: no --interface or "
                                   "--channel")
        if not routing.buses:
            raise BadArgumentError(f"--gateway {args.gateway}: names no [buses.NAME] to route")
        result = run_with_gateway(config, routing)
    else:
        result = run(config)
    if args.summary:
        Path(args.summary).write_text(json.dumps(result.summary, indent=2) + "\n")
    if args.plot and result.throttle_series is not None:
        from vecu.plot import plot_run
        plot_run(result, args.plot)
    if not args.quiet:
        print(format_summary(result.report))
        print(outputs_line(plot=args.plot, log=args.log, summary=args.summary))
    return 0


OUTPUTS = (("plot", "--plot FILE.png"), ("log", "--log FILE.blf"), ("summary", "--summary FILE.json"))


def outputs_line(**given: str | None) -> str:
    """Where the run's evidence went, and the options that would keep the rest."""
    kept = [f"{what} {given[what]}" for what, _ in OUTPUTS if given.get(what)]
    missing = [option for what, option in OUTPUTS if not given.get(what)]
    parts = [f"kept: {', '.join(kept)}"] if kept else []
    if missing:
        parts.append(f"add {' '.join(missing)} to keep {'them' if len(missing) > 1 else 'it'}")
    return "outputs: " + "; ".join(parts)


def format_summary(s: RunSummary) -> str:
    """The run's summary as a few lines: timing, the TPS fault, frames, each other function."""
    th = s.throttle
    det = th.detection
    fr = s.frames
    load = (f"; kernels loaded in {s.kernel_load_s:.1f} s before, not counted"
            if s.kernel_load_s else "")
    lines = [(f"vecu run: {s.sim_time_s:.3f} s in {s.wall_time_s:.2f} s wall "
             f"({s.x_realtime}x real time, {s.kernels} kernels{load}), {s.ticks} ticks, "
             f"{s.overruns} overruns")]
    if det.kill_time_s is None:
        lines.append("TPS: no fault injected")
    elif det.detected:
        lines.append(f"TPS fault '{th.fault}' at {det.kill_time_s:.3f} s: detected as "
                     f"{det.detected_as} after {det.detection_latency_ms:.1f} ms; "
                     f"broadcasting the {th.final_source} (status {th.final_status})")
    else:
        lines.append(f"TPS fault '{th.fault}' at {det.kill_time_s:.3f} s: NOT detected")
    if det.false_alarm:
        lines.append(f"WARNING: TPS fault reported before any injection (at {det.detection_time_s} s)")
    for phase, label in ((th.before_kill, "before fault"), (th.after_kill, "after fault")):
        b, e = phase.broadcast_error_deg, phase.estimate_error_deg
        if b.n:
            lines.append(f"  {label:12s} broadcast error {b.mean:+6.2f} ± {b.std:5.2f} deg | "
                         f"estimator ({th.estimator}) {e.mean:+6.2f} ± {e.std:5.2f} deg")
    rx = fr.ecu_rx
    lines.append(f"frames: sent {fr.sent} (plant {fr.plant_sent}, ecu {fr.ecu_sent}), "
                 f"ECU received {fr.received}, rejected {fr.rejected} "
                 f"(dlc {rx['dlc_errors']}, crc {rx['crc_errors']}, counter {rx['counter_errors']}, "
                 f"value {rx['value_errors']}, unknown id {rx['unknown_id']})")
    lines.append(f"broadcast: {th.missing_broadcasts} missing ticks, {th.nan_outputs} NaN")
    for section in s.functions.values():  # the other functions, each in its own words
        lines.extend(section.lines())
    if s.gateway is not None:
        lines.extend(gateway_lines(s.gateway))
    return "\n".join(lines)


def gateway_lines(figures: dict) -> list[str]:
    """Each route's counters and latency (vecu.gateway.routing's summary)."""
    lines = []
    for name, r in figures["routes"].items():
        lat = r["latency_us"]
        dropped = ", ".join(f"{k} {v}" for k, v in r["dropped"].items()) or "none"
        lines.append(f"gateway {name}: in {r['in']}, out {r['out']}, dropped {dropped}; latency "
                     f"min/mean/p99/max {lat['min']}/{lat['mean']}/{lat['p99']}/{lat['max']} us, "
                     f"queue peak {r['queue_peak']}")
    if figures["denied"]:
        lines.append("gateway denied: " + ", ".join(f"{k} {v}" for k, v in figures["denied"].items()))
    return lines
