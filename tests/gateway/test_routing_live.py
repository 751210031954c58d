"""`vecu gateway` routing live between two udp_multicast buses in a private network namespace
(tests/gateway/routing_live_tester.py): every frame sent on one bus arrives on the other under
its new ID, payload untouched, and repacked with the speed converted; the summary on SIGTERM
has each route's latency. Bad --bus arguments are one line."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.live.pair import run_script
from vecu.live.netns import namespace_prefix

from .routing_setup import write_config

HERE = Path(__file__).resolve().parent


@pytest.mark.skipif(namespace_prefix()[0] is None, reason=namespace_prefix()[1] or "n/a")
def test_frames_sent_on_one_bus_arrive_routed_on_the_other(tmp_path):
    out = run_script(HERE / "routing_live_tester.py", tmp_path, timeout=300)
    assert out["returncode"] == 0 and out["stopped_by"] == "SIGTERM"
    assert out["routed"] == out["sent"]  # all 200, in order, payload untouched
    # on_change: a frame per step that brought new speeds (the latest wins), km/h -> m/s
    speeds, expected = out["speeds"], [(10.0 + i * 0.5) / 3.6 for i in range(200)]
    assert 50 < len(speeds) <= 200 and speeds[-1] == pytest.approx(expected[-1], abs=0.0026)
    assert all(any(abs(v - e) <= 0.0026 for e in expected) for v in speeds)
    assert speeds == sorted(speeds)
    routes = out["routing"]["routes"]
    frame_route, signal_route = routes["routes[0] powertrain->vehicle"], \
        routes["routes[1] powertrain->vehicle"]
    assert frame_route["in"] == frame_route["out"] == 200
    lat = frame_route["latency_us"]
    assert lat["count"] == 200 and 0 < lat["min"] <= lat["mean"] <= lat["p99"] <= lat["max"]
    assert signal_route["in"] == 200 and signal_route["latency_us"]["count"] == len(speeds)
    assert "gateway routes[0] powertrain->vehicle: in 200, out 200" in out["stdout"]
    assert "latency min/mean/p99/max" in out["stdout"]


def _gateway(*argv: str, cwd) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "vecu", "gateway", *argv, "--duration", "0.1"],
                          cwd=cwd, capture_output=True, text=True, timeout=120, check=False,
                          env={**os.environ, "VECU_KERNELS": "python"})


def test_bad_bus_overrides_are_one_line(tmp_path):
    gw = write_config(tmp_path)
    done = _gateway("--config", str(gw), "--bus", "chassis=virtual:x", cwd=tmp_path)
    assert done.returncode == 2 and done.stderr.count("\n") == 1
    assert "no bus 'chassis' in the config (buses: powertrain, vehicle)" in done.stderr
    done = _gateway("--config", str(gw), "--bus", "vehicle-virtual", cwd=tmp_path)
    assert done.returncode == 2 and "expected NAME=INTERFACE:CHANNEL" in done.stderr
    done = _gateway("--bus", "vehicle=virtual:x", cwd=tmp_path)
    assert done.returncode == 2 and "give --config with buses" in done.stderr
