"""Where a simulated `vecu run` spends its time: microseconds per 1 ms tick by component.

`python -m vecu.bench.breakdown [seconds]` runs the default configuration (every function,
all plant parts, TPS killed half way) on the simulated clock twice: once plain (the real
x-real-time) and once under cProfile (nothing is patched). A component's row is its exclusive
time: its cumulative time less the time of the components it calls, directly or through other
functions (a part's tick does not include the frame encoding and bus send it calls, which are
their own rows; time reached through a non-component function is split as that function's
profile splits it). The profiler costs time on every call, so the instrumented total is larger
than the plain one; the rows are for proportions, the plain run for the speed.
"""

from __future__ import annotations

import cProfile
import importlib
import pstats
import sys
from typing import Any

from vecu.clock import Stopwatch

# (module, class or None for a module function, attribute, row label): the harness's own; each
# ECU function brings its parts' rows (EcuFunctionSpec.profile)
COMPONENTS: tuple[tuple[str, str | None, str, str], ...] = (
    ("vecu.plant.node", "PlantNode", "tick", "plant: node tick (FI poll, part dispatch)"),
    ("vecu.codec", "FrameCodec", "frame", "codec: encode + can.Message"),
    ("vecu.codec", "FrameCodec", "decode", "codec: decode"),
    ("vecu.bus", "BusNode", "send", "bus: send"),
    ("vecu.bus", "FastVirtualBus", "recv", "bus: recv (poll)"),
    ("vecu.bus", "LaneBus", "recv", "bus: recv (poll)"),  # simulated runs: the in-process lane
    ("vecu.ecu.node", "EcuNode", "tick", "ecu: node tick (dispatch, status)"),
    ("vecu.ecu.node", "EcuNode", "receive", "ecu: receive + validate"),
    ("vecu.ecu.sensor_monitor", "SensorMonitor", "select", "ecu: sensor monitors"),
)


# generated code (no class attribute to look up): (the file name's prefix, the function's name)
# -> row label; each message's source (vecu.codec.source) is one file "<vecu codec NAME>"
GENERATED: tuple[tuple[str, str, str], ...] = (
    ("<vecu codec ", "frame", "codec: encode + can.Message"),
    ("<vecu codec ", "bad_values", "codec: range check"),
    ("<vecu codec ", "decode_checked", "codec: decode + range check (receive)"),
)

FuncKey = tuple[str, int, str]  # pstats' (file, first line, name)


def _component_keys() -> dict[FuncKey, str]:
    """The profiler's key of each component's function -> its row label."""
    from vecu import functions

    keys: dict[FuncKey, str] = {}
    for mod_name, cls_name, attr, label in (*COMPONENTS,
                                            *(row for s in functions.specs() for row in s.profile)):
        owner = importlib.import_module(mod_name)
        if cls_name is not None:
            owner = getattr(owner, cls_name)
        code = getattr(getattr(owner, attr), "__code__", None)
        if code is not None:  # a compiled kernel has none: it is not profiled on its own
            keys[(code.co_filename, code.co_firstlineno, code.co_name)] = label
    return keys


def exclusive_times(stats: dict[FuncKey, tuple], components: dict[FuncKey, str]
                    ) -> tuple[dict[str, float], dict[str, int]]:
    """(seconds, calls) per label from pstats' raw stats {func: (cc, nc, tt, ct, callers)}.

    share(f) = fraction of f's cumulative time spent inside components (1 for a component);
    a component's exclusive time = its cumulative time - sum over its callees g of
    (time of the calls to g from it) * share(g).
    """
    callees: dict[FuncKey, list[tuple[FuncKey, float]]] = {}
    for func, (_, _, _, _, callers) in stats.items():
        for caller, edge in callers.items():
            callees.setdefault(caller, []).append((func, edge[3]))
    share: dict[FuncKey, float] = {}

    def share_of(func: FuncKey, active: set[FuncKey]) -> float:
        if func in components:
            return 1.0
        if func in share:
            return share[func]
        ct = stats[func][3] if func in stats else 0.0
        if ct <= 0.0 or func in active:
            return 0.0
        active.add(func)
        inside = sum(t * share_of(g, active) for g, t in callees.get(func, ()))
        active.discard(func)
        share[func] = min(inside / ct, 1.0)
        return share[func]

    excl: dict[str, float] = {label: 0.0 for label in components.values()}
    calls: dict[str, int] = {label: 0 for label in components.values()}
    for func, label in components.items():
        if func not in stats:
            continue
        _, nc, _, ct, _ = stats[func]
        nested = sum(t * share_of(g, set()) for g, t in callees.get(func, ()) if g != func)
        excl[label] += max(ct - nested, 0.0)
        calls[label] += nc
    return excl, calls


def breakdown(duration_s: float = 5.0, seed: int = 0) -> dict[str, Any]:
    """Plain and instrumented run of the default configuration; us per tick by component."""
    from vecu.runner import RunConfig, run

    cfg = RunConfig(duration_s=duration_s, kill_tps_at_s=duration_s / 2, seed=seed)
    run(RunConfig(duration_s=0.2, kill_tps_at_s=0.1, seed=seed))  # first use: imports, compiled-kernel loading
    plain = run(cfg).summary
    profiler = cProfile.Profile()
    watch = Stopwatch()
    profiler.enable()
    try:
        inst = run(cfg).summary
    finally:
        profiler.disable()
    wall_inst = watch.elapsed()
    stats = pstats.Stats(profiler).stats  # type: ignore[attr-defined]  # pstats' stats dict is not in typeshed
    keys = _component_keys()
    keys.update({func: label for func in stats for prefix, name, label in GENERATED
                 if func[0].startswith(prefix) and func[2] == name})
    excl, calls = exclusive_times(stats, keys)
    ticks = plain["ticks"]
    rows: dict[str, dict[str, float]] = {}
    for label, sec in excl.items():
        rows[label] = {"us_per_tick": sec / ticks * 1e6, "calls_per_tick": calls[label] / ticks}
    timed = sum(excl.values())
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
