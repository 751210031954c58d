"""`vecu params`: every leaf of the parameter tree with its value, unit and source."""

from __future__ import annotations

import argparse
import json
import sys

from vecu.cli import add_fmu_options, add_set_option, fmu_binding, param_sets


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("params", help="list the parameter tree (plant.* truth, ecu.* calibration)",
                       description="List every parameter: dotted path, value, unit and source. "
                                   "`plant.*` is the simulated car, `ecu.*` what the ECU believes; "
                                   "they default to equal values. Any path can be overridden with "
                                   "--set PATH=VALUE on run / plant / ecu / replay, or in a "
                                   "scenario's [set] table.")
    p.add_argument("prefix", nargs="?", default="", help="only paths starting with this")
    add_set_option(p, "show the tree with these overrides applied")
    p.add_argument("--changed", action="store_true",
                   help="only the parameters that differ from the defaults")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    add_fmu_options(p)
    p.set_defaults(func=main)


def _show(value: object) -> object:
    if isinstance(value, float):
        return float(f"{value:.10g}")
    if isinstance(value, tuple):
        return [_show(v) for v in value]
    return value


def main(args: argparse.Namespace) -> int:
    from vecu import params
    from vecu.config import RunConfig

    config = RunConfig()
    binding = fmu_binding(args)  # its parameters under ecu.fmu.<instance>.*
    if binding is not None:
        config = config.with_fmu(binding)
    default = config.default_params()
    tree = config.params.set(param_sets(args))
    rows = list(params.differences(tree, default) if args.changed else params.leaves(tree))
    rows = [r for r in rows if r.path.startswith(args.prefix)]
    if args.prefix and not rows and not args.changed:
        raise params.ParamError(f"no parameter starts with '{args.prefix}' (try `vecu params`)")
    if args.json:
        print(json.dumps([{"path": r.path, "value": _show(r.value), "unit": r.unit,
                           "source": r.source} for r in rows], indent=1))
        return 0
    width = max((len(r.path) for r in rows), default=10)
    lines = [f"{r.path:<{width}}  {json.dumps(_show(r.value)):>14}  {r.unit:<10}  {r.source}"
             for r in rows]
    try:
        sys.stdout.write("\n".join(lines) + "\n")
        sys.stdout.flush()
    except BrokenPipeError:  # `vecu params | head`
        sys.stderr.close()
    return 0
