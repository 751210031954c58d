"""Issue 29 item 1, live: `vecu ecu` on udp_multicast (private network namespace) answers ISO-TP
requests of every length from two testers nobody here wrote, sending at full speed (STmin 0):
can-isotp's threaded stack and scapy's ISOTPSoftSocket. Before issue 29 (flow control BS 0)
requests above ~900 bytes got no response at all.

CI sends 61 lengths (every 97th from 1, plus the single-frame, first-block and 4095 limits);
VECU_ISOTP_ALL_LENGTHS=1 sends every length 1..4095 with both (about 15-25 minutes)."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest

from vecu.live.netns import namespace_prefix, run_in_namespace

HERE = Path(__file__).resolve().parent
pytest.importorskip("scapy")


@pytest.mark.skipif(namespace_prefix()[0] is None, reason=namespace_prefix()[1] or "n/a")
def test_can_isotp_and_scapy_get_their_answer_at_every_length_live(tmp_path):
    step = 1 if os.environ.get("VECU_ISOTP_ALL_LENGTHS") else 97
    res = run_in_namespace([sys.executable, str(HERE / "isotp_sweep_live.py"), str(tmp_path),
                            "1", "4095", str(step)], timeout=3000 if step == 1 else 300)
    assert res.returncode == 0, res.stderr + res.stdout + (tmp_path / "ecu.err").read_text()
    out = json.loads(res.stdout.strip().splitlines()[-1])
    n = out["lengths"]
    assert n >= (4095 if step == 1 else 61)
    assert out["can-isotp"]["wrong"] == {} and out["scapy"]["wrong"] == {}
    uds = out["uds"]
    assert uds["requests"] == 2 * n and uds["responses"] == 2 * n
    assert uds["frames_dropped"] == 0 and uds["transport_errors"] == 0
