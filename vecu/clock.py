"""One clock abstraction for the whole run: simulated (as fast as possible) or wall time.

Time is an integer count of nanoseconds since the start of the run, so periodic deadlines never
accumulate floating-point drift. Nothing else in vecu reads the system time or sleeps: live
pacing, frame timestamps and bench / eval timing use the readers and the Stopwatch below.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Protocol

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
        if deadline_ns > self._now:  # noqa: PLR1730 - every tick: a compare, not a call
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


# ---- the system's time, for the few places that need it (live pacing, frame timestamps, timing)

def perf_s() -> float:
    """High-resolution monotonic seconds (time.perf_counter): durations only."""
    return time.perf_counter()


def perf_ns() -> int:
    """High-resolution monotonic nanoseconds (time.perf_counter_ns): durations and pacing."""
    return time.perf_counter_ns()


def process_s() -> float:
    """CPU seconds of this process (time.process_time)."""
    return time.process_time()


def monotonic_ns() -> int:
    """Monotonic nanoseconds (time.monotonic_ns), e.g. for unique names and coarse deadlines."""
    return time.monotonic_ns()


def wall_time() -> float:
    """Seconds since the epoch (time.time), the base of kernel frame timestamps."""
    return time.time()


def wall_time_ns() -> int:
    """Nanoseconds since the epoch (time.time_ns)."""
    return time.time_ns()


def sleep(seconds: float) -> None:
    """Block the calling thread for `seconds` (time.sleep)."""
    time.sleep(seconds)


class Stopwatch:
    """Elapsed wall (perf_counter) and CPU (process_time) seconds since creation or restart().

    lap() returns the wall seconds since the previous lap() (or the start) and starts the next
    lap, so a caller can split one pass into timed parts. The readers are injectable.
    """

    def __init__(self, wall: Callable[[], float] = time.perf_counter,
                 cpu: Callable[[], float] = time.process_time) -> None:
        self._wall = wall
        self._cpu = cpu
        self.restart()

    def restart(self) -> None:
        self._w0 = self._lap0 = self._wall()
        self._c0 = self._cpu()

    def elapsed(self) -> float:
        """Wall seconds since the start."""
        return self._wall() - self._w0

    def cpu(self) -> float:
        """CPU seconds of this process since the start."""
        return self._cpu() - self._c0

    def lap(self) -> float:
        """Wall seconds since the previous lap (or the start); the next lap starts now."""
        now = self._wall()
        split, self._lap0 = now - self._lap0, now
        return split
