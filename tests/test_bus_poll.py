"""FastVirtualBus.recv's poll shortcut (timeout 0, no filters) behaves like BusABC.recv."""

from __future__ import annotations

import can
import pytest

from vecu.bus import open_bus


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
