"""`vecu identify throttle TRACE`: fit the throttle model to a trace (Vargas 2015 §III-B)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from vecu.argtypes import out_plot, output, positive_int
from vecu.cli import add_set_option, param_sets


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("identify", help="fit a model's parameters to a recorded trace",
                       description="System identification from a trace: the ECU calibration "
                                   "a real device needs instead of the paper's values.")
    what = p.add_subparsers(dest="system", required=True)
    t = what.add_parser(
        "throttle", help="the throttle body: eq. 3 modes, switching angles, noise F and H",
        description="Estimate eq. 3 / Table I (all three modes and their switching angles, as far "
                    "as the trace makes them identifiable) and the noise F, H from a trace with "
                    "the motor voltage, the wattmeter and the TPS (docs/reproduction.md). Prints "
                    "each parameter with a 95 %% interval and the residuals per state and mode; "
                    "--out writes PARAMS.toml for `vecu run/replay --params`.")
    t.add_argument("trace", help="trace file (any python-can format)")
    t.add_argument("--dbc", action="append", default=[], metavar="FILE",
                   help="the trace's DBC (repeatable; default vecu's)")
    t.add_argument("--map", dest="signal_map", metavar="MAP.toml",
                   help="signal map: [throttle] motor_voltage, motor_power, tps_voltage")
    t.add_argument("--format", dest="fmt", metavar="FMT", help="reader when the suffix does not tell")
    t.add_argument("--out", type=output("file", ".toml"), metavar="PARAMS.toml", help="write the identified ECU calibration")
    t.add_argument("--plot", type=out_plot, metavar="F.png", help="Fig. 2: residual histograms, fitted Gaussians")
    t.add_argument("--json", action="store_true", help="print the result as JSON")
    t.add_argument("--free", default="", metavar="NAMES",
                   help="also fit these of the terms kept by default (c1,c2,c3; e.g. --free c1,c3)")
    t.add_argument("--max-samples", type=positive_int, default=None, metavar="N",
                   help="use the first N samples only")
    add_set_option(t, "ecu.*: the start calibration and the TPS law", params_file=True)
    t.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from vecu.config import ParamTree
    from vecu.ident.report import fit_json, format_fit, params_toml, plot_residuals
    from vecu.ident.throttle import DEFAULT_FIXED, identify_throttle
    from vecu.ident.trace import read_throttle_trace

    tree = ParamTree().set(param_sets(args, only="ecu."))
    free = {n.strip() for n in args.free.split(",") if n.strip()}
    unknown = free - set(DEFAULT_FIXED)
    if unknown:
        from vecu.errors import BadArgumentError

        raise BadArgumentError(f"--free {args.free}: expected names from {', '.join(DEFAULT_FIXED)}")
    data = read_throttle_trace(args.trace, tuple(args.dbc), args.signal_map,
                               tree.ecu.throttle.calibration, args.fmt, args.max_samples)
    fit = identify_throttle(data, tree.ecu.throttle.model,
                            fixed=tuple(n for n in DEFAULT_FIXED if n not in free))
    if args.out:
        Path(args.out).write_text(params_toml(fit, args.trace))
    if args.plot:
        plot_residuals(fit, args.plot, f"Vargas 2015 Fig. 2 from {Path(args.trace).name}")
    if args.json:
        print(json.dumps(fit_json(fit), indent=2))
    else:
        print(format_fit(fit))
        if args.out:
            print(f"\ncalibration written to {args.out}: vecu replay {args.trace} --params {args.out}")
    return 0
