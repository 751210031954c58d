"""Benchmarks of the bus and of the whole `vecu run` pipeline, as ratios measured in one run."""

from __future__ import annotations

import json
import logging
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
    from vecu import kernels, runner
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
            res = runner.run(cfg, make_estimator=make)  # the seam: a timed estimator
            wall = res.report.wall_time_s  # the run loop (kernel loading not counted)
            est = timed[-1]
            per_tick = wall / res.report.ticks * 1e6
            est_us = est.seconds / max(est.steps, 1) * 1e6
            rows.append({"name": f"vecu run pipeline ({label})", "estimator": estimator,
                         "sim_s": duration_s, "wall_s": round(wall, 3),
                         "x_realtime": round(duration_s / wall, 2),
                         "us_per_tick": round(per_tick, 1),
                         "estimator_us_per_tick": round(est_us, 1),
                         "rest_us_per_tick": round(per_tick - est_us, 1),
                         "target_x_realtime": TARGET_RUN_X[kernels.backend()]})
    return rows


# targets (vecu bench --only pipeline,replay): numba as issue 32 restated issue 16's 50x, python
# issue 16's; "before": the same figures measured on the 2-core machine before the work on
# issue 16 (docs/performance.md), for the scenarios' ratio
TARGET_RUN_X = {"numba": 25.0, "python": 20.0}
TARGET_PF_US = 4.0  # the throttle estimator alone, us per 1 ms tick (issue 32)
PF_ALONE_S = 20.0  # its simulated trace (seed 7, alpha 1) in every group that measures it
SCENARIOS_BEFORE_S = {"numba": 7.03, "python": 5.94}  # 17 scenarios, wall s (performance.md)
TARGET_SCENARIOS_SPEEDUP = 3.0


def bench_run_backends(duration_s: float = 60.0) -> list[dict[str, Any]]:
    """`vecu run --duration S` (default configuration, TPS killed half way) under each kernel
    backend available, in this run: x real time against the target (numba: `vecu[fast]`)."""
    from vecu import kernels
    from vecu.runner import RunConfig, load_kernels, run

    names = ("numba", "python") if kernels.numba_available() else ("python",)
    rows = []
    for name in names:
        with kernels.using(name):
            load_kernels()  # compiling or loading the kernels is not the run's speed
            cfg = RunConfig(duration_s=duration_s, kill_tps_at_s=duration_s / 2)
            s = run(cfg).report
            alone_us = throttle_estimator_alone_us(pf_alone_seconds(duration_s))
        rows.append({"name": f"vecu run --duration {duration_s:g}", "kernels": name,
                     "wall_s": s.wall_time_s, "x_realtime": s.x_realtime,
                     "target_x_realtime": TARGET_RUN_X[name],
                     "met": bool(s.x_realtime and s.x_realtime >= TARGET_RUN_X[name]),
                     "throttle_estimator_alone_us_per_tick": round(alone_us, 1),
                     "target_throttle_estimator_us_per_tick": TARGET_PF_US,
                     "ceiling_x_realtime": round(1000.0 / alone_us, 1),
                     "budget_left_us_per_tick": round(1000.0 / TARGET_RUN_X[name] - alone_us, 1)})
    return rows


def pf_alone_seconds(group_s: float) -> float:
    """The trace length for throttle_estimator_alone_us in a group sized group_s: PF_ALONE_S
    (the same figure in the pipeline, kernels and replay groups), 5 s in --quick runs."""
    return PF_ALONE_S if group_s >= 5.0 else 5.0


def throttle_estimator_alone_us(duration_s: float, seed: int = 7) -> float:
    """us per 1 ms tick of the ECU's default throttle estimator (production particle filter)
    stepped alone, in a tight loop, over a simulated wattmeter trace: the floor under any
    pipeline that runs it every tick (1000 / it is the most x real time such a pipeline can
    reach, whatever the rest costs)."""
    from vecu.estimators.registry import make_throttle_estimator
    from vecu.plant.throttle import simulate

    steps = int(duration_s * 1000)
    trace = simulate(steps, seed=seed)
    u, y = trace.u.tolist(), trace.y.tolist()
    est = make_throttle_estimator("production")
    est.step(0.0, y[0])
    watch = Stopwatch()
    for k in range(1, steps):
        est.step(u[k - 1], y[k])
    return watch.elapsed() / (steps - 1) * 1e6


def shipped_scenarios() -> list[Path]:
    """The scenario files shipped with vecu (`vecu scenario list`), by name."""
    from vecu.shipped import shipped_files

    return list(shipped_files("scenario").values())


def bench_scenarios(limit: int | None = None) -> dict[str, Any]:
    """The shipped scenarios one after another in this process (as `vecu scenario run
    $(vecu scenario list --names)`): total wall time and verdicts; `limit` runs only the first ones."""
    from vecu import kernels
    from vecu.scenario.batch import run_scenarios
    from vecu.scenario.loader import load_scenario

    files = shipped_scenarios()[:limit]
    if not files:
        return {"scenarios": 0, "note": "no shipped scenarios (vecu/data/scenarios/ missing)"}
    scenarios = [load_scenario(f) for f in files]
    from vecu.runner import load_kernels
    load_kernels()
    quiet = logging.getLogger("vecu")  # the scenarios' rx warnings, as `vecu scenario run`
    level = quiet.level
    quiet.setLevel(logging.ERROR)
    try:
        watch = Stopwatch()
        outcomes = run_scenarios(scenarios, stream=None, progress=False)
        wall = watch.elapsed()
    finally:
        quiet.setLevel(level)
    backend = kernels.backend()
    before = SCENARIOS_BEFORE_S.get(backend, 0.0) if limit is None else 0.0
    return {"scenarios": len(outcomes), "kernels": backend, "wall_s": round(wall, 2),
            "sim_s": round(sum(o.sim_s for o in outcomes), 3),
            "verdicts": {o.name: ("PASS" if o.passed else "FAIL") for o in outcomes},
            "before_wall_s": before or None,
            "speedup": round(before / wall, 2) if before else None,
            "target_speedup": TARGET_SCENARIOS_SPEEDUP}


def format_targets(runs: list[dict[str, Any]], sc: dict[str, Any]) -> str:
    lines = ["Offline speed targets (same run):"]
    for r in runs:
        lines.append(f"  {r['name']} ({r['kernels']} kernels): {r['x_realtime']}x real time "
                     f"(target >= {r['target_x_realtime']:.0f}x: {'met' if r['met'] else 'not met'})")
        if "ceiling_x_realtime" in r:
            pf_us = r["throttle_estimator_alone_us_per_tick"]
            pf_ok = "met" if pf_us <= r["target_throttle_estimator_us_per_tick"] else "not met"
            lines.append(f"    its throttle estimator alone: {pf_us} us/tick (target <= "
                         f"{r['target_throttle_estimator_us_per_tick']:g} us: {pf_ok})"
                         f" -> no pipeline running it beats {r['ceiling_x_realtime']}x; "
                         f"the target leaves {r['budget_left_us_per_tick']} us/tick for the rest")
    if sc.get("scenarios"):
        passed = sum(v == "PASS" for v in sc["verdicts"].values())
        ratio = (f", {sc['speedup']}x faster than before ({sc['before_wall_s']} s; target >= "
                 f"{sc['target_speedup']:.0f}x)" if sc["speedup"] else "")
        lines.append(f"  {sc['scenarios']} shipped scenarios ({sc['kernels']} kernels): "
                     f"{sc['wall_s']} s wall, {passed} passed{ratio}")
    return "\n".join(lines)


_LOGGED_RUN = """
import json, resource, sys
from vecu.runner import RunConfig, run
d = float(sys.argv[1])
s = run(RunConfig(duration_s=d, kill_tps_at_s=d / 2, log_path=sys.argv[2])).summary
print(json.dumps([resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, s["frames"]["logged"]]))
"""


def bench_log_memory(durations_s: tuple[float, ...] = (60.0, 300.0)) -> list[dict[str, Any]]:
    """Peak RSS of `vecu run --duration S --log x.log` (truth frames), each in a fresh process:
    a log that streams keeps the peak flat as S grows (issue 16; 3600 for the 1 h figure)."""
    import subprocess
    import sys

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for d in durations_s:
            log = str(Path(tmp) / "run.log")
            res = subprocess.run([sys.executable, "-c", _LOGGED_RUN, str(d), log],
                                 capture_output=True, text=True, check=True)
            rss, frames = json.loads(res.stdout.strip().splitlines()[-1])
            rows.append({"sim_s": d, "peak_rss_kb": rss, "frames_logged": frames,
                         "log_bytes": Path(log).stat().st_size})
    return rows


def format_log_memory(rows: list[dict[str, Any]]) -> str:
    parts = [f"{r['sim_s']:g} s: {r['peak_rss_kb']} kB ({r['frames_logged']} frames, "
             f"{r['log_bytes'] / 1e6:.1f} MB)" for r in rows]
    return "  peak RSS of `vecu run --log x.log`, fresh process each: " + "; ".join(parts)
