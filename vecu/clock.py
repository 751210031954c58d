"""One clock abstraction for the whole run: simulated (as fast as possible) or wall time.

Time is an integer count of nanoseconds since the start of the run, so periodic deadlines never
accumulate floating-point drift. Nothing else in vecu reads the system time or sleeps.
"""

from __future__ import annotations

import time
from typing import Callable, Protocol

NS_PER_S = 1_000_000_000
NS_PER_MS = 1_000_000


class Clock(Protocol):
    """Time source and deadline waiter shared by the scheduler and every node."""

    realtime: bool

    def now_ns(self) -> int:
        """Nanoseconds since the start of the run."""
        ...

    def wait_until(self, deadline_ns: int) -> None:
        """Return at (wall) or jump to (simulated) the absolute deadline; never earlier."""
        ...

    def start(self) -> None:
        """Make 'now' the start of the run (t = 0); call right before the first deadline."""
        ...


class SimClock:
    """Deterministic simulated time: wait_until jumps forward, never backwards."""

    realtime = False

    def __init__(self, start_ns: int = 0) -> None:
        self._now = start_ns
        self._start = start_ns

    def start(self) -> None:
        self._now = self._start

    def now_ns(self) -> int:
        return self._now

    def wait_until(self, deadline_ns: int) -> None:
        if deadline_ns > self._now:
            self._now = deadline_ns


class WallClock:
    """Wall time paced on absolute deadlines (monotonic), with a short final spin for precision.

    `sleep` and `monotonic_ns` are injectable so tests can drive the pacing logic deterministically.
    """

    realtime = True

    def __init__(
        self,
        spin_ns: int = 500_000,
        sleep: Callable[[float], None] = time.sleep,
        monotonic_ns: Callable[[], int] = time.perf_counter_ns,
    ) -> None:
        self._sleep = sleep
        self._mono = monotonic_ns
        self._spin_ns = spin_ns
        self._t0 = monotonic_ns()

    def start(self) -> None:
        self._t0 = self._mono()

    def sibling(self, spin_ns: int) -> WallClock:
        """A clock on the same time origin with another final spin, for a second thread
        (spin_ns=0 sleeps the whole wait and so leaves the GIL to the other thread)."""
        twin = WallClock(spin_ns, self._sleep, self._mono)
        twin._t0 = self._t0
        return twin

    def now_ns(self) -> int:
        return self._mono() - self._t0

    def wait_until(self, deadline_ns: int) -> None:
        remaining = deadline_ns - self.now_ns()
        if remaining > self._spin_ns:
            self._sleep((remaining - self._spin_ns) / NS_PER_S)
        while self.now_ns() < deadline_ns:
            pass


def seconds(t_ns: int) -> float:
    return t_ns / NS_PER_S
