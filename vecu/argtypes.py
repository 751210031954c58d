"""argparse types for every numeric option of every command line (vecu/cli, vecu/live/args.py and
the module-level tools): a bad value is refused by argparse before any work starts, in one line
(`vecu: error: argument --X: expected …`). Imports nothing of vecu, so any front end may use it.

Output options (--out, --log, --summary, --plot, --junit, --report, --ready-file …) take an
output type (out_file, out_log, out_plot, out_dir, output(kind, suffix)): their value is an
OutputPath, which the command line checks before any work (vecu.cli.outputs.check_output_args):
the type marks the option, so every output option of every subcommand is checked by one check.

Seeds (decision): integers 0..2**63-1. numpy's SeedSequence takes any non-negative integer; the
upper bound is the largest integer a scenario file can hold (TOML integers are 64-bit signed),
so every seed of the command line can be written in a scenario too.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

SEED_MAX = 2**63 - 1
NOISE_SCALE_MAX = 1000.0  # process-noise scale alpha: 1 is the paper's; beyond this, noise only
RUN_MAX_S = 86_400.0      # a day of simulated time, as a scenario's duration_s
TICK_S = 0.001            # the 1 ms base tick: a run shorter than this has nothing to run


def _fmt(v: float) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def bounded(lo: float | None = None, hi: float | None = None, *, integer: bool = False,
            lo_open: bool = False, unit: str = "") -> Callable[[str], float]:
    """An argparse type: a finite number (an integer with integer=True) in lo..hi (None: no
    bound; lo_open: lo itself excluded). NaN and ±inf are always refused."""
    what = "an integer" if integer else "a number"
    if lo is not None and hi is not None:
        what += f" in {'(' if lo_open else ''}{_fmt(lo)}..{_fmt(hi)}"
    elif lo is not None:
        what += f" {'>' if lo_open else '>='} {_fmt(lo)}"
    elif hi is not None:
        what += f" <= {_fmt(hi)}"
    if unit:
        what += f" {unit}"

    def parse(text: str) -> float:
        try:
            v: float = int(text, 10) if integer else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if not math.isfinite(v) or (lo is not None and (v <= lo if lo_open else v < lo)) \
                or (hi is not None and v > hi):
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        return v

    parse.__name__ = what  # argparse names the type by it in its own messages
    return parse


def name_list(choices: tuple[str, ...], what: str = "group") -> Callable[[str], frozenset[str]]:
    """An argparse type: one name of `choices` or several, comma-separated (pipeline,replay)."""

    def parse(text: str) -> frozenset[str]:
        names = [n.strip() for n in text.split(",") if n.strip()]
        bad = [n for n in names if n not in choices]
        if bad or not names:
            raise argparse.ArgumentTypeError(f"unknown {what} {', '.join(bad) or repr(text)} "
                                             f"(choose from {', '.join(choices)})")
        return frozenset(names)

    parse.__name__ = f"{what}[,{what}...]"
    return parse


seed = bounded(0, SEED_MAX, integer=True)
finite = bounded()
positive = bounded(0.0, lo_open=True)
non_negative = bounded(0.0)
positive_int = bounded(1, integer=True)
noise_scale = bounded(0.0, NOISE_SCALE_MAX)
run_seconds = bounded(TICK_S, RUN_MAX_S, unit="s")
live_seconds = bounded(TICK_S, RUN_MAX_S, unit="s")
tick_us = bounded(0, 1000, integer=True, unit="us")  # a part of the 1 ms tick


class OutputPath(str):
    """A path a command will write (the value of an output option): kind 'file', 'log' (a trace
    python-can writes), 'plot' (a figure matplotlib writes) or 'dir' (a directory vecu creates
    and fills); suffixes: the file suffixes allowed (empty: any)."""

    kind: str
    suffixes: tuple[str, ...]

    def __new__(cls, text: str, kind: str = "file",  # noqa: PYI034 - 3.10: typing has no Self
                suffixes: tuple[str, ...] = ()) -> OutputPath:
        self = str.__new__(cls, text)
        self.kind, self.suffixes = kind, suffixes
        return self

    def __getnewargs__(self) -> tuple[str, str, tuple[str, ...]]:  # type: ignore[override]  # picklable with its kind
        return str(self), self.kind, self.suffixes


OUTPUT_KINDS = ("file", "log", "plot", "dir")


def output(kind: str, *suffixes: str) -> Callable[[str], OutputPath]:
    """An argparse type marking an output option: the value as an OutputPath of this kind."""
    if kind not in OUTPUT_KINDS:
        raise ValueError(f"output kind {kind!r}: expected one of {', '.join(OUTPUT_KINDS)}")

    def parse(text: str) -> OutputPath:
        return OutputPath(text, kind, suffixes)

    parse.__name__ = "directory" if kind == "dir" else "file name"
    parse.output_kind = kind  # type: ignore[attr-defined]  # how a parser walk finds output options
    parse.output_suffixes = suffixes  # type: ignore[attr-defined]
    return parse


out_file = output("file")
out_log = output("log")
out_plot = output("plot")
out_dir = output("dir")


def kill_time(text: str) -> float | str | None:
    """--kill-tps-at / --kill-swa-at: finite seconds, 'none' (never) or 'half' (of the run)."""
    if text.lower() in ("none", "never", "off"):
        return None
    if text == "half":
        return text
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected seconds or 'none', got {text!r}")
    return v


def bus_override(text: str) -> tuple[str, str, str]:
    """`--bus NAME=INTERFACE:CHANNEL` -> (name, interface, channel); the channel may hold ':'."""
    name, eq, rest = text.partition("=")
    interface, colon, channel = rest.partition(":")
    if not (eq and colon and name.strip() and interface.strip() and channel.strip()):
        raise argparse.ArgumentTypeError(f"expected NAME=INTERFACE:CHANNEL (e.g. "
                                         f"vehicle=socketcan:vcan1), got {text!r}")
    return name.strip(), interface.strip(), channel.strip()
