"""`vecu` command line: one module per subcommand, each exposing register(subparsers).

Exit codes: 0 done, 1 a bug (traceback) or a failed check the subcommand reports, 2 a user error
(one line `vecu: error: …`; with --debug its traceback first), 130 interrupted, 143 a SIGTERM
while the command had child processes (stopped first, vecu.live.children).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
import traceback
from typing import Any, NoReturn

import vecu
from vecu.cli.outputs import check_output_args, output_state, report_interrupted
from vecu.cli.outputs import check_outputs as check_outputs
from vecu.errors import BadArgumentError, Interrupted, UserError

SUBCOMMANDS = ("run", "eval", "bench", "plant", "ecu", "inject", "replay", "scenario", "params",
               "campaign", "excite", "identify", "figures", "restbus", "a2l", "gateway",
               "plugins")
KERNEL_COMMANDS = ("run", "eval", "bench", "plant", "ecu", "replay", "scenario",
                   "campaign", "excite", "identify", "figures")  # use estimators


DEBUG_HELP = "on a user error, print its traceback too"


class VecuArgumentParser(argparse.ArgumentParser):
    """argparse under vecu's error contract: a bad command line is one line `vecu: error: …`
    and exit code 2 (the usage is left to --help). Subcommand parsers inherit the class."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"vecu: error: {message} (see `{self.prog} --help`)\n")


class VersionAction(argparse.Action):
    """--version: the installed version, looked up only when asked (importlib.metadata costs
    ~45 ms, which every other command would pay if the text were built with the parser)."""

    def __init__(self, option_strings: list[str], dest: str = argparse.SUPPRESS) -> None:
        super().__init__(option_strings, dest=dest, default=argparse.SUPPRESS, nargs=0,
                         help="print vecu's version and exit")

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: object, option_string: str | None = None) -> None:
        print(f"vecu {vecu.__version__}")
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    parser = VecuArgumentParser(prog="vecu", description="Virtual ECU gateway for CAN")
    parser.add_argument("--debug", action="store_true", help=DEBUG_HELP)
    parser.add_argument("--version", action=VersionAction)
    sub = parser.add_subparsers(dest="command", required=True)
    for name in SUBCOMMANDS:
        importlib.import_module(f"vecu.cli.{name}").register(sub)
    add_debug_flag(parser)
    return parser


def add_debug_flag(parser: argparse.ArgumentParser) -> None:
    """Accept --debug after every (nested) subcommand too; SUPPRESS keeps `vecu --debug run`
    from being reset by the subparser's default."""
    seen: set[int] = set()
    stack = [parser]
    while stack:
        p = stack.pop()
        for action in p._actions:
            if not isinstance(action, argparse._SubParsersAction):
                continue
            for child in action.choices.values():
                if id(child) in seen:  # aliases share a parser
                    continue
                seen.add(id(child))
                if "--debug" not in child._option_string_actions:
                    child.add_argument("--debug", action="store_true",
                                       default=argparse.SUPPRESS, help=DEBUG_HELP)
                stack.append(child)


def main(argv: list[str] | None = None) -> int:
    """The `vecu` command: parse argv (argparse errors exit 2 on their own) and run it."""
    return run_command(build_parser().parse_args(argv))


def run_command(args: argparse.Namespace) -> int:
    """Run args.func(args) and map the outcome to an exit code (see the module docstring)."""
    from vecu.live.children import EXIT_TERMINATED, Terminated

    before: dict[str, object] = {}
    try:
        check_output_args(args)  # every output option of every subcommand, before any work
        before = output_state(args)  # what an interrupted command kept: what changed since
        from vecu import kernels

        cold = kernels.cache_is_cold()  # VECU_KERNELS checked before any work starts
        uses_kernels = getattr(args, "uses_kernels", True)  # False: e.g. `scenario list`
        if cold and uses_kernels and getattr(args, "command", None) in KERNEL_COMMANDS:
            print("vecu: compiling the numba kernels on first use (about 40 s, once per install; "
                  "VECU_KERNELS=python skips them)", file=sys.stderr, flush=True)
        return int(args.func(args) or 0)
    except Interrupted as exc:  # Ctrl-C part-way, with a partial result
        return report_interrupted(args, before, exc.done, exc.summary)
    except KeyboardInterrupt:  # Ctrl-C anywhere else
        return report_interrupted(args, before)
    except Terminated:  # a SIGTERM while children ran: they are stopped (vecu.live.children)
        return EXIT_TERMINATED
    except UserError as exc:
        if getattr(args, "debug", False):
            traceback.print_exc()
        print(f"vecu: error: {exc}", file=sys.stderr)
        return 2
    except Exception:  # noqa: BLE001 - a bug: its traceback, exit 1 (as Python itself would)
        traceback.print_exc()
        return 1


UserInputError = UserError  # the former name of vecu.errors.UserError (kept for importers)


def configure_logging(quiet: bool) -> None:
    """Warnings (rx problems, send failures) on stderr; with --quiet errors only."""
    logging.basicConfig(level=logging.ERROR if quiet else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")


def add_set_option(p: argparse.ArgumentParser, scope: str, params_file: bool = False) -> None:
    """--set PATH=VALUE (repeatable): override a leaf of the parameter tree (`vecu params`);
    params_file: also --params FILE.toml (a [set] table, read first; --set wins)."""
    if params_file:
        p.add_argument("--params", dest="params_file", metavar="PARAMS.toml",
                       help="parameter file: a [set] table of tree paths, e.g. the calibration "
                            "`vecu identify throttle --out` writes (--set overrides it)")
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="PATH=VALUE",
                   help=f"override a parameter ({scope}; `vecu params` lists them), repeatable")


def add_fmu_options(p: argparse.ArgumentParser) -> None:
    """--fmu MODEL.fmu --fmu-map MAP.toml: an FMU as an ECU function (docs/fmu.md)."""
    p.add_argument("--fmu", metavar="MODEL.fmu",
                   help="an FMI 2.0 / 3.0 co-simulation FMU as an ECU function (needs --fmu-map; "
                        "docs/fmu.md)")
    p.add_argument("--fmu-map", metavar="MAP.toml",
                   help="binds the FMU's inputs and outputs to DBC signals, its step and "
                        "parameters (docs/fmu.md)")


def fmu_binding(args: argparse.Namespace) -> Any:
    """The FMU binding of --fmu / --fmu-map (None without), checked before any work (one line
    per problem)."""
    fmu, fmu_map = getattr(args, "fmu", None), getattr(args, "fmu_map", None)
    if fmu is None and fmu_map is None:
        return None
    if fmu is None or fmu_map is None:
        raise BadArgumentError("--fmu and --fmu-map go together (the map binds the FMU to the "
                               "bus; docs/fmu.md)")
    from vecu.fmu.binding import load_binding

    return load_binding(fmu, fmu_map)


def with_fmu(config: Any, args: argparse.Namespace) -> Any:
    """config (a RunConfig) with the FMU of --fmu / --fmu-map; unchanged without."""
    binding = fmu_binding(args)
    return config if binding is None else config.with_fmu(binding)


def param_sets(args: argparse.Namespace, only: str | None = None) -> list[tuple[str, str]]:
    """The --set pairs of args; `only` restricts them to one half of the tree."""
    from vecu.params import ParamError, parse_set_args

    pairs = parse_set_args(getattr(args, "sets", []) or [])
    if getattr(args, "params_file", None):
        from vecu.simulation import read_params_file

        pairs = read_params_file(args.params_file, only) + pairs
    if only is not None:
        for path, _ in pairs:
            if not path.startswith(only):
                raise ParamError(f"--set {path}: `vecu {args.command}` takes {only}* parameters "
                                 f"only")
    return pairs


if __name__ == "__main__":
    sys.exit(main())
