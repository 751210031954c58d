"""Trace source: frame times at 1 us (every format keeps that), idle gaps shortened and counted."""

from __future__ import annotations

import math

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

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


# ------------------------------------------------------------------ a corrupt MF4 (issue 14 item 9)
# asammdf prints on its own: a logger with its own stderr handler logs a traceback while it opens a
# corrupt file, and the half-built MDF4 object raises in __del__ ('Exception ignored in ...'). This
# stand-in does both, so the test runs where asammdf is not installed (python-can needs only these
# names from it to load its MF4 reader).
FAKE_ASAMMDF = {
    "__init__.py": (
        "import logging, sys\n"
        "logger = logging.getLogger('asammdf')\n"
        "logger.addHandler(logging.StreamHandler(sys.stderr))\n"
        "class Signal: pass\n"
        "class Source: pass\n"),
    "blocks/__init__.py": "",
    "blocks/v4_blocks.py": "class ChannelGroup: pass\nclass SourceInformation: pass\n",
    "blocks/v4_constants.py": "BUS_TYPE_CAN = 2\nFLAG_CG_BUS_EVENT = 2\nSOURCE_BUS = 2\n",
    "blocks/mdf_v4.py": (
        "import logging\n"
        "class MdfException(Exception): pass\n"
        "class MDF4:\n"
        "    def __init__(self, name, **kwargs):\n"
        "        try:\n"
        "            raise ValueError('CAN logging block broken')\n"
        "        except ValueError:\n"
        "            logging.getLogger('asammdf').exception('Error during CAN logging processing')\n"
        "        raise MdfException(f'Incomplete block in {name}')\n"
        "    def __del__(self):\n"
        "        self.close()\n"
        "    def close(self):\n"
        "        self._file.close()  # never set: AttributeError, as asammdf's\n"),
    "mdf.py": "from asammdf.blocks.mdf_v4 import MDF4 as MDF\n",
}


def _replay(trace, cwd, pythonpath=None):
    import os
    import subprocess
    import sys

    env = {**os.environ, "VECU_KERNELS": "python"}
    if pythonpath:
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(pythonpath), env.get("PYTHONPATH")) if p)
    return subprocess.run([sys.executable, "-m", "vecu", "replay", str(trace), "--no-progress"],
                          capture_output=True, text=True, env=env, cwd=cwd, timeout=120,
                          check=False)


def test_a_corrupt_mf4_is_one_line_without_the_readers_own_tracebacks(tmp_path):
    fake = tmp_path / "fake"
    for name, text in FAKE_ASAMMDF.items():
        (fake / "asammdf" / name).parent.mkdir(parents=True, exist_ok=True)
        (fake / "asammdf" / name).write_text(text)
    (tmp_path / "bad.mf4").write_bytes(b"MDF     4.10    " + bytes(48))
    res = _replay("bad.mf4", tmp_path, pythonpath=fake)
    assert res.returncode == 2 and res.stderr == (
        "vecu: error: bad.mf4: not an MF4 file (another format? try --format asc, blf, csv, db, "
        "log, trc)\n")


@pytest.mark.parametrize("damage", ["truncated", "overwritten"])
def test_a_corrupt_mf4_with_asammdf_is_one_line(tmp_path, damage):
    pytest.importorskip("asammdf")
    good = tmp_path / "good.mf4"
    with can.Logger(str(good)) as w:
        for k in range(2000):
            w.on_message_received(can.Message(timestamp=k * 1e-3, arbitration_id=0x100,
                                              data=bytes([k % 256, 1, 2, 3]), is_extended_id=False))
    data = bytearray(good.read_bytes())
    if damage == "truncated":
        data = data[:len(data) // 2]
    else:
        data[len(data) // 2:len(data) // 2 + 64] = b"\xa5" * 64
    (tmp_path / "bad.mf4").write_bytes(bytes(data))
    res = _replay("bad.mf4", tmp_path)
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(lines) == 1, res.stderr
    assert lines[0].startswith("vecu: error: bad.mf4: "), lines[0]


def _reference_order(stamps: list[float], window_ns: int, idle_ns: int) -> tuple[list, dict]:
    """The re-order window and idle-gap rules written plainly (a heap for every frame): what
    TraceSource's one-loop reader with its in-order FIFO must reproduce."""
    import heapq

    heap, out, released, prev, stats = [], [], None, None, {"late": 0, "out_of_order": 0}
    t0 = stamps[0]
    order = []
    for seq, ts in enumerate(stamps):
        if prev is not None and ts < prev:
            stats["out_of_order"] += 1
        prev = ts
        t_ns = math.floor((ts - t0) * 1_000_000 + 0.5) * 1000
        if t_ns < 0:
            stats["late"] += 1
            t_ns = 0
        if released is not None and t_ns < released:
            stats["late"] += 1
            t_ns = released
        heapq.heappush(heap, (t_ns, seq))
        while heap and heap[0][0] <= t_ns - window_ns:
            released, s = heapq.heappop(heap)
            order.append((released, s))
    order += [heapq.heappop(heap) for _ in range(len(heap))]
    last, skipped = None, 0
    for t_ns, s in order:
        if last is not None and t_ns - last > idle_ns:
            skipped += t_ns - last - idle_ns
        last = t_ns
        out.append((t_ns - skipped, s))
    stats["skipped_ns"] = skipped
    return out, stats


@settings(max_examples=30, deadline=None, derandomize=True)
@given(steps=st.lists(st.one_of(st.integers(0, 3000), st.integers(-80_000, -1),
                                st.sampled_from([0, 11_000_000, -60_000])), min_size=1,
                      max_size=60))
def test_ordering_and_idle_gaps_match_the_plain_heap_rules(tmp_path_factory, steps):
    """Frames in order, a little out of order (inside the 50 ms window), far out of order (late)
    and after idle gaps: the same order, times and counts as the rules written plainly."""
    path = tmp_path_factory.mktemp("order") / "t.log"
    stamps, t = [], 100.0
    for us in steps:
        t += us * 1e-6
        stamps.append(round(t, 6))
    with can.Logger(str(path)) as w:
        for i, ts in enumerate(stamps):
            w.on_message_received(can.Message(timestamp=ts, arbitration_id=i, data=b"\x01",
                                              is_extended_id=True))
    stamps = [m.timestamp for m in can.LogReader(str(path))]  # as the file holds them
    src = TraceSource(path, idle_gap_ns=1_000_000_000)
    got = [(t_ns, msg.arbitration_id) for t_ns, msg in src]
    want, stats = _reference_order(stamps, src.window_ns, 1_000_000_000)
    assert got == want
    assert (src.stats.late, src.stats.out_of_order, src.stats.skipped_ns) == \
           (stats["late"], stats["out_of_order"], stats["skipped_ns"])
