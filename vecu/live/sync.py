"""Put the ECU's 1 ms grid just after the sensor frames' arrival (frame-synchronous schedule).

The plant sends ETB_Wattmeter every 1 ms on its own clock. If the ECU's tick fell just before
each arrival, every frame would wait almost a whole period in the receive queue. Before its clock
starts, the ECU listens to the trigger frames, finds their arrival phase within the period
(circular mean, robust to wrap-around), takes the late edge of the spread (a quantile of the
deviations) and starts its grid `margin` after it. Done once at start-up: both processes pace
on the same monotonic clock, so the phase holds; a plant restarted later costs up to one period
of latency, which the frame-in -> estimate-out figures show.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from vecu.clock import NS_PER_MS, NS_PER_S, perf_ns, wall_time_ns
from vecu.live.livebus import LiveBus

PERIOD_NS = NS_PER_MS


@dataclass(frozen=True)
class PhaseSync:
    """Result of the start-up listen; start_at_perf_ns is None when no trigger frames came."""

    frames: int
    phase_us: float | None          # circular mean arrival phase in the period
    late_edge_us: float | None      # quantile of the deviations after the mean
    margin_us: float
    start_at_perf_ns: int | None
    discarded: int = 0  # all frames read (and dropped) while listening, trigger frames included

    def as_dict(self) -> dict[str, object]:
        return {"frames": self.frames, "phase_us": self.phase_us, "late_edge_us": self.late_edge_us,
                "margin_us": self.margin_us, "synced": self.start_at_perf_ns is not None,
                "discarded_frames": self.discarded}


def arrival_phase(arrivals_ns: list[int], period_ns: int = PERIOD_NS,
                  quantile: float = 0.95) -> tuple[float, float]:
    """(mean phase, late edge) in ns of arrival times on a period grid; the late edge is the
    quantile of the deviations from the circular mean (deviations wrapped to +-period/2)."""
    if not arrivals_ns:
        raise ValueError("no arrivals")
    two_pi = 2.0 * math.pi
    s = sum(math.sin(two_pi * (t % period_ns) / period_ns) for t in arrivals_ns)
    c = sum(math.cos(two_pi * (t % period_ns) / period_ns) for t in arrivals_ns)
    mean = (math.atan2(s, c) / two_pi * period_ns) % period_ns
    half = period_ns / 2
    devs = sorted(((t % period_ns) - mean + half) % period_ns - half for t in arrivals_ns)
    k = min(len(devs) - 1, max(0, math.ceil(quantile * len(devs)) - 1))
    return mean, devs[k]


def start_instant(mean_ns: float, late_edge_ns: float, margin_ns: float, now_perf_ns: int,
                  lead_ns: int, period_ns: int = PERIOD_NS) -> int:
    """First perf_counter instant at least lead_ns after now whose phase is mean + late edge +
    margin (capped at 0.9 period after the mean)."""
    offset = min(max(late_edge_ns, 0.0) + margin_ns, 0.9 * period_ns)
    target_phase = int(mean_ns + offset) % period_ns
    earliest = now_perf_ns + lead_ns
    return earliest + (target_phase - earliest) % period_ns


def _clock_offset_ns() -> int:
    """wall_time_ns() - perf_ns(), the narrowest of a few paired reads."""
    best = None
    for _ in range(5):
        a = perf_ns()
        w = wall_time_ns()
        b = perf_ns()
        if best is None or b - a < best[0]:
            best = (b - a, w - (a + b) // 2)
    return best[1]


def sync_to_trigger(bus: LiveBus, trigger: tuple[int, bool], frames: int = 100,
                    timeout_s: float = 10.0, margin_us: float = 150.0,
                    arrival_timestamps: bool = True, stop=lambda: False) -> PhaseSync:
    """Listen for up to `frames` trigger frames (other frames are read and dropped) for at most
    timeout_s of wall time; return where to start the 1 ms grid. Frames read here are counted by
    the LiveBus like any other."""
    offset = _clock_offset_ns()
    arrivals: list[int] = []
    read = 0
    deadline = perf_ns() + int(timeout_s * NS_PER_S)
    while len(arrivals) < frames and not stop():
        left = deadline - perf_ns()
        if left <= 0:
            break
        msg = bus.recv(min(left / NS_PER_S, 0.05))
        if msg is None:
            continue
        read += 1
        if (msg.arbitration_id, msg.is_extended_id) != trigger:
            continue
        if arrival_timestamps:
            arrivals.append(int(msg.timestamp * NS_PER_S) - offset)
        else:
            arrivals.append(perf_ns())
    if len(arrivals) < max(10, frames // 10):
        return PhaseSync(len(arrivals), None, None, margin_us, None, read)
    mean, late = arrival_phase(arrivals)
    start = start_instant(mean, late, margin_us * 1000, perf_ns(), lead_ns=2 * PERIOD_NS)
    return PhaseSync(len(arrivals), round(mean / 1000, 1), round(late / 1000, 1), margin_us, start,
                     read)
