"""CLI smoke test: every subcommand's quick path run as a user runs it (`python -m vecu …`), and
the error contract: a user's mistake is one line `vecu: error: …` with exit code 2 (with --debug
its traceback too), a bug is a traceback with exit code 1.

Adding a case is one line in SMOKE: (argv, regular expression the output must contain).
`vecu bench` has its own smoke test (tests/bench/test_smoke.py).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import tomllib

from vecu.cli import add_debug_flag, build_parser, run_command
from vecu.errors import BadFileError

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "VECU_KERNELS": "python"}  # no numba compile in the subprocesses


def _shortest_scenario() -> Path:
    files = sorted((ROOT / "vecu" / "data" / "scenarios").glob("*.toml"))
    return min(files, key=lambda f: tomllib.loads(f.read_text())["duration_s"])


def vecu(*argv: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    """`python -m vecu ARGV` in a fresh process, output captured."""
    return subprocess.run([sys.executable, "-m", "vecu", *argv], capture_output=True, text=True,
                          env=ENV, cwd=cwd, timeout=300, check=False)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("smoke")


@pytest.fixture(scope="module")
def recorded(workdir: Path) -> tuple[Path, subprocess.CompletedProcess[str]]:
    """One short `vecu run --log` (a candump trace), shared by the log and replay cases."""
    log = workdir / "drive.log"
    return log, vecu("run", "--duration", "0.5", "--seed", "3", "--log", str(log), cwd=workdir)


# (argv, what stdout must contain); {log}: the recorded trace, {scenario}: the name of the shortest
# shipped scenario (found by name from the work directory, outside the checkout)
SMOKE: list[tuple[list[str], str]] = [
    (["--help"], r"\{run,eval,.*\}"),
    (["run", "--duration", "0.5"], r"500 ticks.*\n.*TPS fault 'dead' at 0\.250 s: detected as \w+"),
    (["eval", "throttle", "--steps", "1500"], r"\nproduction +-?\d+\.\d\d +\d+\.\d\d"),
    (["eval", "speed", "--runs", "1"], r"\npaper +\+\d+\.\ddB"),
    (["eval", "steering", "--duration", "1"], r"\nUKF \(live\) +\d+\.\d{3}"),
    (["eval", "manifold", "--duration", "1", "--no-dare"],
     r"\nsdkf +\d+ +\d\.\d{3}.*\nadaptive +\d+ +\d\.\d{3}"),
    (["eval", "consistency", "--runs", "1", "--quick"],
     r"\nthrottle +theta +1 +\d+\.\d\d.*\nspeed +v,a +2 .*\nmanifold +p_im,t_im +2 +\d+\.\d\d"),
    (["run", "--duration", "0.5", "--manifold-filter", "adaptive"],
     r"manifold \(adaptive, \d+ engine events, 0 lost\)"),
    (["replay", "{log}", "--no-progress"], r"score throttle: broadcast RMS \d+\.\d\d deg"),
    (["scenario", "run", "{scenario}"], r"vecu scenario: 1/1 passed"),
    (["inject", "--target", "tps", "--kind", "dead", "--interface", "virtual", "--channel",
      "smoke"], r"sent FI_Command tps dead on virtual smoke"),
    (["inject", "--help"], r"usage: vecu inject.*--target"),
    (["plant", "--help"], r"usage: vecu plant"),
    (["ecu", "--help"], r"usage: vecu ecu"),
    (["gateway", "--print-config"], r"logical_address = 0x1000.*\[\[ecu\]\]"),
    (["params", "ecu.manifold.kf.params.omega0"], r"ecu\.manifold\.kf\.params\.omega0 +50\.0 +rad/s"),
    (["run", "--duration", "0.3", "--set", "plant.manifold.engine.zeta=0.7"], r"300 ticks"),
    (["run", "--duration", "0.2"], r"fixed-lag smoother: no output yet.*\noutputs: add --plot"),
    (["campaign", "run", "--help"], r"usage: vecu campaign run .*--scheduler"),
    (["restbus", str(ROOT / "dbc" / "vecu.dbc"), "--node", "PLANT", "--duration", "1"],
     r"vecu restbus: \d+ messages, \d+ frames in 1 s \(simulated clock"),
    (["plugins"], r"no plug-ins installed|\S+ +\S+ +\S+ +\S+:\S+ +(ok|NOT LOADED)"),
    (["conformance", "run", "--help"], r"usage: vecu conformance run .*--tester"),
    (["conformance", "list"], r"pending=N .*\n +client must: wait on.*fc_overflow .*canfd_frame"),
    (["ecu", "--duration", "0.3", "--sync-timeout", "0", "--no-status", "--summary",
      "faulty.json", "--diag-fault", "pending=3@0.1", "--diag-fault", "fc_wait@request=2"],
     r"vecu ecu: 0\.\d s"),
    (["dbc", "export", "dbcs", "--force"], r"dbcs/vecu\.dbc\ndbcs/vecu_truth\.dbc\ndbcs/vecu_all\.dbc"),
    (["a2l", "--out", "smoke.a2l"], (r"smoke\.a2l: \d+ characteristics \(\d+ calibratable "
                                     r"live\), \d+ measurements; XCP on CAN 0x7F0 -> 0x7F1")),
]


@pytest.mark.parametrize("argv,expected", SMOKE, ids=[" ".join(a[:2]) for a, _ in SMOKE])
def test_subcommand_quick_path(argv: list[str], expected: str, recorded, workdir: Path) -> None:
    log, _ = recorded
    args = [a.format(log=log, scenario=_shortest_scenario().stem) for a in argv]
    res = vecu(*args, cwd=workdir)
    assert res.returncode == 0, res.stderr
    assert re.search(expected, res.stdout, re.DOTALL), res.stdout


def test_run_log_is_a_candump_trace_of_every_frame(recorded) -> None:
    log, res = recorded
    assert res.returncode == 0, res.stderr
    lines = log.read_text().splitlines()
    sent = int(re.search(r"frames: sent (\d+)", res.stdout).group(1))
    assert len(lines) == sent > 0  # plant, ECU and debug truth frames, one line each
    assert all(re.fullmatch(r"\(\d+\.\d{6}\) vecu [0-9A-F]{3}#[0-9A-F]* [RT]", ln)
               for ln in lines[:50]), lines[:3]


# ------------------------------------------------------------------ error contract
USER_MISTAKES = [
    (["run", "--duration", "1", "--kill-tps-at", "5"], "kill time 5.0 s is outside the run"),
    (["replay", "missing.log"], "missing.log: no such file"),
    (["replay", "missing.log", "nothing*.blf", "--out-dir", "f"], "missing.log: no such file"),
    (["replay", "{bad_scenario}", "{bad_scenario}"], "need --out-dir DIR"),
    (["replay", "{bad_scenario}", "--out-dir", "f", "--diff", "{bad_scenario}"],
     "bad.toml: unknown key 'duration_s'"),
    (["scenario", "run", "{bad_scenario}"], "bad.toml: key 'plant.wheels': unknown key"),
    (["eval", "steering", "--duration", "0.1"], "--duration: expected 1..3600 s"),
    (["eval", "consistency", "--estimators", "brakes"], "--estimators: expected names from"),
    (["inject", "--target", "brakes", "--kind", "dead"], "unknown target 'brakes'"),
    (["ecu", "--log", "x.bogus"], "x.bogus: cannot write log"),  # and no bus-not-shut-down warning
    (["gateway", "--config", "nope.toml"], "nope.toml"),
    (["gateway", "--doip-port", "70000"], "--doip-port"),
    (["run", "--fmu", "nope.fmu"], "--fmu and --fmu-map go together"),
    (["ecu", "--diag-fault", "bogus"], "unknown diagnostic fault 'bogus' (known: pending,"),
    (["ecu", "--diag-fault", "pending=101"], "N must be an integer 1..100, got 101"),
    (["gateway", "--diag-fault", "pending"], "pending is an ECU fault"),
    (["conformance", "run", "--tester", "true", "--faults", "fc_wait=0"],
     "fc_wait: WAITs must be an integer 1..10, got 0"),
]


@pytest.fixture(scope="module")
def bad_scenario(workdir: Path) -> Path:
    path = workdir / "bad.toml"
    path.write_text("duration_s = 1.0\n[plant]\nwheels = 4\n")
    return path


@pytest.mark.parametrize("argv,needle", USER_MISTAKES, ids=[a[0] for a, _ in USER_MISTAKES])
def test_user_mistake_is_one_line_exit_2(argv: list[str], needle: str, bad_scenario,
                                         workdir: Path) -> None:
    res = vecu(*[a.format(bad_scenario=bad_scenario) for a in argv], cwd=workdir)
    err = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(err) == 1, res.stderr
    assert err[0].startswith("vecu: error:") and needle in err[0], err[0]


@pytest.mark.parametrize("argv", [
    ["--debug", "run", "--duration", "1", "--kill-tps-at", "5"],
    ["run", "--duration", "1", "--kill-tps-at", "5", "--debug"],
    ["eval", "--debug", "steering", "--duration", "0.1"],
])
def test_debug_shows_the_traceback_of_a_user_error(argv: list[str], workdir: Path) -> None:
    res = vecu(*argv, cwd=workdir)
    err = res.stderr.strip().splitlines()
    assert res.returncode == 2, res.stderr
    assert err[0] == "Traceback (most recent call last):" and len(err) > 3, res.stderr
    assert err[-1].startswith("vecu: error:") and "vecu.errors." in err[-2], res.stderr


def _with_test_subcommand(func) -> argparse.ArgumentParser:
    """vecu's own parser plus a test-only subcommand `boom` that calls func."""
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    sub.add_parser("boom").set_defaults(func=func)
    add_debug_flag(parser)
    return parser


def _bug(args: argparse.Namespace) -> int:
    return {"a": 1}["b"]  # a KeyError inside vecu is a bug, not a user error


def _user_mistake(args: argparse.Namespace) -> int:
    raise BadFileError("x.toml", "not what was expected")


@pytest.mark.parametrize("debug", [[], ["--debug"]])
def test_a_bug_is_a_traceback_and_exit_1(debug: list[str], capsys) -> None:
    rc = run_command(_with_test_subcommand(_bug).parse_args(["boom", *debug]))
    err = capsys.readouterr().err
    assert rc == 1
    assert err.startswith("Traceback (most recent call last):") and "KeyError: 'b'" in err
    assert "vecu: error" not in err


def test_user_error_from_a_subcommand_in_process(capsys) -> None:
    parser = _with_test_subcommand(_user_mistake)
    assert run_command(parser.parse_args(["boom"])) == 2
    assert capsys.readouterr().err == "vecu: error: x.toml: not what was expected\n"
    assert run_command(parser.parse_args(["--debug", "boom"])) == 2
    err = capsys.readouterr().err
    assert "Traceback" in err and err.endswith("vecu: error: x.toml: not what was expected\n")


def test_ctrl_c_is_exit_130() -> None:
    def interrupted(args: argparse.Namespace) -> int:
        raise KeyboardInterrupt

    assert run_command(_with_test_subcommand(interrupted).parse_args(["boom"])) == 130


def test_a_bug_in_a_real_process_exits_1() -> None:
    code = ("import argparse, sys; from vecu.cli import run_command; "
            "sys.exit(run_command(argparse.Namespace(func=lambda a: int('x'))))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=ENV,
                         timeout=60, check=False)
    assert res.returncode == 1 and "ValueError: invalid literal" in res.stderr, res.stderr
    assert "Traceback" in res.stderr and "vecu: error" not in res.stderr
