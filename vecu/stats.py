"""Running statistics in constant memory (Welford), for hour-long runs."""

from __future__ import annotations

import math


class RunningStats:
    """Count, mean, standard deviation, RMS and max |x| of a stream of finite values."""

    __slots__ = ("n", "mean", "_m2", "_sumsq", "max_abs", "non_finite")

    def __init__(self) -> None:
        self.n = 0
        self.mean = 0.0
        self._m2 = 0.0
        self._sumsq = 0.0
        self.max_abs = 0.0
        self.non_finite = 0

    def add(self, x: float) -> None:
        if not math.isfinite(x):
            self.non_finite += 1
            return
        self.n += 1
        d = x - self.mean
        self.mean += d / self.n
        self._m2 += d * (x - self.mean)
        self._sumsq += x * x
        ax = -x if x < 0 else x
        if ax > self.max_abs:
            self.max_abs = ax

    @property
    def std(self) -> float:
        return math.sqrt(self._m2 / self.n) if self.n > 1 else 0.0

    @property
    def rms(self) -> float:
        return math.sqrt(self._sumsq / self.n) if self.n else 0.0

    def as_dict(self, digits: int = 4) -> dict[str, float | int]:
        return {"n": self.n, "mean": round(self.mean, digits), "std": round(self.std, digits),
                "rms": round(self.rms, digits), "max_abs": round(self.max_abs, digits),
                "non_finite": self.non_finite}


class LatencyHistogram:
    """Percentiles of a stream of non-negative durations (ns) in constant memory: 1 µs bins up to
    max_us, beyond that only counted and the maximum kept."""

    def __init__(self, max_us: int = 100_000) -> None:
        self._bins = [0] * (max_us + 1)
        self._max_us = max_us
        self.n = 0
        self.over = 0
        self.max_ns = 0
        self._sum_ns = 0

    def add(self, ns: int) -> None:
        ns = max(ns, 0)
        self.n += 1
        self._sum_ns += ns
        if ns > self.max_ns:
            self.max_ns = ns
        us = ns // 1000
        if us > self._max_us:
            self.over += 1
        else:
            self._bins[us] += 1

    def percentile_us(self, q: float) -> float | None:
        """Upper edge of the 1 µs bin holding the q-th percentile (None when empty)."""
        if self.n == 0:
            return None
        rank = q / 100.0 * self.n
        seen = 0
        for us, count in enumerate(self._bins):
            seen += count
            if count and seen >= rank:
                return float(us + 1)
        return self.max_ns / 1000.0

    def summary_ms(self) -> dict[str, float | int | None]:
        p = self.percentile_us
        to_ms = (lambda v: None if v is None else round(v / 1000.0, 3))
        return {"n": self.n, "p50": to_ms(p(50)), "p99": to_ms(p(99)),
                "max": round(self.max_ns / 1e6, 3), "mean": round(self._sum_ns / self.n / 1e6, 3)
                if self.n else None, "over_100ms": self.over}
