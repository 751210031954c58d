"""Running statistics in constant memory, for hour-long runs: Welford moments of a stream and
fixed-size histograms of durations (1 us bins up to a limit, overflow counted, exact maximum)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from vecu.kernels import kernel

NS_PER_US = 1_000
COARSE_US = 100  # second-level bins of DurationHistogram (fast percentile queries)


@dataclass(frozen=True)
class ErrorStats:
    """A finished RunningStats, rounded for a summary (JSON: the same keys, in this order)."""

    n: int
    mean: float
    std: float
    rms: float
    max_abs: float
    non_finite: int


@kernel
def welford(xs: Any, n: int, mean: float, m2: float, sumsq: float, max_abs: float,
            non_finite: int) -> tuple[int, float, float, float, float, int]:
    """RunningStats' state after the values xs in order (Welford's mean and M2, the sum of
    squares, max |x|; a non-finite value is only counted). The one copy of the update."""
    for x in xs:
        if not math.isfinite(x):
            non_finite += 1
            continue
        n += 1
        d = x - mean
        mean += d / n
        m2 += d * (x - mean)
        sumsq += x * x
        ax = -x if x < 0 else x
        if ax > max_abs:  # noqa: PLR1730 - every sample: a compare, not a call
            max_abs = ax
    return n, mean, m2, sumsq, max_abs, non_finite


class RunningStats:
    """Count, mean, standard deviation, RMS and max |x| of a stream of finite values.

    add() only keeps the value; every CHUNK values (and before any figure is read) they are
    folded into the moments in order by `welford` (vecu.kernels: compiled under numba, plain
    Python otherwise): the same numbers as folding each value as it comes, in constant memory."""

    __slots__ = ("_n", "_mean", "_m2", "_sumsq", "_max_abs", "_non_finite", "_pending")
    CHUNK = 512

    def __init__(self) -> None:
        self._n = 0
        self._mean = 0.0
        self._m2 = 0.0
        self._sumsq = 0.0
        self._max_abs = 0.0
        self._non_finite = 0
        self._pending: list[float] = []

    def add(self, x: float) -> None:
        pending = self._pending
        pending.append(x)
        if len(pending) >= self.CHUNK:
            self._fold()

    def _fold(self) -> None:
        pending = self._pending
        if not pending:
            return
        n, mean, m2, sumsq, max_abs, non_finite = welford(
            np.array(pending, dtype=np.float64), self._n, self._mean, self._m2, self._sumsq,
            self._max_abs, self._non_finite)
        # Python numbers whatever ran the fold (round() of a numpy float rounds otherwise)
        self._n, self._non_finite = int(n), int(non_finite)
        self._mean, self._m2, self._sumsq, self._max_abs = (
            float(mean), float(m2), float(sumsq), float(max_abs))
        pending.clear()

    @property
    def n(self) -> int:
        self._fold()
        return self._n

    @property
    def mean(self) -> float:
        self._fold()
        return self._mean

    @property
    def max_abs(self) -> float:
        self._fold()
        return self._max_abs

    @property
    def non_finite(self) -> int:
        self._fold()
        return self._non_finite

    @property
    def std(self) -> float:
        n = self.n
        return math.sqrt(self._m2 / n) if n > 1 else 0.0

    @property
    def rms(self) -> float:
        n = self.n
        return math.sqrt(self._sumsq / n) if n else 0.0

    def as_dict(self, digits: int = 4) -> dict[str, float | int]:
        return {"n": self.n, "mean": round(self.mean, digits), "std": round(self.std, digits),
                "rms": round(self.rms, digits), "max_abs": round(self.max_abs, digits),
                "non_finite": self.non_finite}

    def summary(self, digits: int = 4) -> ErrorStats:
        """as_dict() as a typed record."""
        return ErrorStats(self.n, round(self.mean, digits), round(self.std, digits),
                          round(self.rms, digits), round(self.max_abs, digits), self.non_finite)


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
