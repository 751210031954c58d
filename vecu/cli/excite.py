"""`vecu excite throttle`: drive the simulated throttle with the §III-B excitation and record it."""

from __future__ import annotations

import argparse

from vecu import argtypes
from vecu.cli import add_set_option, configure_logging, param_sets

DEFAULT_LOG = "throttle-excite.blf"
DEFAULT_DURATION_S = 30.0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("excite", help="record a persistent-excitation trace for identification",
                       description="Drive a simulated system with a persistent excitation and "
                                   "record the trace a test bench would: the input to "
                                   "`vecu identify`.")
    what = p.add_subparsers(dest="system", required=True)
    t = what.add_parser(
        "throttle", help="the throttle body (Vargas 2015 Section III-B excitation)",
        description="Pseudo-random rectangular pulses of random amplitude 0-10 V through a "
                    "4th-order Butterworth low-pass with a cut-off redrawn in 0.01-60 Hz every "
                    "10 s (plant.input.*), applied to the simulated throttle body (plant.throttle."
                    "*; perturb it with --set to play an unknown throttle), or u(t) from your "
                    "own file (--input). Records u, the wattmeter and the TPS at 1 kHz, no "
                    "faults, with the truth frames for scoring.")
    t.add_argument("--duration", type=argtypes.run_seconds, default=None, metavar="S",
                   help="seconds (default 30: the paper's three blocks of 10 000 points; with "
                        "--input, the file's last time)")
    t.add_argument("--input", metavar="FILE",
                   help="drive the throttle with u(t) from FILE instead of the excitation: CSV "
                        "with a header naming t_s and u_V (s, V in 0..12), times increasing; u "
                        "linearly interpolated at each 1 ms tick, held after the last row "
                        "(docs/reproduction.md)")
    t.add_argument("--seed", type=argtypes.seed, default=0, help="random seed (default 0)")
    t.add_argument("--log", type=argtypes.out_log, default=DEFAULT_LOG, metavar="FILE",
                   help=f"trace file, format by suffix (default {DEFAULT_LOG})")
    t.add_argument("--no-truth", dest="truth", action="store_false",
                   help="leave the simulated truth frames out (a bench has none)")
    add_set_option(t, "plant.* and ecu.*", params_file=True)
    t.add_argument("--quiet", action="store_true", help="print nothing but errors")
    t.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    configure_logging(args.quiet)
    from vecu.functions import OPTIONAL
    from vecu.runner import RunConfig, run

    duration = args.duration
    if args.input is not None:
        from vecu.plant.input_file import load_input_file

        series = load_input_file(args.input)  # a bad file: one line naming it, before any work
        if duration is None:
            duration = max(round(series.end_s, 3), 0.001)
    duration = DEFAULT_DURATION_S if duration is None else duration
    config = RunConfig(duration_s=duration, seed=args.seed, kill_tps_at_s=None,
                       log_path=args.log, truth=args.truth, throttle_input=args.input,
                       **{name: False for name in OPTIONAL},  # type: ignore[arg-type]  # the throttle function alone: every optional one off
                       ).with_params(param_sets(args))
    config.validate()
    result = run(config)
    if not args.quiet:
        changed = result.report.config["params"]
        what = "throttle excitation" if args.input is None else f"throttle input {args.input}"
        print(f"recorded {duration:g} s of {what} to {args.log} "
              f"({result.report.frames.sent} frames)"
              + (f"; plant changed: {', '.join(f'{k}={v}' for k, v in changed.items())}"
                 if changed else "; plant: Table I"))
        print(f"next: vecu identify throttle {args.log} --out params.toml")
    return 0
