"""Scenario runner: progress comes on time (wall-clock interval), whatever the run's length
(issue 14 item 13: a 24 h scenario printed its first line after 10 % of the run)."""

from __future__ import annotations

import io

from vecu.scenario.batch import Progress, run_scenarios
from vecu.scenario.loader import load_scenario


def test_progress_of_a_day_long_scenario_comes_every_interval_of_wall_time():
    wall = [0.0]
    out = io.StringIO()
    progress = Progress("day", out, interval_s=2.0, now=lambda: wall[0])
    day = 24 * 3600.0
    for t in range(1, 11):  # each simulated second takes 0.5 s of wall time
        wall[0] += 0.5
        progress(float(t), day)
    lines = out.getvalue().splitlines()
    assert len(lines) == 2, lines  # at 2 s and 4 s of wall time, not after 2.4 h simulated
    assert lines[0].startswith("  day: 4/86400 s simulated") and "2 s wall" in lines[0]
    assert lines[1].startswith("  day: 8/86400 s simulated")


def test_progress_ends_with_a_last_line_only_after_earlier_ones():
    wall = [0.0]
    short, long_ = io.StringIO(), io.StringIO()
    quick = Progress("quick", short, interval_s=2.0, now=lambda: wall[0])
    slow = Progress("slow", long_, interval_s=2.0, now=lambda: wall[0])
    for t in (1.0, 2.0, 3.0):
        wall[0] += 0.1
        quick(t, 3.0)
    assert short.getvalue() == ""  # done within the interval: no progress at all
    wall[0] = 0.0
    for t in (1.0, 2.0, 3.0):
        wall[0] += 1.5
        slow(t, 3.0)
    lines = long_.getvalue().splitlines()
    assert [ln.split(":")[1].split(" s ")[0].strip() for ln in lines] == ["2/3", "3/3"], lines


def test_a_short_scenario_with_a_small_interval_reports_progress(tmp_path):
    path = tmp_path / "short.toml"
    path.write_text('name = "short"\nduration_s = 2.0\nseed = 3\n')
    out = io.StringIO()
    (outcome,) = run_scenarios([load_scenario(path)], stream=out, progress_interval_s=0.0)
    assert outcome.error is None
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("  short: 1/2 s simulated"), lines
    assert lines[1].startswith("  short: 2/2 s simulated"), lines
    assert lines[2].startswith("[1/1] short: PASS"), lines
    quiet = io.StringIO()  # progress=False: the result line only
    run_scenarios([load_scenario(path)], stream=quiet, progress=False, progress_interval_s=0.0)
    assert [ln[:16] for ln in quiet.getvalue().splitlines()] == ["[1/1] short: PAS"]
