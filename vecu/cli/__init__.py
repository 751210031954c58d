"""`vecu` command line: one module per subcommand, each exposing register(subparsers)."""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from pathlib import Path

SUBCOMMANDS = ("run", "eval", "bench", "plant", "ecu", "inject", "replay", "scenario")
KERNEL_COMMANDS = ("run", "eval", "bench", "plant", "ecu", "replay", "scenario")  # use estimators


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="vecu", description="Virtual ECU gateway for CAN")
    sub = parser.add_subparsers(dest="command", required=True)
    for name in SUBCOMMANDS:
        importlib.import_module(f"vecu.cli.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    from vecu import kernels

    try:
        cold = kernels.cache_is_cold()  # VECU_KERNELS checked before any work starts
    except kernels.KernelBackendError as exc:
        print(f"vecu: error: {exc}", file=sys.stderr)
        return 2
    if cold and args.command in KERNEL_COMMANDS:
        print("vecu: compiling the numba kernels on first use (about 40 s, once per install; "
              "VECU_KERNELS=python skips them)", file=sys.stderr, flush=True)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        return 130
    except UserInputError as exc:
        print(f"vecu: error: {exc}", file=sys.stderr)
        return 2


class UserInputError(Exception):
    """A bad file or argument given by the user: reported as one line, exit code 2."""


def configure_logging(quiet: bool) -> None:
    """Warnings (rx problems, send failures) on stderr; with --quiet errors only."""
    logging.basicConfig(level=logging.ERROR if quiet else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")


def require_output_dirs(*paths: str | None) -> None:
    """Fail before a run, not after it, when an output file's directory does not exist."""
    for path in paths:
        if path and not Path(path).resolve().parent.is_dir():
            raise UserInputError(f"{path}: directory does not exist")


if __name__ == "__main__":
    sys.exit(main())
