"""`vecu bench --only xcp` (quick): every figure is there, DAQ lost no ODT, and every ECU tick
that broadcast also sampled (the DAQ did not take a broadcast tick)."""

from __future__ import annotations

import pytest

from vecu.bench.xcp import bench_xcp, format_xcp

pytestmark = pytest.mark.alone  # live processes on the wall clock


def test_bench_xcp_quick():
    r = bench_xcp(commands=10, daq_s=0.5)
    daq, bd = r["daq"], r["broadcast_daq"]
    assert daq["odts_lost_at_slave"] == 0 and daq["samples"] > 0
    # one sample per tick the ECU ran, within a tick at either end of the window
    assert abs(daq["samples"] - bd["estimates_sent"]) <= 3
    assert bd["estimates_sent"] <= bd["ecu_ticks"]
    assert r["command"]["n"] == r["echo"]["n"] == 10
    assert r["command"]["p50_ms"] > 0 and r["echo"]["p50_ms"] > 0
    cost = r["daq_cost"]  # simulated clock: three DTOs a tick, the tick well inside 1 ms
    assert cost["odts_sent"] == 3 * cost["ticks_each"]
    assert 0 < cost["tick_us_p50_daq"] < 1000 and cost["tick_us_p50"] > 0
    text = format_xcp(r)
    assert "samples/s" in text and "broadcast ticks kept" in text and "bare echo" in text
    assert "ECU tick CPU" in text
