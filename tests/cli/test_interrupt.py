"""Ctrl-C on a long-running command: the partial summary where --summary asked for it, one line
saying how far the command came and what it kept, exit 130 (vecu.cli.run_command with
vecu.errors.Interrupted; the runner and the replay raise it with their summary so far)."""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import can
import pytest

from vecu.argtypes import OutputPath
from vecu.cli import run_command
from vecu.config import RunConfig
from vecu.errors import Interrupted
from vecu.runner import run

ENV = {**os.environ, "VECU_KERNELS": "python"}


def test_an_interrupted_command_writes_its_partial_summary_and_says_what_it_kept(
        tmp_path: Path, capsys) -> None:
    log, summary = tmp_path / "x.log", tmp_path / "s.json"
    old = tmp_path / "old.png"
    old.write_text("from before")  # not written by the command: not kept

    def cut(args: argparse.Namespace) -> int:
        log.write_text("frames")
        raise Interrupted("2.5 of 60 s simulated", {"ticks": 2500})

    args = argparse.Namespace(func=cut, log=OutputPath(str(log), "log"),
                              summary=OutputPath(str(summary)), plot=OutputPath(str(old), "plot"))
    assert run_command(args) == 130
    assert capsys.readouterr().err == (f"vecu: interrupted after 2.5 of 60 s simulated; kept "
                                       f"--log {log}, --summary {summary} (partial)\n")
    assert json.loads(summary.read_text()) == {"ticks": 2500, "interrupted": True}


def test_ctrl_c_elsewhere_says_nothing_was_written(capsys) -> None:
    def cut(args: argparse.Namespace) -> int:
        raise KeyboardInterrupt

    assert run_command(argparse.Namespace(func=cut)) == 130
    assert capsys.readouterr().err == "vecu: interrupted; nothing written\n"


def test_the_runner_interrupted_returns_the_summary_of_the_ticks_run() -> None:
    """A KeyboardInterrupt inside the run loop (here from the progress callback after the
    first simulated second) is an Interrupted carrying the summary of that second."""
    def progress(t_s: float, duration_s: float) -> None:
        raise KeyboardInterrupt

    with pytest.raises(Interrupted) as exc:
        run(RunConfig(duration_s=30.0, kill_tps_at_s=None), progress)
    s = exc.value.summary
    assert exc.value.done == "1 of 30 s simulated"
    assert s is not None and s["ticks"] == 1000 and s["sim_time_s"] == 1.0
    assert s["frames"]["sent"] > 0


# ------------------------------------------------------------------ a real Ctrl-C
def _interrupt(argv: list[str], cwd: Path, started: Path) -> subprocess.CompletedProcess:
    """Start vecu, wait until `started` exists and is not empty (the command is at work), send
    SIGINT, collect."""
    # a test run started in the background inherits SIGINT ignored, and so would vecu (Python then
    # installs no KeyboardInterrupt): the default handler is set again for the child's exec
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        proc = subprocess.Popen([sys.executable, "-m", "vecu", *argv], cwd=cwd, env=ENV,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    finally:
        signal.signal(signal.SIGINT, previous)
    try:
        deadline = time.monotonic() + 120
        while not (started.exists() and started.stat().st_size > 0):
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.02)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


@pytest.mark.slow
def test_ctrl_c_on_run_keeps_the_log_and_the_summary_of_what_ran(tmp_path: Path) -> None:
    res = _interrupt(["run", "--duration", "3600", "--log", "x.log", "--summary", "s.json"],
                     tmp_path, tmp_path / "x.log")
    assert res.returncode == 130 and res.stdout == "", res.stderr
    line = res.stderr.strip()
    assert line.startswith("vecu: interrupted after ") and "\n" not in line, res.stderr
    assert line.endswith(" of 3600 s simulated; kept --log x.log, --summary s.json (partial)")
    s = json.loads((tmp_path / "s.json").read_text())
    assert s["interrupted"] is True and 0 < s["sim_time_s"] < 3600
    lines = (tmp_path / "x.log").read_text().splitlines()
    assert s["frames"]["logged"] == len(lines) > 0  # every frame the summary counts is in the log


@pytest.mark.slow
def test_ctrl_c_on_replay_keeps_what_was_replayed(tmp_path: Path) -> None:
    with can.Logger(str(tmp_path / "t.log")) as w:  # 60 s of trace, replayed at its own pace
        for k in range(6000):
            w.on_message_received(can.Message(timestamp=k * 0.01, arbitration_id=0x123,
                                              is_extended_id=False, data=bytes(8)))
    res = _interrupt(["replay", "t.log", "--speed", "1", "--out", "o.log", "--with-inputs",
                      "--summary", "s.json", "--no-progress", "--quiet"],
                     tmp_path, tmp_path / "o.log")
    assert res.returncode == 130 and res.stdout == "", res.stderr
    s = json.loads((tmp_path / "s.json").read_text())
    line = res.stderr.strip()
    assert line.startswith("vecu: interrupted after ") and "\n" not in line, res.stderr
    assert line.endswith(f" s of the trace ({s['frames']['read']} frames read); kept --out "
                         "o.log, --summary s.json (partial)"), line
    assert s["interrupted"] is True and 0 < s["frames"]["read"] < 6000
    assert s["frames_written"] == len((tmp_path / "o.log").read_text().splitlines())


@pytest.mark.slow
@pytest.mark.parametrize("argv,started", [
    (["plant", "--duration", "3600", "--ready-file", "ready", "--no-status"], "ready"),
    (["restbus", "{dbc}", "--realtime", "--duration", "3600", "--log", "ready.log"], "ready.log"),
], ids=["plant", "restbus"])
def test_ctrl_c_on_a_live_node(argv: list[str], started: str, tmp_path: Path) -> None:
    from vecu.codec import builtin_dbc_path

    argv = [a.format(dbc=builtin_dbc_path()) for a in argv] + ["--summary", "s.json"]
    (tmp_path / started).unlink(missing_ok=True)
    res = _interrupt(argv, tmp_path, tmp_path / started)
    assert res.returncode == 130, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vecu: interrupted after "), res.stderr
    assert "--summary s.json (partial)" in lines[0]
    s = json.loads((tmp_path / "s.json").read_text())
    assert s.get("stopped_by") == "SIGINT" or s.get("interrupted") is True
