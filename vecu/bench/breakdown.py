"""Where a simulated `vecu run` spends its time: microseconds per 1 ms tick by component.

`python -m vecu.bench.breakdown [seconds]` runs the default configuration (all four estimators,
all plant parts, TPS killed half way) on the simulated clock twice: once plain (the real
x-real-time) and once with timers around the components (exclusive times: a part's tick does
not include the frame encoding and bus send it calls, which are their own rows). The timers
cost ~0.5 us per timed call, so the instrumented total is larger than the plain one; the rows
are for proportions, the plain run for the speed.
"""

from __future__ import annotations

import importlib
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

# (module, class or None for a module function, attribute, row label)
COMPONENTS: tuple[tuple[str, str | None, str, str], ...] = (
    ("vecu.plant.node", "PlantNode", "tick", "plant: node tick (FI poll, part dispatch)"),
    ("vecu.plant.node", "ThrottlePart", "tick", "plant: throttle part"),
    ("vecu.plant.throttle", "ThrottlePlant", "step", "plant: throttle model step"),
    ("vecu.plant.throttle", "InputGenerator", "next", "plant: throttle input generator"),
    ("vecu.plant.node", "LongitudinalPart", "tick", "plant: longitudinal part"),
    ("vecu.plant.node", "LateralPart", "tick", "plant: lateral part"),
    ("vecu.plant.node", "ManifoldPart", "event", "plant: manifold part (event)"),
    ("vecu.plant.manifold", "ManifoldPlant", "step", "plant: manifold model step"),
    ("vecu.codec", "FrameCodec", "frame", "codec: encode + can.Message"),
    ("vecu.codec", "FrameCodec", "decode", "codec: decode"),
    ("vecu.codec", "FrameCodec", "crc_ok", "codec: E2E CRC check"),
    ("vecu.codec", "FrameCodec", "bad_values", "codec: range check"),
    ("vecu.node", "BusNode", "_send", "bus: send"),
    ("vecu.bus", "FastVirtualBus", "recv", "bus: recv (poll)"),
    ("vecu.ecu.node", "EcuNode", "tick", "ecu: node tick (dispatch, status)"),
    ("vecu.ecu.node", "EcuNode", "receive", "ecu: receive + validate"),
    ("vecu.ecu.throttle_function", "ThrottleFunction", "run", "ecu: throttle function"),
    ("vecu.estimators.throttle.production", "ThrottleParticleFilter", "step",
     "estimator: throttle production PF/KF"),
    ("vecu.ecu.speed_function", "SpeedFunction", "run", "ecu: speed function"),
    ("vecu.estimators.speed.kf", "SpeedKalmanFilter", "step", "estimator: speed KF"),
    ("vecu.ecu.steering_function", "SteeringFunction", "run", "ecu: steering function"),
    ("vecu.estimators.steering.smoothers", "FixedLagSmoother", "step",
     "estimator: steering smoother (w/o UKF)"),
    ("vecu.estimators.steering.filters", "_SteeringFilter", "step", "estimator: steering UKF"),
    ("vecu.ecu.manifold_function", "ManifoldFunction", "run", "ecu: manifold function"),
    ("vecu.estimators.manifold.filters", "_ManifoldKF", "step", "estimator: manifold SDKF"),
    ("vecu.ecu.manifold_function", None, "predict_cac", "estimator: manifold CAC prediction"),
    ("vecu.ecu.sensor_monitor", "SensorMonitor", "select", "ecu: sensor monitors"),
    ("vecu.probes", "ThrottleProbe", "tick", "probes"),
    ("vecu.probes", "SpeedProbe", "tick", "probes"),
    ("vecu.probes", "SteeringProbe", "tick", "probes"),
    ("vecu.probes", "ManifoldProbe", "tick", "probes"),
)


class _Timers:
    def __init__(self) -> None:
        self.excl: dict[str, float] = {}
        self.calls: dict[str, int] = {}
        self._stack: list[float] = []

    def wrap(self, fn: Any, label: str) -> Any:
        perf = time.perf_counter
        stack = self._stack
        excl, calls = self.excl, self.calls
        excl.setdefault(label, 0.0)
        calls.setdefault(label, 0)

        def timed(*args: Any, **kwargs: Any) -> Any:
            stack.append(0.0)
            t0 = perf()
            try:
                return fn(*args, **kwargs)
            finally:
                el = perf() - t0
                child = stack.pop()
                excl[label] += el - child
                calls[label] += 1
                if stack:
                    stack[-1] += el

        return timed


@contextmanager
def _instrumented(timers: _Timers) -> Iterator[None]:
    saved = []
    try:
        for mod_name, cls_name, attr, label in COMPONENTS:
            mod = importlib.import_module(mod_name)
            owner = getattr(mod, cls_name) if cls_name else mod
            if attr not in vars(owner) and cls_name is not None:
                orig = getattr(owner, attr)  # inherited: wrap on this class, delete afterwards
                saved.append((owner, attr, None))
            else:
                orig = vars(owner)[attr]
                saved.append((owner, attr, orig))
            setattr(owner, attr, timers.wrap(orig, label))
        yield
    finally:
        for owner, attr, orig in reversed(saved):
            if orig is None:
                delattr(owner, attr)
            else:
                setattr(owner, attr, orig)


def breakdown(duration_s: float = 5.0, seed: int = 0) -> dict[str, Any]:
    """Plain and instrumented run of the default configuration; us per tick by component."""
    from vecu.runner import RunConfig, run

    cfg = RunConfig(duration_s=duration_s, kill_tps_at_s=duration_s / 2, seed=seed)
    run(RunConfig(duration_s=0.2, kill_tps_at_s=0.1, seed=seed))  # first use: imports, compiled-kernel loading
    plain = run(cfg).summary
    timers = _Timers()
    with _instrumented(timers):
        t0 = time.perf_counter()
        inst = run(cfg).summary
        wall_inst = time.perf_counter() - t0
    ticks = plain["ticks"]
    rows: dict[str, dict[str, float]] = {}
    for label, sec in timers.excl.items():
        row = rows.setdefault(label, {"us_per_tick": 0.0, "calls_per_tick": 0.0})
        row["us_per_tick"] += sec / ticks * 1e6
        row["calls_per_tick"] += timers.calls[label] / ticks
    timed = sum(timers.excl.values())
    rows["scheduler, run loop and untimed glue"] = {
        "us_per_tick": (inst["wall_time_s"] - timed) / ticks * 1e6, "calls_per_tick": 0.0}
    for row in rows.values():
        row["us_per_tick"] = round(row["us_per_tick"], 2)
        row["calls_per_tick"] = round(row["calls_per_tick"], 3)
    return {
        "sim_s": duration_s,
        "ticks": ticks,
        "x_realtime": plain["x_realtime"],
        "us_per_tick": round(plain["wall_time_s"] / ticks * 1e6, 1),
        "instrumented_us_per_tick": round(inst["wall_time_s"] / ticks * 1e6, 1),
        "setup_and_summary_s": round(wall_inst - inst["wall_time_s"], 3),
        "frames_per_tick": round(plain["frames"]["sent"] / ticks, 3),
        "manifold_events": plain["manifold"]["events"],
        "components": rows,
    }


def format_breakdown(res: dict[str, Any]) -> str:
    lines = [(f"vecu run, default config, {res['sim_s']} s simulated: {res['x_realtime']}x real "
              f"time, {res['us_per_tick']} us/tick ({res['frames_per_tick']} frames/tick, "
              f"{res['manifold_events']} engine events)"),
             f"instrumented: {res['instrumented_us_per_tick']} us/tick; exclusive us per tick:"]
    for label, row in sorted(res["components"].items(), key=lambda kv: -kv[1]["us_per_tick"]):
        lines.append(f"  {label:<44}{row['us_per_tick']:>9.2f}  ({row['calls_per_tick']:.3g} "
                     "calls/tick)")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    print(format_breakdown(breakdown(float(args[0]) if args else 5.0)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
