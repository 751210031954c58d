"""`vecu gateway` as a user runs it, inside a private network namespace (it binds TCP/UDP on
127.0.0.1): a short run writes its summary; a port already taken is one line `vecu: error:`
naming it, exit 2, before any work."""

from __future__ import annotations

import json
import sys

import pytest

from vecu.live.netns import namespace_prefix, run_in_namespace

pytestmark = pytest.mark.skipif(namespace_prefix()[0] is None,
                                reason=namespace_prefix()[1] or "n/a")
TAKE_PORT = ("import socket, subprocess, sys; s = socket.socket(); s.bind(('127.0.0.1', 13400)); "
             "s.listen(); r = subprocess.run([sys.executable, '-m', 'vecu', 'gateway', "
             "'--duration', '1'], capture_output=True, text=True); print(r.returncode); "
             "print(r.stderr)")


def test_a_short_run_writes_the_summary(tmp_path):
    summary = tmp_path / "gw.json"
    res = run_in_namespace([sys.executable, "-m", "vecu", "gateway", "--duration", "1.6",
                            "--seed", "7", "--summary", str(summary)], timeout=60)
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith("vecu gateway: 1.6 s")
    s = json.loads(summary.read_text())
    assert s["role"] == "gateway" and s["stopped_by"] == "duration"
    d = s["doip"]
    assert d["port"] == 13400 and d["udp"]["announcements"] == 3  # A_DoIP_Announce_Num
    # the first after a seeded random 0 .. 500 ms (A_DoIP_Announce_Wait): the same every run
    assert 0 <= d["announce_delay_ms"] <= 500
    again = run_in_namespace([sys.executable, "-m", "vecu", "gateway", "--duration", "0.1",
                              "--seed", "7", "--summary", str(summary)], timeout=60)
    assert again.returncode == 0
    assert json.loads(summary.read_text())["doip"]["announce_delay_ms"] == d["announce_delay_ms"]
    assert [r["logical_address"] for r in s["routes"]["routes"]] == [0x0010, 0x0011]


def test_a_taken_port_is_a_one_line_error():
    res = run_in_namespace([sys.executable, "-c", TAKE_PORT], timeout=60)
    code, *err = res.stdout.strip().splitlines()
    assert code == "2", res.stdout + res.stderr
    assert err[0].startswith("vecu: error: --doip-bind 127.0.0.1 --doip-port 13400:")
    assert "in use" in err[0] and len([ln for ln in err if ln.strip()]) == 1
