"""The poll shortcuts (timeout 0, no filters) of FastVirtualBus and FastUdpMulticastBus behave
like python-can's BusABC.recv."""

from __future__ import annotations

import json
import sys

import can
import pytest

from vecu.bus import open_bus
from vecu.live.netns import namespace_prefix, run_in_namespace


def test_poll_returns_frames_in_order_then_none_and_respects_filters():
    tx, rx = open_bus(channel="poll"), open_bus(channel="poll")
    try:
        for i in range(3):
            tx.send(can.Message(arbitration_id=0x10 + i, data=[i], is_extended_id=False))
        assert [rx.recv(0.0).arbitration_id for _ in range(3)] == [0x10, 0x11, 0x12]
        assert rx.recv(0.0) is None and rx.recv(0) is None
        rx.set_filters([{"can_id": 0x11, "can_mask": 0x7FF, "extended": False}])
        for i in range(3):
            tx.send(can.Message(arbitration_id=0x10 + i, data=[i], is_extended_id=False))
        got = [rx.recv(0.0) for _ in range(4)]  # python-can's own recv: one frame per poll
        assert [m.arbitration_id for m in got if m is not None] == [0x11]
    finally:
        tx.shutdown()
        rx.shutdown()
    with pytest.raises(can.CanOperationError):
        rx.recv(0.0)  # a shut-down bus refuses, as python-can's does


UDP_CHECK = r'''
import json, sys, time
import can
from vecu.bus import FastUdpMulticastBus, open_bus
G = "239.74.163.2"
tx = can.Bus(interface="udp_multicast", channel=G)
fast, plain = open_bus("udp_multicast", G), can.Bus(interface="udp_multicast", channel=G)
fast.skip_keys = frozenset({(0x200, False)})
sent = [can.Message(arbitration_id=0x100 + i, data=bytes([i] * (i % 9)), is_extended_id=i % 3 == 0)
        for i in range(20)]
sent += [can.Message(arbitration_id=0x200, data=bytes(8), is_extended_id=False)] * 5
sent += [can.Message(arbitration_id=0x123, is_remote_frame=True, dlc=3, is_extended_id=False),
         can.Message(is_error_frame=True)]
for m in sent:
    tx.send(m)
time.sleep(0.3)
def drain(bus):
    out = []
    while (m := bus.recv(0.0)) is not None:
        out.append(m)
    return out
got, ref = drain(fast), drain(plain)
key = lambda m: [m.arbitration_id, m.is_extended_id, m.is_remote_frame, m.is_error_frame, m.dlc,
                 bytes(m.data).hex(), m.is_rx, m.is_fd, m.channel]
res = {"fast": type(fast) is FastUdpMulticastBus, "got": [key(m) for m in got],
       "ref": [key(m) for m in ref if (m.arbitration_id, m.is_extended_id) != (0x200, False)],
       "skipped": fast.skipped, "dt_ms": max(abs(a.timestamp - b.timestamp) * 1e3 for a, b in
       zip(got, [m for m in ref if m.arbitration_id != 0x200 or m.is_extended_id])),
       "empty_wait": fast.recv(0.05) is None}
fast.shutdown()
try:
    fast.recv(0.0)
    res["after_shutdown"] = "no error"
except can.CanOperationError:
    res["after_shutdown"] = "CanOperationError"
tx.shutdown(); plain.shutdown()
print(json.dumps(res))
'''


@pytest.mark.skipif(namespace_prefix()[0] is None, reason=namespace_prefix()[1] or "n/a")
def test_udp_multicast_poll_gives_python_cans_frames_and_skips_the_owners_ids():
    """FastUdpMulticastBus.recv(0) (no select, own IDs dropped before decoding) hands over the
    same frames as python-can's recv, kernel timestamps included."""
    res = run_in_namespace([sys.executable, "-c", UDP_CHECK], timeout=120)
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout.strip().splitlines()[-1])
    assert out["fast"] and len(out["got"]) == 22 and out["got"] == out["ref"]
    assert out["skipped"] == 5 and out["dt_ms"] < 50 and out["empty_wait"]
    assert out["after_shutdown"] == "CanOperationError"
