"""Ctrl-C / SIGTERM on `vecu campaign run` (issue 29 item 4): one vecu line naming the rows kept
and the command that finishes the campaign, exit 130 (SIGINT) / 143 (SIGTERM), no Dask
traceback, no process left running; the printed command completes it to the same bytes."""

from __future__ import annotations

import os
import shlex
import signal
import subprocess
import sys
import time

import pytest

from tests.campaign.test_engine import ENV, _kill, reference, small  # noqa: F401 (fixtures)
from vecu.campaign.engine import RUNS_CSV, columns, read_rows

pytest.importorskip("distributed")


def _alive_in_session(sid: int) -> list[str]:
    """Processes of session `sid` still running (zombies are dead: not counted)."""
    ps = subprocess.run(["ps", "-e", "-o", "sid=,stat=,pid=,args="], capture_output=True,
                        text=True, check=True).stdout
    return [line for line in ps.splitlines()
            if line.split()[0] == str(sid) and not line.split()[1].startswith("Z")]


@pytest.mark.parametrize(("sig", "whole_group", "code"), [
    (signal.SIGINT, True, 130),    # Ctrl-C on a terminal: the whole foreground group gets it
    (signal.SIGTERM, False, 143),  # a service manager / kill PID
])
def test_an_interrupted_campaign_says_one_line_and_resumes(small, reference, tmp_path,  # noqa: F811 (fixtures)
                                                          sig, whole_group, code):
    out = tmp_path / "cut"
    # a test run started in the background inherits SIGINT ignored, and so would vecu (Python then
    # installs no KeyboardInterrupt): a handled SIGINT here is reset to the default at exec
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        proc = subprocess.Popen([sys.executable, "-m", "vecu", "campaign", "run", small.path,
                                 "--workers", "2", "--out", str(out), "--runs", "6"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                start_new_session=True, env=ENV)
    finally:
        signal.signal(signal.SIGINT, previous)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            if (out / RUNS_CSV).exists() and len(read_rows(out / RUNS_CSV, columns(small))) >= 1:
                break
            time.sleep(0.05)
        if whole_group:
            os.killpg(proc.pid, sig)
        else:
            proc.send_signal(sig)
        _, stderr = proc.communicate(timeout=60)
    finally:
        _kill(proc)
    kept = len(read_rows(out / RUNS_CSV, columns(small)))
    assert proc.returncode == code, stderr
    assert "Traceback" not in stderr and "KeyboardInterrupt" not in stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    line = lines[0]
    assert line.startswith(f"vecu: interrupted: {kept}/6 runs kept in {out}; `"), line
    time.sleep(0.5)
    assert _alive_in_session(proc.pid) == []  # no worker or nanny left behind
    command = shlex.split(line.split("`")[1])
    assert command[:3] == ["vecu", "campaign", "run"] and command[-1] == "--resume"
    res = subprocess.run([sys.executable, "-m", "vecu", *command[1:], "--no-progress"],
                         capture_output=True, text=True, env=ENV, timeout=300, check=False)
    assert res.returncode == 0, res.stderr
    assert f"6/6 runs in {out} ({6 - kept} new" in res.stdout
    assert (out / RUNS_CSV).read_bytes() == (reference / RUNS_CSV).read_bytes()
