"""`vecu eval`: offline estimator accuracy against simulated truth, one subcommand per ECU
function that has an evaluation (vecu.cli.eval.<function>, in the registry's order), then
`consistency` over all of them (vecu.cli.eval.consistency)."""

from __future__ import annotations

import argparse
import importlib
import importlib.util

from vecu import functions


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("eval", help="score estimators offline against simulated truth",
                       description="Offline evaluation of state estimators on simulated plants.")
    models = p.add_subparsers(dest="model", required=True, metavar="MODEL")
    # the built-in functions' names (a plug-in has no module here): nothing imported, and no
    # scan of the installed packages' entry points before every command
    for name in functions.FUNCTIONS:
        module = f"{__name__}.{name}"
        if importlib.util.find_spec(module) is not None:
            importlib.import_module(module).register(models)
    from vecu.cli.eval import consistency

    consistency.register(models)
