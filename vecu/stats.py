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
