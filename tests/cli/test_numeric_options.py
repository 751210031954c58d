"""Numeric options of every subcommand: checked by argparse with the shared types of
vecu/argtypes.py, so a bad value is one line `vecu: error: …` and exit 2 before any work (issue 14
item 8: seeds, durations shorter than a tick, non-finite or huge scales and values, negative
microseconds, bench sizes)."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys

import pytest

from vecu.cli import build_parser, main


def _actions(parser: argparse.ArgumentParser, prefix: str = "vecu"):
    """(command, action) for every option and positional of every (nested) subcommand."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            seen: set[int] = set()
            for name, child in action.choices.items():
                if id(child) not in seen:
                    seen.add(id(child))
                    yield from _actions(child, f"{prefix} {name}")
        else:
            yield prefix, action


def test_every_typed_option_uses_a_shared_checked_type() -> None:
    """No bare int/float (they take nan, inf, -1): each typed option uses vecu.argtypes."""
    bad = [f"{cmd} {'/'.join(a.option_strings) or a.dest}: {getattr(a.type, '__name__', a.type)}"
           for cmd, a in _actions(build_parser())
           if a.type is not None and getattr(a.type, "__module__", "") != "vecu.argtypes"]
    assert not bad, bad


BAD = [
    # seeds: numpy's SeedSequence refuses negatives with a traceback (eval speed/manifold, plant, ecu)
    ["run", "--seed", "-1"], ["eval", "speed", "--runs", "1", "--seed", "-1"],
    ["eval", "manifold", "--duration", "1", "--seed", "-1"], ["eval", "throttle", "--seed", "-2"],
    ["eval", "steering", "--duration", "1", "--seed", "-1"],
    ["plant", "--duration", "0.2", "--seed", "-1"], ["ecu", "--duration", "0.2", "--seed", "-1"],
    ["run", "--seed", str(2**64)],
    # a run shorter than one 1 ms tick; non-finite and overflowing numbers
    ["run", "--duration", "0.0004"], ["run", "--duration", "nan"],
    ["run", "--duration", "0.2", "--noise-scale", "1e300"],
    ["run", "--duration", "0.2", "--noise-scale", "nan"],
    ["run", "--duration", "0.2", "--noise-scale", "inf"],
    ["run", "--duration", "0.2", "--fault", "offset", "--fault-value", "inf"],
    ["run", "--duration", "0.2", "--kill-swa-at", "0.1", "--swa-fault", "offset",
     "--swa-fault-value", "nan"],
    ["run", "--duration", "0.2", "--kill-tps-at", "nan"],
    ["eval", "throttle", "--steps", "1500", "--noise-scale", "inf"],
    ["eval", "steering", "--duration", "1", "--lag", "nan"],
    # live processes: microseconds that cannot be negative
    ["plant", "--duration", "0.2", "--spin-us", "-1"],
    ["ecu", "--duration", "0.2", "--sync-timeout", "0", "--sync-margin-us", "-1"],
    ["ecu", "--duration", "0.2", "--sync-timeout", "nan"],
    ["plant", "--duration", "nan"], ["plant", "--duration", "0.2", "--noise-scale", "-1"],
    ["inject", "--target", "tps", "--kind", "offset", "--value", "nan"],
    ["replay", "x.log", "--speed", "nan"],
    ["scenario", "run", "x.toml", "--jobs", "0"],
    # bench sizes
    ["bench", "--quick", "--only", "replay", "--replay-seconds", "0"],
    ["bench", "--quick", "--only", "replay", "--replay-seconds", "-1"],
    ["bench", "--quick", "--only", "replay", "--replay-seconds", "nan"],
    ["bench", "--quick", "--only", "live", "--live-seconds", "nan"],
    ["bench", "--quick", "--only", "live", "--live-seconds", "-1"],
    ["bench", "--quick", "--only", "live", "--memory-minutes", "-1"],
]


def _option(argv: list[str]) -> str:
    """The option whose value is bad: the last one given (every case above ends with it)."""
    return [a for a in argv if a.startswith("--")][-1]


@pytest.mark.parametrize("argv", BAD, ids=[" ".join(a) for a in BAD])
def test_bad_number_is_one_line_exit_2_before_any_work(argv: list[str], capsys) -> None:
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse's own exit
        rc = exc.code
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1, err
    assert lines[0].startswith(f"vecu: error: argument {_option(argv)}: expected"), lines[0]
    assert out == ""  # nothing ran


@pytest.mark.parametrize("argv", [
    ["eval", "manifold", "--seed", "-1"], ["bench", "--live-seconds", "nan"],
    ["run", "--duration", "0.0004"],
])
def test_in_a_real_process_too(argv: list[str]) -> None:
    res = subprocess.run([sys.executable, "-m", "vecu", *argv], capture_output=True, text=True,
                         env={**os.environ, "VECU_KERNELS": "python"}, timeout=120, check=False)
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(lines) == 1, res.stderr
    assert lines[0].startswith("vecu: error: argument") and res.stdout == ""


def test_any_argparse_error_is_one_line(capsys) -> None:
    """Unknown options and missing arguments follow the same contract (the usage: --help)."""
    for argv in (["run", "--bogus"], ["inject"], ["eval"]):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        lines = capsys.readouterr().err.strip().splitlines()
        assert exc.value.code == 2 and len(lines) == 1, lines
        assert lines[0].startswith("vecu: error: ") and "--help" in lines[0], lines
