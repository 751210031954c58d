"""Issue 17: a udsoncan tester over can-isotp against `vecu ecu` live on udp_multicast (private
network namespace): VIN, live throttle, the TPS DTC with its snapshot after a kill, clear,
security, a forced sensor value. Fails on the tree before vecu/uds (no answer on 0x7E0)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from vecu.live.netns import namespace_prefix, run_in_namespace

HERE = Path(__file__).resolve().parent


@pytest.mark.skipif(namespace_prefix()[0] is None, reason=namespace_prefix()[1] or "n/a")
def test_a_udsoncan_tester_diagnoses_the_live_ecu_on_udp_multicast(tmp_path):
    res = run_in_namespace([sys.executable, str(HERE / "uds_live_tester.py"), str(tmp_path)],
                           timeout=240)
    _check(res, tmp_path)


def _check(res, tmp_path) -> None:
    assert res.returncode == 0, res.stderr + res.stdout + "".join(
        p.read_text() for p in tmp_path.glob("*.err"))
    out = json.loads(res.stdout.strip().splitlines()[-1])
    assert out["vin"] == "1VECU00SIM0000001"
    assert out["live"]["0103"] == 0 and out["live"]["0105"] == 0  # the sensor, ok
    assert [0x012200, 0x2F] in out["confirmed"]
    assert out["snapshot"]["0104"] == 0.0 and out["snapshot"]["0105"] == 2
    assert 0x012200 in out["after_clear"]  # still dead: back at once
    assert out["forced"] == [pytest.approx(4.99), 3]  # range_high, as if the sensor sent 4.99 V
    assert out["latency_ms"] < 500
    uds = out["uds"]
    assert uds["requests"] >= 10 and uds["transport_errors"] == 0 and uds["negative"] == 0
