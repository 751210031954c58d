"""Fixed-size histograms of durations for long-running live processes.

One bin per microsecond up to a limit (default 20 ms) plus an overflow count and the exact
maximum: recording is two list increments, memory never grows, and percentiles are exact to 1 us
below the limit (above it they are reported as the maximum, an upper bound). A second level of
100 us bins keeps a percentile query at a few hundred steps, cheap enough for a live status line.
"""

from __future__ import annotations

from typing import Any

NS_PER_US = 1_000
COARSE_US = 100


class DurationHistogram:
    """Counts of durations in 1 us bins; record() takes nanoseconds."""

    def __init__(self, limit_us: int = 20_000) -> None:
        if limit_us <= 0:
            raise ValueError(f"histogram limit must be positive, got {limit_us} us")
        self.limit_us = limit_us
        self._bins = [0] * limit_us
        self._coarse = [0] * (limit_us // COARSE_US + 1)
        self.count = 0
        self.overflow = 0
        self.negative = 0  # values below 0 (clock offsets between hosts), counted in bin 0
        self.max_ns = 0
        self._sum_ns = 0

    def record(self, ns: int) -> None:
        self.count += 1
        if ns < 0:
            self.negative += 1
            ns = 0
        self._sum_ns += ns
        self.max_ns = max(self.max_ns, ns)
        us = ns // NS_PER_US
        if us < self.limit_us:
            self._bins[us] += 1
            self._coarse[us // COARSE_US] += 1
        else:
            self.overflow += 1

    def percentile_us(self, q: float) -> float | None:
        """Upper edge of the bin holding the q-quantile (0 < q <= 1), in us; None when empty."""
        if self.count == 0:
            return None
        if not 0.0 < q <= 1.0:
            raise ValueError(f"quantile must be in (0, 1], got {q}")
        rank = max(1, int(-(-q * self.count // 1)))  # ceil(q * n): the rank-th smallest value
        max_us = self.max_ns / NS_PER_US
        seen = 0
        for block, n in enumerate(self._coarse):
            if seen + n >= rank:
                first = block * COARSE_US
                for us in range(first, min(first + COARSE_US, self.limit_us)):
                    seen += self._bins[us]
                    if seen >= rank:
                        return min(float(us + 1), max_us)
            seen += n
        return max_us

    def fraction_above_us(self, limit_us: float) -> float:
        """Share of values at or above limit_us (resolution 1 us)."""
        if self.count == 0:
            return 0.0
        first = int(limit_us)
        above = sum(self._bins[first:]) + self.overflow if first < self.limit_us else self.overflow
        return above / self.count

    def summary(self) -> dict[str, Any]:
        """count, mean, p50, p90, p99, p99.9 and max in us (None when nothing was recorded)."""
        empty = self.count == 0
        return {
            "count": self.count,
            "mean_us": None if empty else round(self._sum_ns / self.count / NS_PER_US, 1),
            "p50_us": self.percentile_us(0.5),
            "p90_us": self.percentile_us(0.9),
            "p99_us": self.percentile_us(0.99),
            "p999_us": self.percentile_us(0.999),
            "max_us": None if empty else round(self.max_ns / NS_PER_US, 1),
            "over_limit": self.overflow,
            "negative": self.negative,
        }


class RunningStats:
    """Mean, standard deviation and RMS of a stream (Welford), constant memory."""

    def __init__(self) -> None:
        self.n = 0
        self._mean = 0.0
        self._m2 = 0.0
        self._sq = 0.0

    def add(self, x: float) -> None:
        self.n += 1
        d = x - self._mean
        self._mean += d / self.n
        self._m2 += d * (x - self._mean)
        self._sq += x * x

    def summary(self) -> dict[str, Any]:
        if self.n == 0:
            return {"n": 0, "mean": None, "std": None, "rms": None}
        return {"n": self.n, "mean": round(self._mean, 4),
                "std": round((self._m2 / self.n) ** 0.5, 4), "rms": round((self._sq / self.n) ** 0.5, 4)}
