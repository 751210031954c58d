"""Two `vecu ecu` processes, instance 0 and 1, and a plant on one udp_multicast bus (private
network namespace): a udsoncan tester tells them apart by their IDs (docs/live.md 'Several ECUs
on one bus'), and each one's frames are on the bus at its own IDs."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.live.pair import run_script
from vecu.live.netns import namespace_prefix

HERE = Path(__file__).resolve().parent


@pytest.mark.slow
@pytest.mark.skipif(namespace_prefix()[0] is None, reason=namespace_prefix()[1] or "n/a")
def test_two_live_ecus_on_one_bus_answer_each_at_its_own_ids(tmp_path):
    out = run_script(HERE / "instances_live.py", tmp_path, timeout=240)
    assert out["serial"] == {"0": "VECU-00000", "1": "VECU-00001"}
    assert all(0x012200 in out["dtcs"][n] for n in ("0", "1"))  # each its own TPS DTC
    s0, s1 = out["summary0"], out["summary1"]
    assert (s0["instance"], s1["instance"]) == (0, 1)
    assert s0["uds"]["requests"] >= 2 and s1["uds"]["requests"] >= 2
    ids = out["ids"]
    # instance 0: throttle 0x200, manifold 0x210, status 0x300; instance 1: throttle 0x260,
    # speed 0x280, steering 0x290, status 0x360 - and neither the other's functions' frames
    assert s0["can_ids"]["ECU_ThrottleEstimate"] == "0x200"
    assert s1["can_ids"]["ECU_ThrottleEstimate"] == "0x260"
    for present in ("0x200", "0x300", "0x260", "0x280", "0x360"):
        assert ids.get(present, 0) > 0, (present, ids)
    assert ids.get("0x300", 0) < 30 and ids.get("0x360", 0) < 30  # 100 ms each, one sender
    for absent in ("0x220", "0x230", "0x270"):  # speed, steering of 0; manifold of 1
        assert absent not in ids, (absent, ids)
