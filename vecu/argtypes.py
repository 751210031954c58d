"""argparse types for every numeric option of every command line (vecu/cli, vecu/live/args.py and
the module-level tools): a bad value is refused by argparse before any work starts, in one line
(`vecu: error: argument --X: expected …`). Imports nothing of vecu, so any front end may use it.

Seeds (decision): integers 0..2**63-1. numpy's SeedSequence takes any non-negative integer; the
upper bound is the largest integer a scenario file can hold (TOML integers are 64-bit signed),
so every seed of the command line can be written in a scenario too.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from typing import Any

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


def checked(parse: Callable[[str], Any], what: str) -> Callable[[str], Any]:
    """An argparse type from a parser that raises ValueError (e.g. a BadArgumentError) whose
    message says it all: that message becomes argparse's one line (`vecu conformance`'s fault
    settings)."""

    def run(text: str) -> Any:
        try:
            return parse(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    run.__name__ = what
    return run
