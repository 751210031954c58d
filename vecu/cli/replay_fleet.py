"""`vecu replay` of several traces (a fleet) on Dask: vecu.fleet (docs/replay.md 'Fleet')."""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from vecu.cli import check_outputs, fmu_binding, param_sets
from vecu.errors import BadArgumentError

SINGLE_ONLY = {"out": "--out (a fleet writes DIR/traces/NAME.FMT: --out-format FMT)",
               "summary": "--summary (a fleet writes DIR/traces/NAME.summary.json)",
               "plot": "--plot", "speed": "--speed (a fleet replays on the simulated clock)",
               "interface": "--interface", "channel": "--channel"}


def main_fleet(args: argparse.Namespace, traces: list[str]) -> int:
    from vecu.campaign.cluster import default_progress_stream
    from vecu.fleet.criteria import load_trace_criteria
    from vecu.fleet.diff import load_diff_spec
    from vecu.fleet.engine import FleetInterrupted, run_fleet
    from vecu.fleet.task import FleetConfig
    from vecu.live.children import EXIT_TERMINATED, sigterm_unwinds
    from vecu.replay.engine import ReplayConfig
    from vecu.replay.source import reader_formats

    for key, what in SINGLE_ONLY.items():
        if getattr(args, key, None) is not None:
            raise BadArgumentError(f"{what}: one trace only, not with several traces")
    if not args.out_dir:
        raise BadArgumentError("several traces (or --diff / --criteria / --junit) need "
                               "--out-dir DIR for their results")
    fmt = args.out_format.lstrip(".").lower() if args.out_format else None
    if fmt is not None and fmt.removesuffix(".gz") not in reader_formats():
        raise BadArgumentError(f"--out-format {args.out_format}: expected one of "
                               f"{', '.join(reader_formats())} (also .gz)")
    check_outputs(junit=args.junit)
    base = ReplayConfig(trace="", dbc=tuple(args.dbc), signal_map=args.signal_map,
                        with_inputs=args.with_inputs, fmt=args.fmt, estimator=args.estimator,
                        sets=tuple(param_sets(args, only="ecu.")), progress=False,
                        gateway=args.gateway, fmu=fmu_binding(args))
    base.validate()
    fleet = FleetConfig(
        base, fmt, None if args.diff is None else load_diff_spec(args.diff or None),
        None if args.criteria is None else load_trace_criteria(args.criteria))
    out = Path(args.out_dir)
    stream = ((sys.stderr if args.progress else None) if args.progress is not None
              else default_progress_stream())
    try:
        with sigterm_unwinds():
            res = run_fleet(traces, fleet, out, workers=args.workers, scheduler=args.scheduler,
                            resume=args.resume, progress=stream, junit=args.junit)
    except FleetInterrupted as exc:
        print(f"vecu: {exc}; `{_resume_command()}` finishes it", file=sys.stderr)
        return 130 if exc.signal_name == "SIGINT" else EXIT_TERMINATED
    if not args.quiet:
        for r in res.summary["rows"]:
            why = r["error"] or r["criteria_failed"] or r["diff_failed_signals"]
            print(f"{r['name']:<32} {r['verdict']:<8} {r['trace_duration_s'] or '-':>10} s"
                  + (f"  {why}" if why else ""))
        print(f"vecu replay: {res.done}/{res.traces} traces in {out} ({res.new} new): "
              f"{res.passed} ok, {res.failed} failed, {res.errors} errors; report "
              f"{out / 'report.html'}")
    return 0 if res.passed == res.done else 1


def _resume_command() -> str:
    """The command line again, with --resume."""
    argv = list(sys.argv[1:])
    if "--resume" not in argv:
        argv.append("--resume")
    return shlex.join(["vecu", *argv])
