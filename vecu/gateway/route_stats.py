"""Per-route figures of the routing engine, as gateway analysers report them: frames in / out /
dropped by reason, signal values saturated, latency min / mean / p99 / max (from a frame's
arrival at the gateway to the frame that carries it leaving, on the caller's clock) and the
peak of the route's queue."""

from __future__ import annotations

from collections import Counter
from typing import Any

from vecu.stats import NS_PER_US, DurationHistogram

LATENCY_LIMIT_US = 1_000_000  # 1 s of 1 us bins: beyond it a latency counts as over_limit


class RouteStats:
    """Counters and latency of one route (or the firewall's drops under one deny rule)."""

    def __init__(self) -> None:
        self.frames_in = 0
        self.frames_out = 0
        self.dropped: Counter[str] = Counter()   # reason -> frames
        self.saturated: Counter[str] = Counter()  # target signal -> values clipped to its range
        self.timeouts = 0                         # a source falling silent (each onset once)
        self.queue_peak = 0
        self.latency = DurationHistogram(LATENCY_LIMIT_US)
        self.min_latency_ns: int | None = None

    def drop(self, reason: str, n: int = 1) -> None:
        self.dropped[reason] += n

    def queued(self, depth: int) -> None:
        self.queue_peak = max(self.queue_peak, depth)

    def sent(self, latency_ns: int | None) -> None:
        """One frame out; latency_ns: the oldest input it carries waited this long (None: a
        cyclic repeat carrying nothing new)."""
        self.frames_out += 1
        if latency_ns is not None:
            self.latency.record(latency_ns)
            if self.min_latency_ns is None or latency_ns < self.min_latency_ns:
                self.min_latency_ns = latency_ns

    def summary(self) -> dict[str, Any]:
        lat = self.latency.summary()
        return {"in": self.frames_in, "out": self.frames_out,
                "dropped": dict(sorted(self.dropped.items())),
                "saturated": dict(sorted(self.saturated.items())),
                "timeouts": self.timeouts, "queue_peak": self.queue_peak,
                "latency_us": {"count": lat["count"],
                               "min": None if self.min_latency_ns is None
                               else round(self.min_latency_ns / NS_PER_US, 1),
                               "mean": lat["mean_us"], "p99": lat["p99_us"], "max": lat["max_us"]}}
