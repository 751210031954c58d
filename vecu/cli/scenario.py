"""`vecu scenario run FILE|NAME...`, `vecu scenario list|show`: declarative fault-injection scenarios with pass/fail for CI."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from vecu import argtypes
from vecu.cli import configure_logging
from vecu.cli.shipped import register_list_show
from vecu.errors import BadArgumentError, BadFileError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("scenario", help="run fault-injection scenarios (TOML) and judge them",
                       description="Declarative fault-injection scenarios (docs/scenarios.md).")
    ssub = p.add_subparsers(dest="scenario_command", required=True)
    r = ssub.add_parser("run", help="run scenarios (files or shipped names) on the simulated clock",
                        description="Run each scenario, evaluate its criteria, write reports; "
                                    "exit 1 when any criterion fails.")
    r.add_argument("files", nargs="+", metavar="FILE|NAME",
                   help="scenario .toml files or names of shipped ones (`vecu scenario list`); "
                        "an existing file wins over a name")
    r.add_argument("--junit", type=argtypes.out_file, metavar="OUT.xml", help="write JUnit XML")
    r.add_argument("--report", type=argtypes.out_dir, metavar="DIR", help="write DIR/index.html with PNG plots")
    r.add_argument("--jobs", type=argtypes.bounded(1, 256, integer=True), default=1, metavar="N",
                   help="run N scenarios in parallel processes (default 1)")
    r.add_argument("--quiet", action="store_true",
                   help="print nothing but errors and the verdict (and, on a terminal, the "
                        "progress of a long scenario every 2 s)")
    r.set_defaults(func=main)
    register_list_show(ssub, "scenario")


def main(args: argparse.Namespace) -> int:
    from vecu.scenario.batch import run_scenarios
    from vecu.scenario.loader import load_scenario
    from vecu.scenario.report import write_html, write_junit
    from vecu.shipped import resolve

    configure_logging(quiet=True)  # errors only: the scenario lines are the output
    scenarios = [load_scenario(resolve("scenario", f)) for f in args.files]
    names = [s.name for s in scenarios]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise BadArgumentError(f"scenario names must be unique, repeated: {', '.join(dup)}")
    if args.report:
        try:
            Path(args.report).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise BadFileError(args.report, f"cannot create directory: {exc.strerror}") from exc
    # --quiet: no result lines, and progress only for a person at a terminal (not in CI logs)
    progress = sys.stderr if not args.quiet or sys.stderr.isatty() else None
    outcomes = run_scenarios(scenarios, jobs=args.jobs, report_dir=args.report,
                             stream=None if args.quiet else sys.stderr, progress=progress)
    if args.junit:
        write_junit(outcomes, args.junit)
    if args.report:
        index = write_html(outcomes, args.report)
        if not args.quiet:
            print(f"report: {index}")
    failed = [o.name for o in outcomes if not o.passed]
    print(f"vecu scenario: {len(outcomes) - len(failed)}/{len(outcomes)} passed"
          + (f"; failed: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0
