"""`vecu` command line: one module per subcommand, each exposing register(subparsers)."""

from __future__ import annotations

import argparse
import importlib
import sys

SUBCOMMANDS = ("run", "eval", "bench", "plant", "ecu", "inject", "replay", "scenario")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="vecu", description="Virtual ECU gateway for CAN")
    sub = parser.add_subparsers(dest="command", required=True)
    for name in SUBCOMMANDS:
        importlib.import_module(f"vecu.cli.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        return 130
    except UserInputError as exc:
        print(f"vecu: error: {exc}", file=sys.stderr)
        return 2


class UserInputError(Exception):
    """A bad file or argument given by the user: reported as one line, exit code 2."""


if __name__ == "__main__":
    sys.exit(main())
