"""Trace source: frame times at 1 us (every format keeps that), idle gaps shortened and counted."""

from __future__ import annotations

import can
import pytest

from vecu.clock import NS_PER_S
from vecu.replay.source import IDLE_GAP_NS, TraceSource


def _write(path, times):
    with can.Logger(str(path)) as w:
        for t in times:
            w.on_message_received(can.Message(timestamp=t, arbitration_id=0x100, data=bytes(4)))


def test_frame_times_are_rounded_to_the_microsecond(tmp_path):
    """Issue 14 item 5: python-can's MF4 writer gives times back ~1e-7 s off; a frame recorded
    on a tick must not come back after it (one tick late). CSV keeps the floats as written."""
    path = tmp_path / "t.csv"
    _write(path, [100.0, 100.001 + 1.2e-7, 100.002 - 1.2e-7, 100.0030004, 100.0040006])
    times = [t for t, _ in TraceSource(str(path))]
    assert times == [0, 1_000_000, 2_000_000, 3_000_000, 4_001_000]


def test_an_idle_gap_is_shortened_counted_and_mapped_back(tmp_path):
    """Issue 14 item 6: two frames 5 h apart; the replay's clock skips all but IDLE_GAP_NS."""
    path = tmp_path / "gap.log"
    path.write_text("(0.000000) vecu 100#F4008813\n(0.001000) vecu 100#F4008813\n"
                    "(18000.000000) vecu 100#F4008813\n(18000.001000) vecu 100#F4008813\n")
    src = TraceSource(str(path))
    times = [t for t, _ in src]
    resume = 1_000_000 + IDLE_GAP_NS
    assert times == [0, 1_000_000, resume, resume + 1_000_000]
    skipped = 18000 * NS_PER_S - 1_000_000 - IDLE_GAP_NS
    st = src.stats
    assert (st.gaps, st.skipped_ns, st.longest_gap_ns) == (1, skipped, 18000 * NS_PER_S - 1_000_000)
    assert st.gap_list == [(1_000_000, 18000 * NS_PER_S - 1_000_000)]
    # replay time -> trace time: nothing skipped before the frame that ends the gap
    assert src.skipped_before(resume - 1) == 0
    assert src.skipped_before(resume) == skipped
    assert resume + src.skipped_before(resume) == 18000 * NS_PER_S


@pytest.mark.parametrize("gap_s", [0.5, 9.9])
def test_a_silence_shorter_than_the_idle_gap_is_kept(tmp_path, gap_s):
    path = tmp_path / "short.log"
    _write(path, [0.0, gap_s])
    src = TraceSource(str(path))
    assert [t for t, _ in src] == [0, round(gap_s * NS_PER_S)]
    assert src.stats.gaps == 0 and src.skipped_before(10 * NS_PER_S) == 0
