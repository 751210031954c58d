"""Recorder time stamps: 1 us, each frame on the same side of every ECU tick as it was sent."""

from __future__ import annotations

import pytest

from vecu.recorder import record_stamp


@pytest.mark.parametrize("sent_s,stamp_s", [
    (1.499, 1.499),                 # on a tick
    (1.2345672, 1.234567),          # between ticks: nearest us
    (1.49999997, 1.5),              # just before a tick: the tick (that tick takes it)
    (1.5000003, 1.500001),          # just after a tick: not on it (the next tick takes it)
    (1.5000007, 1.500001),
])
def test_stamps_keep_each_frame_on_its_side_of_the_ecu_tick(sent_s, stamp_s):
    assert record_stamp(sent_s) == stamp_s


def test_frames_sent_after_the_last_tick_stay_before_the_end_of_the_run():
    """Issue 14 item 4: a 1.5 s run's last engine event at 1.49999997 s came after the ECU's last
    tick (1.499 s); stamped 1.5 s, a replay would run a tick the live ECU never ran."""
    end_ns = 1_500_000_000
    assert record_stamp(1.49999997, before_ns=end_ns) == 1.499999
    assert record_stamp(1.4995, before_ns=end_ns) == 1.4995
