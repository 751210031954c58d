from __future__ import annotations

import pytest

from vecu.clock import NS_PER_MS, SimClock, WallClock
from vecu.scheduler import Scheduler


def test_periodic_tasks_run_at_exact_times_in_priority_order():
    clock = SimClock()
    sched = Scheduler(clock)
    calls: list[tuple[str, int]] = []
    sched.every(2 * NS_PER_MS, lambda t: calls.append(("b2ms", t)), name="b", priority=5)
    sched.every(NS_PER_MS, lambda t: calls.append(("a1ms", t)), name="a", priority=0)
    sched.at(3 * NS_PER_MS, lambda t: calls.append(("event", t)), name="e", priority=-1)
    sched.run_until(5 * NS_PER_MS)
    assert calls == [
        ("a1ms", 0), ("b2ms", 0), ("a1ms", 1 * NS_PER_MS), ("a1ms", 2 * NS_PER_MS),
        ("b2ms", 2 * NS_PER_MS), ("event", 3 * NS_PER_MS), ("a1ms", 3 * NS_PER_MS),
        ("a1ms", 4 * NS_PER_MS), ("b2ms", 4 * NS_PER_MS),
    ]
    assert clock.now_ns() == 5 * NS_PER_MS
    assert sched.overruns == 0


def test_no_drift_over_a_simulated_hour():
    clock = SimClock()
    sched = Scheduler(clock)
    stats = sched.every(NS_PER_MS, lambda t: None, name="tick")
    last = []
    sched.every(1000 * NS_PER_MS, lambda t: last.append(t), name="1s")
    sched.run_until(3600 * 1000 * NS_PER_MS)
    assert stats.runs == 3_600_000
    assert last[-1] == 3599 * 1000 * NS_PER_MS  # integer ns: exact, no float accumulation


class FakeTime:
    """Monotonic time advanced by sleeps and by simulated work."""

    def __init__(self) -> None:
        self.t = 0
        self.sleeps: list[float] = []

    def mono(self) -> int:
        self.t += 1_000  # each clock read costs 1 us
        return self.t

    def sleep(self, s: float) -> None:
        self.sleeps.append(s)
        self.t += int(s * 1e9)


def test_wall_clock_waits_on_absolute_deadlines_and_counts_overruns():
    ft = FakeTime()
    clock = WallClock(spin_ns=200_000, sleep=ft.sleep, monotonic_ns=ft.mono)
    sched = Scheduler(clock, record_lateness=True)
    starts: list[int] = []

    def work(t: int) -> None:
        starts.append(t)
        if t == 5 * NS_PER_MS:  # one release takes 3.5 periods
            ft.t += 3_500_000

    stats = sched.every(NS_PER_MS, work, name="tick")
    sched.run_until(20 * NS_PER_MS)
    assert stats.overruns == 1
    assert stats.skipped == 3  # releases at 6, 7 and 8 ms dropped, no catch-up burst
    assert 9 * NS_PER_MS in starts and 6 * NS_PER_MS not in starts
    # deadlines stay on the 1 ms grid after the overrun (absolute, no drift)
    assert all(t % NS_PER_MS == 0 for t in starts)
    assert ft.sleeps, "the wall clock must sleep rather than only spin"
    assert max(stats.lateness_ns) < 2 * NS_PER_MS


def test_skips_past_the_end_of_a_run_are_counted_only_when_reached():
    """A stall near the end of run_until must not count releases beyond its end as skipped
    (runs + skipped == releases of the window); a later run_until that reaches them does."""
    ft = FakeTime()
    clock = WallClock(spin_ns=200_000, sleep=ft.sleep, monotonic_ns=ft.mono)
    sched = Scheduler(clock)

    def work(t: int) -> None:
        if t == 18 * NS_PER_MS:  # stalls 4.5 periods: releases 19..22 ms are missed
            ft.t += 4_500_000

    stats = sched.every(NS_PER_MS, work, name="tick")
    sched.run_until(20 * NS_PER_MS)
    assert stats.runs + stats.skipped == 20  # releases 0..19 ms; 20..22 ms lie beyond the end
    assert stats.skipped == 1 and stats.overruns == 1
    sched.run_until(30 * NS_PER_MS)
    assert stats.runs + stats.skipped == 30 and stats.skipped == 4


def test_scheduler_rejects_bad_period():
    with pytest.raises(ValueError):
        Scheduler(SimClock()).every(0, lambda t: None, name="bad")


def test_stop_returns_early():
    clock = SimClock()
    sched = Scheduler(clock)
    sched.every(NS_PER_MS, lambda t: sched.stop() if t == 3 * NS_PER_MS else None, name="s")
    sched.run_until(100 * NS_PER_MS)
    assert clock.now_ns() == 3 * NS_PER_MS


def test_chained_event_task_follows_a_varying_period_interleaved_with_fixed_ticks():
    """Engine events every Ts = 120 / (8 N) s with N ramping, between 1 ms ticks."""
    clock = SimClock()
    sched = Scheduler(clock)
    events: list[int] = []
    order: list[str] = []

    def engine_event(t: int) -> int | None:
        events.append(t)
        order.append("event")
        rpm = 1000.0 + 100.0 * len(events)
        return t + int(round(120.0 / (8.0 * rpm) * 1e9))

    sched.every(NS_PER_MS, lambda t: order.append("tick"), name="tick", priority=5)
    stats = sched.chain(0, engine_event, name="engine", priority=0)
    sched.run_until(100 * NS_PER_MS)
    gaps = [b - a for a, b in zip(events, events[1:])]
    assert gaps == [int(round(120.0 / (8.0 * (1000.0 + 100.0 * k)) * 1e9))
                    for k in range(1, len(events))]
    assert stats.runs == len(events) and events[-1] < 100 * NS_PER_MS <= events[-1] + gaps[-1] + 1
    assert order.count("tick") == 100


def test_chained_task_must_move_forward():
    sched = Scheduler(SimClock())
    sched.chain(0, lambda t: t, name="stuck")
    with pytest.raises(ValueError, match="not after"):
        sched.run_until(NS_PER_MS)


def test_a_catch_up_window_runs_missed_releases_late_instead_of_skipping_them():
    """Issue 29: a live plant that stalls 50 ms skipped every send of those 50 ms for good; with
    a 20 ms catch-up window the releases of the last 20 ms run late, back to back, in order,
    and only the older ones are skipped."""
    ft = FakeTime()
    clock = WallClock(spin_ns=200_000, sleep=ft.sleep, monotonic_ns=ft.mono)
    sched = Scheduler(clock)
    starts: list[int] = []

    def work(t: int) -> None:
        starts.append(t)
        if t == 5 * NS_PER_MS:  # one release stalls 50.5 periods
            ft.t += 50_500_000

    stats = sched.every(NS_PER_MS, work, name="plant", catch_up_ns=20 * NS_PER_MS)
    sched.run_until(100 * NS_PER_MS)
    assert stats.overruns == 1  # one stall
    # it ends at 55.5 ms: 6..35 ms are older than the window (skipped), 36..55 ms run late,
    # in order (19 of them after their next deadline: caught up), none lost
    assert stats.skipped == 30 and stats.caught_up == 19
    assert starts == sorted(starts) and stats.runs + stats.skipped == 100
    assert [t // NS_PER_MS for t in starts if t > 5 * NS_PER_MS][:20] == list(range(36, 56))


def test_a_task_that_schedules_an_earlier_release_keeps_the_order():
    """A periodic task that puts a one-shot ahead of its own next release (same time, lower
    priority; the simulated loop's release is then no longer on top of its heap) and a one-shot
    that adds another: every release once, in (time, priority, registration) order."""
    sched = Scheduler(SimClock())
    calls: list[tuple[str, int]] = []

    def a(t):
        calls.append(("a", t))
        if t == NS_PER_MS:
            sched.at(t, lambda u: calls.append(("now", u)), name="now", priority=-5)
            sched.at(t, b, name="b", priority=-1)

    def b(t):
        calls.append(("b", t))
        sched.at(t, lambda u: calls.append(("c", u)), name="c", priority=-3)

    sched.every(NS_PER_MS, a, name="a", priority=0)
    sched.every(NS_PER_MS, lambda t: calls.append(("z", t)), name="z", priority=1)
    sched.run_until(3 * NS_PER_MS)
    m = NS_PER_MS
    assert calls == [("a", 0), ("z", 0), ("a", m), ("now", m), ("b", m), ("c", m), ("z", m),
                     ("a", 2 * m), ("z", 2 * m)]
    assert [t.runs for t in sched.stats] == [3, 3, 1, 1, 1]
