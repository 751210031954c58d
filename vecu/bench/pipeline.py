"""Benchmarks of the bus and of the whole `vecu run` pipeline, as ratios measured in one run."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import can

from vecu.bus import open_baseline_virtual_bus, open_bus
from vecu.clock import Stopwatch


def bench_virtual_bus(frames: int = 20_000) -> dict[str, Any]:
    """send + recv of one 8-byte frame: vecu's FastVirtualBus against python-can's VirtualBus."""
    out: dict[str, Any] = {"name": "virtual bus send+recv", "frames": frames}
    for label, factory in (("baseline_us", open_baseline_virtual_bus),
                           ("vecu_us", lambda ch: open_bus(channel=ch))):
        tx, rx = factory(f"bench-{label}"), factory(f"bench-{label}")
        try:
            msg = can.Message(arbitration_id=0x100, data=bytes(8), is_extended_id=False)
            watch = Stopwatch()
            for _ in range(frames):
                tx.send(msg)
                rx.recv(0.0)
            out[label] = round(watch.elapsed() / frames * 1e6, 2)
        finally:
            tx.shutdown()
            rx.shutdown()
    out["speedup"] = round(out["baseline_us"] / out["vecu_us"], 2)
    return out


class _TimedEstimator:
    """Wraps an estimator to time its step() inside the running pipeline."""

    def __init__(self, inner: Any) -> None:
        self._inner = inner
        self._watch = Stopwatch()
        self.seconds = 0.0
        self.steps = 0

    def step(self, u_prev: float, y: float | None) -> None:
        self._watch.lap()
        self._inner.step(u_prev, y)
        self.seconds += self._watch.lap()
        self.steps += 1

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)


def bench_pipeline(duration_s: float = 10.0, estimator: str = "production") -> list[dict[str, Any]]:
    """Simulated-time `vecu run` (TPS killed half way) as x real time, without and with a log.

    Each row also gives the estimator's own us per step measured inside the same run, so the
    pipeline's cost splits into estimator and everything else (CAN encode/decode, bus, scheduler).
    """
    from vecu import runner
    from vecu.estimators.registry import make_throttle_estimator

    timed: list[_TimedEstimator] = []

    def make(name: str, noise_scale: float = 1.0, model: Any = None) -> Any:
        est = _TimedEstimator(make_throttle_estimator(name, noise_scale, model))
        timed.append(est)
        return est

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for label, log in (("no log", None), ("with .log", str(Path(tmp) / "run.log")),
                           ("with .blf", str(Path(tmp) / "run.blf"))):
            cfg = runner.RunConfig(duration_s=duration_s, kill_tps_at_s=duration_s / 2,
                                   log_path=log).with_params(estimator=estimator)
            watch = Stopwatch()
            res = runner.run(cfg, make_estimator=make)  # the seam: a timed estimator
            wall = watch.elapsed()
            est = timed[-1]
            per_tick = wall / res.summary["ticks"] * 1e6
            est_us = est.seconds / max(est.steps, 1) * 1e6
            rows.append({"name": f"vecu run pipeline ({label})", "estimator": estimator,
                         "sim_s": duration_s, "wall_s": round(wall, 3),
                         "x_realtime": round(duration_s / wall, 2),
                         "us_per_tick": round(per_tick, 1),
                         "estimator_us_per_tick": round(est_us, 1),
                         "rest_us_per_tick": round(per_tick - est_us, 1),
                         "target_x_realtime": 20.0})
    return rows
