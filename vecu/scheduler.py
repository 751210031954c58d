"""Fixed-rate and event-driven task scheduler on the injected clock.

Periodic tasks are released on absolute deadlines (release k at offset + k*period), so a late
release never shifts later ones. A release that starts after its *next* deadline has already
passed is an overrun: it is counted and the missed releases are skipped (no catch-up bursts),
unless the task was given a catch-up window: then the missed releases not older than the window
run late, back to back (counted as caught up), and only older ones are skipped.
Tasks due at the same instant run in (priority, registration order), which makes a simulated run
fully deterministic.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable
from dataclasses import dataclass, field

from vecu.clock import Clock

TaskFn = Callable[[int], None]


@dataclass
class TaskStats:
    """Per-task counters; lateness is start time minus release time (ns, wall clock only)."""

    name: str
    period_ns: int | None
    runs: int = 0
    overruns: int = 0
    skipped: int = 0
    caught_up: int = 0  # releases run after their next deadline (catch_up_ns), not skipped
    max_lateness_ns: int = 0
    lateness_ns: list[int] = field(default_factory=list)


class Scheduler:
    """Runs periodic tasks and one-shot events in deadline order."""

    def __init__(self, clock: Clock, record_lateness: bool = False) -> None:
        self.clock = clock
        self._heap: list[tuple[int, int, int, int]] = []
        self._tasks: list[tuple[TaskFn, TaskStats, int | None, int]] = []  # fn, stats, period, priority
        self._seq = 0
        self._record_lateness = record_lateness
        self._stopped = False
        # releases skipped by an overrun that fall at or after the end of the run_until call
        # they happened in: per task (first skipped time, period, count); counted when a later
        # run_until reaches them, so a run's `runs + skipped` is exactly its releases
        self._skips_ahead: dict[int, tuple[int, int, int]] = {}
        self._catch_up: dict[int, int] = {}  # task index -> catch-up window (ns)

    def every(self, period_ns: int, fn: TaskFn, *, name: str, offset_ns: int = 0,
              priority: int = 0, catch_up_ns: int = 0) -> TaskStats:
        """Run fn(release_ns) at offset, offset + period, ... (priority: lower runs first).
        catch_up_ns (wall clock): after a stall, run the missed releases due within this window
        of now, late, instead of skipping them."""
        if period_ns <= 0:
            raise ValueError(f"task {name!r}: period must be positive, got {period_ns} ns")
        stats = self._add(fn, name, period_ns, offset_ns, priority)
        if catch_up_ns > 0:
            self._catch_up[len(self._tasks) - 1] = catch_up_ns
        return stats

    def at(self, t_ns: int, fn: TaskFn, *, name: str, priority: int = 0) -> TaskStats:
        """Run fn(t_ns) once at t_ns."""
        return self._add(fn, name, None, t_ns, priority)

    def chain(self, first_ns: int, fn: Callable[[int], int | None], *, name: str,
              priority: int = 0) -> TaskStats:
        """Event-driven task: fn(t_ns) returns its next release time (> t_ns), or None to stop.

        For rates that follow the plant, e.g. engine events every Ts = 120 / (8 N) seconds.
        """
        stats = TaskStats(name=name, period_ns=None)
        idx = len(self._tasks)

        def release(t_ns: int) -> None:
            nxt = fn(t_ns)
            if nxt is not None:
                if nxt <= t_ns:
                    raise ValueError(f"task {name!r}: next release {nxt} ns is not after {t_ns} ns")
                self._push(nxt, priority, idx)

        self._tasks.append((release, stats, None, priority))
        self._push(first_ns, priority, idx)
        return stats

    def _add(self, fn: TaskFn, name: str, period: int | None, first_ns: int,
             priority: int) -> TaskStats:
        stats = TaskStats(name=name, period_ns=period)
        idx = len(self._tasks)
        self._tasks.append((fn, stats, period, priority))
        self._push(first_ns, priority, idx)
        return stats

    def _push(self, due_ns: int, priority: int, idx: int) -> None:
        self._seq += 1
        heapq.heappush(self._heap, (due_ns, priority, self._seq, idx))

    def stop(self) -> None:
        """Ask run_until to return after the task now running."""
        self._stopped = True

    @property
    def stats(self) -> list[TaskStats]:
        return [t[1] for t in self._tasks]

    @property
    def overruns(self) -> int:
        return sum(t[1].overruns for t in self._tasks)

    def _count_skips_ahead(self, end_ns: int) -> None:
        for idx, (first, period, count) in list(self._skips_ahead.items()):
            inside = min(count, max(0, -((first - end_ns) // period)))
            self._tasks[idx][1].skipped += inside
            if inside == count:
                del self._skips_ahead[idx]
            else:
                self._skips_ahead[idx] = (first + inside * period, period, count - inside)

    def _run_simulated(self, end_ns: int) -> int:
        """run_until on a simulated clock (no lateness, no overruns): the same releases in the
        same order as the general loop, with its lookups bound once. A periodic release stays
        at the top of the heap while it runs and is replaced there by its next one (one sift
        instead of a pop and a push); were it no longer on top (its task pushed an earlier
        release), it is taken out where it is."""
        clock = self.clock
        heap = self._heap
        tasks = self._tasks
        pop, replace, wait = heapq.heappop, heapq.heapreplace, clock.wait_until
        seq = self._seq
        now = None  # the release time waited for last: the tasks due with it need no wait
        while heap and heap[0][0] < end_ns:
            item = heap[0]
            due, priority, _, idx = item
            fn, stats, period, _ = tasks[idx]
            if due != now:
                wait(due)
                now = due
            self._seq = seq  # a task that pushes (chain, at) numbers on from here
            fn(due)
            seq = self._seq
            if period is None:
                nxt = None
            else:
                seq += 1
                nxt = (due + period, priority, seq, idx)
            if heap[0] is not item:
                self._take(item, nxt)
            elif nxt is None:
                pop(heap)
            else:
                replace(heap, nxt)
            stats.runs += 1
            if self._stopped:
                self._seq = seq
                return clock.now_ns()
        self._seq = seq
        clock.wait_until(end_ns)
        return clock.now_ns()

    def _take(self, item: tuple[int, int, int, int], nxt: tuple[int, int, int, int] | None
              ) -> None:
        """Take `item` off the heap where a push moved it (not the top), pushing `nxt`."""
        heap = self._heap
        heap.remove(item)
        heapq.heapify(heap)
        if nxt is not None:
            heapq.heappush(heap, nxt)

    def run_until(self, end_ns: int) -> int:
        """Run every release due before end_ns (exclusive); return the clock time at exit."""
        clock = self.clock
        heap = self._heap
        realtime = clock.realtime
        self._stopped = False
        if self._skips_ahead:
            self._count_skips_ahead(end_ns)
        if not realtime:
            return self._run_simulated(end_ns)
        while heap and heap[0][0] < end_ns and not self._stopped:
            due, priority, _, idx = heapq.heappop(heap)
            fn, stats, period, _ = self._tasks[idx]
            clock.wait_until(due)
            if realtime:
                late = clock.now_ns() - due
                stats.max_lateness_ns = max(stats.max_lateness_ns, late)
                if self._record_lateness:
                    stats.lateness_ns.append(late)
            fn(due)
            stats.runs += 1
            if period is not None:
                nxt = due + period
                if realtime:
                    if late > period:
                        stats.caught_up += 1
                    now = clock.now_ns()
                    if now > nxt:
                        stats.overruns += late <= period  # once per stall, not per catch-up
                        window = self._catch_up.get(idx, 0)
                        # skip what is older than the window (all of it without one)
                        missed = max(0, (now - window - nxt) // period + 1) if window \
                            else (now - nxt) // period + 1
                        inside = min(missed, max(0, -((nxt - end_ns) // period)))
                        stats.skipped += inside
                        if missed > inside:
                            self._skips_ahead[idx] = (nxt + inside * period, period,
                                                      missed - inside)
                        nxt += missed * period
                self._push(nxt, priority, idx)
        if not self._stopped:
            clock.wait_until(end_ns)
        return clock.now_ns()
