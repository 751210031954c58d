"""`vecu replay TRACE --gateway`: the powertrain bus of a `vecu run --gateway` log, without the
ECU's frames, replayed through the same gateway gives the run's vehicle bus frame for frame
(the ECU recomputes its estimates, the gateway routes them and the trace's frames)."""

from __future__ import annotations

import os
import subprocess
import sys

import can
import pytest

from .routing_setup import write_config

ENV = {**os.environ, "VECU_KERNELS": "python"}


def _vecu(*argv: str, cwd) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "vecu", *argv], cwd=cwd, env=ENV, text=True,
                          capture_output=True, timeout=300, check=False)


def _lines(path, channel: str) -> list[str]:
    with can.LogReader(str(path)) as reader:
        return [f"{m.timestamp:.6f} {m.arbitration_id:X} {bytes(m.data).hex()}" for m in reader
                if m.channel == channel]


@pytest.mark.slow
def test_a_replayed_bus_routes_as_the_run_did(tmp_path):
    gw = write_config(tmp_path)
    done = _vecu("run", "--duration", "0.6", "--gateway", str(gw), "--log", "run.log",
                 cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    with can.LogReader(str(tmp_path / "run.log")) as reader, \
            can.Logger(str(tmp_path / "pt.log")) as writer:
        for m in reader:  # the plant's frames only: the replayed ECU sends its own
            if m.channel == "powertrain" and not 0x200 <= m.arbitration_id < 0x400:
                writer.on_message_received(m)
    done = _vecu("replay", "pt.log", "--gateway", str(gw), "--out", "rep.log", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "gateway routes[1] powertrain->vehicle: in 900, out 30" in done.stdout
    vehicle = _lines(tmp_path / "rep.log", "vehicle")
    assert len(vehicle) > 60 and {ln.split()[1] for ln in vehicle} == {"420", "500", "510"}
    assert vehicle == _lines(tmp_path / "run.log", "vehicle")
    # the replayed ECU's frames are on the first bus, under its name
    assert len(_lines(tmp_path / "rep.log", "powertrain")) == len(
        [ln for ln in _lines(tmp_path / "run.log", "powertrain")
         if 0x200 <= int(ln.split()[1], 16) < 0x400])


def test_replay_gateway_errors_before_any_work(tmp_path):
    gw = write_config(tmp_path, "[buses.a]\ninterface = \"virtual\"\ndbc = [\"nope.dbc\"]\n")
    (tmp_path / "t.log").write_text("(0.000000) can0 100#00\n")  # a trace: the config is at fault
    done = _vecu("replay", "t.log", "--gateway", str(gw), cwd=tmp_path)
    assert done.returncode == 2 and done.stderr.count("\n") == 1
    assert "buses.a.dbc" in done.stderr
    done = _vecu("replay", "t.log", "--gateway", str(gw), "--speed", "1", cwd=tmp_path)
    assert done.returncode == 2 and "no --speed" in done.stderr
