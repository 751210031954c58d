"""`vecu replay`: the ECU on a recorded trace, fast (simulated clock) or live onto a bus."""

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
    fmu_binding,
    param_sets,
)

if TYPE_CHECKING:
    from vecu.replay.summary import ReplaySummary, ScoreSection


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "replay", help="run the ECU's estimators on a recorded trace (candump .log, .asc, .blf, ...)",
        description="Feed a recorded trace (any format python-can reads: .log .asc .blf .trc .csv "
                    ".mf4, also .gz) into the virtual ECU and write its estimate frames. Fast "
                    "(default): simulated clock, faster than real time, bit-identical across runs. "
                    "--speed X: send the trace onto a python-can bus at X times the recorded pace "
                    "with the ECU listening, and report the schedule error.")
    p.add_argument("traces", nargs="+", metavar="TRACE|DIR|GLOB",
                   help="trace file; several, directories (every trace in them) or globs make a "
                        "fleet, replayed on Dask (--out-dir)")
    p.add_argument("--dbc", action="append", default=[], metavar="FILE",
                   help="the trace's DBC (repeatable; default: vecu's own DBCs)")
    p.add_argument("--map", dest="signal_map", metavar="MAP.toml",
                   help="signal map: which message.signal of --dbc feeds each ECU input")
    p.add_argument("--out", type=argtypes.out_log, metavar="FILE", help="write the ECU's frames; format by suffix")
    p.add_argument("--with-inputs", action="store_true", help="also copy the trace's frames to --out")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--fast", action="store_true", help="simulated clock (default)")
    mode.add_argument("--speed", type=argtypes.bounded(0.0, 10_000.0, lo_open=True), metavar="X",
                      help="live: replay onto a bus at X times the recorded pace, (0..10000]")
    p.add_argument("--interface", help="python-can interface for --speed (default: config, else virtual)")
    p.add_argument("--channel", help="python-can channel for --speed")
    p.add_argument("--format", dest="fmt", metavar="FMT",
                   help="reader when the suffix does not tell (asc, blf, log, trc, csv, mf4)")
    p.add_argument("--gateway", metavar="GATEWAY.toml",
                   help="route the trace (its first bus) and the ECU's frames between the buses "
                        "this gateway config names; --out holds every bus (docs/gateway.md)")
    p.add_argument("--estimator", default=None, help="throttle estimator (default production)")
    add_set_option(p, "ecu.* calibration only", params_file=True)
    add_fmu_options(p)
    p.add_argument("--summary", type=argtypes.out_file, metavar="FILE.json", help="write the JSON summary")
    p.add_argument("--plot", type=argtypes.out_plot, metavar="FILE.png", help="plot the ECU's estimates (and truth if present)")
    prog = p.add_mutually_exclusive_group()
    prog.add_argument("--progress", action="store_true", default=None, help="always show progress")
    prog.add_argument("--no-progress", dest="progress", action="store_false", help="never show progress")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    fleet = p.add_argument_group("fleet (several traces, on Dask; docs/replay.md 'Fleet')")
    fleet.add_argument("--out-dir", type=argtypes.out_dir, metavar="DIR",
                       help="fleet results: runs.csv, summary.json, report.html, traces/")
    fleet.add_argument("--out-format", metavar="FMT",
                       help="write each trace's ECU frames as DIR/traces/NAME.FMT (blf, log, ...)")
    where = fleet.add_mutually_exclusive_group()
    where.add_argument("--workers", type=argtypes.bounded(1, 1024, integer=True), metavar="N",
                       help="local Dask worker processes (default: the machine's cores)")
    where.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                       help="submit to a running Dask scheduler instead")
    fleet.add_argument("--resume", action="store_true",
                       help="complete the traces missing in --out-dir")
    fleet.add_argument("--junit", type=argtypes.out_file, metavar="OUT.xml",
                       help="JUnit XML, one test case per trace")
    fleet.add_argument("--diff", nargs="?", const="", default=None, metavar="DIFF.toml",
                       help="compare every ECU frame with the one recorded (tolerances: "
                            "DIFF.toml, default one LSB per signal)")
    fleet.add_argument("--criteria", metavar="FILE.toml",
                       help="scenario criteria judged on each trace ([criteria], [truth])")
    p.set_defaults(func=main)


FLEET_ONLY = ("out_dir", "out_format", "resume", "junit", "diff", "criteria", "workers",
              "scheduler")


def main(args: argparse.Namespace) -> int:
    configure_logging(args.quiet)
    from vecu.fleet.traces import expand

    single = (len(args.traces) == 1 and Path(args.traces[0]).is_file()
              and not any(getattr(args, k) not in (None, False) for k in FLEET_ONLY))
    if not single:
        from vecu.cli.replay_fleet import main_fleet

        return main_fleet(args, expand(args.traces))
    args.trace = args.traces[0]

    from vecu.replay.engine import ReplayConfig, replay
    from vecu.replay.source import TraceReadError

    config = ReplayConfig(
        trace=args.trace, dbc=tuple(args.dbc), signal_map=args.signal_map, out=args.out,
        with_inputs=args.with_inputs, speed=args.speed, interface=args.interface,
        channel=args.channel, fmt=args.fmt, estimator=args.estimator, progress=args.progress,
        sets=tuple(param_sets(args, only="ecu.")),
        keep_series=bool(args.plot), gateway=args.gateway, fmu=fmu_binding(args))
    result = replay(config)
    if result.error and result.report.frames.read == 0:  # not a trace: no summary of nothing
        raise TraceReadError(None, result.error)
    if args.summary:
        Path(args.summary).write_text(json.dumps(result.summary, indent=2) + "\n")
    if args.plot and result.series is not None:
        from vecu.replay.plot import plot_replay
        plot_replay(result.series, args.plot, f"vecu replay {Path(args.trace).name}")
    if not args.quiet:
        print(format_summary(result.report))
    if result.error:
        raise TraceReadError(None, result.error)  # after the summary of what was read
    return 0


def format_summary(s: ReplaySummary) -> str:
    fr = s.frames
    lines = [(f"vecu replay ({s.mode}): {s.trace}: {s.trace_duration_s:.3f} s of trace in "
             f"{s.wall_time_s:.2f} s ({s.x_realtime}x real time, {s.frames_per_s} frames/s)"),
             f"frames: read {fr.read}, decoded {fr.decoded} (truth {fr.truth}), unknown id "
             f"{fr.unknown_id}, error frames {fr.error_frames}, remote {fr.remote_frames}, "
             f"rejected {fr.rejected}"
             + (f" ({', '.join(f'{k} {v}' for k, v in fr.rejected_by_reason.items())})"
                if fr.rejected else "")
             + (f"; out of order {fr.out_of_order} (re-ordered), late {fr.late}"
                if fr.out_of_order or fr.late else "")]
    gaps = s.idle_gaps
    if gaps.count:
        at, length = gaps.first[0]
        lines.append(f"idle gaps: {gaps.count} longer than {gaps.threshold_s:g} s, "
                     f"{gaps.skipped_s:.3f} s skipped (the ECU ran {gaps.threshold_s:g} s "
                     f"of each silence); the first at {at:.3f} s, {length:.3f} s long")
    for name, f in s.functions.items():
        if not f.enabled or not f.ran:
            lines.append(f"{name}: {f.reason}")
        else:
            lines.append(f"{name}: {f.estimates_sent} estimates")
    lines += [f"note: {n}" for n in s.map.notes]
    if s.score is not None:
        lines += score_lines(s.score.functions)
    if s.schedule_error is not None:
        e = s.schedule_error
        lines.append(f"schedule error: p50 {e['p50_us']} us, p99 {e['p99_us']} us, max "
                     f"{e['max_us']} us over {e['count']} frames")
    if s.gateway is not None:
        from vecu.cli.run import gateway_lines
        lines += gateway_lines(s.gateway)
    if s.frames_written:
        lines.append(f"wrote {s.frames_written} frames to {s.config['out']}")
    return "\n".join(lines)


def score_lines(score: dict[str, ScoreSection]) -> list[str]:
    """One line per function scored against the trace's truth frames (its registry entry's
    truth channel words it; a plug-in without one: its errors' RMS)."""
    from vecu import functions

    lines = []
    for spec in functions.specs():
        section = score.get(spec.name)
        if section is None or spec.truth is None:
            continue
        lines.append(f"score {spec.name}: " + (
            spec.truth.describe(section.errors) if spec.truth.describe is not None else
            ", ".join(f"{k} RMS {e.rms:.3f}" for k, e in section.errors.items())))
    return lines
