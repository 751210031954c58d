"""Run scenarios on the simulated clock (serially or in worker processes) and judge them."""

from __future__ import annotations

import multiprocessing
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import TextIO

from vecu.clock import perf_s, process_s
from vecu.runner import load_kernels, run
from vecu.scenario.criteria import ScenarioOutcome, evaluate
from vecu.scenario.loader import Scenario

LONG_RUN_S = 30.0  # simulated seconds from which a scenario reports its own progress


def run_scenario(scenario: Scenario, report_dir: str | None = None,
                 stream: TextIO | None = None) -> ScenarioOutcome:
    """One scenario: run, evaluate criteria, plot into report_dir (when given)."""
    wall0 = perf_s()
    cpu0 = process_s()
    progress = None
    if stream is not None and scenario.config.duration_s >= LONG_RUN_S:
        step = max(1.0, round(scenario.config.duration_s / 10.0))

        def progress(t_s: float, dur: float) -> None:
            if t_s % step < 1e-9 or t_s >= dur:
                print(f"  {scenario.name}: {t_s:.0f}/{dur:.0f} s simulated "
                      f"({perf_s() - wall0:.0f} s wall)", file=stream, flush=True)
    try:
        result = run(scenario.config, progress=progress)
        cpu = process_s() - cpu0
        criteria = tuple(evaluate(scenario, result))
        plot = None
        if report_dir is not None and result.throttle_series is not None:
            from vecu.scenario.report import plot_scenario
            plot = str(Path(report_dir) / f"{scenario.name}.png")
            plot_scenario(scenario, result, plot)
    except Exception as exc:  # noqa: BLE001 - a crash is a failed scenario, reported, not a traceback
        return ScenarioOutcome(scenario.name, scenario.path, scenario.description, False, (),
                               scenario.config.duration_s, perf_s() - wall0, 0.0,
                               error=f"{type(exc).__name__}: {exc}")
    s = result.summary
    return ScenarioOutcome(
        scenario.name, scenario.path, scenario.description, all(c.passed for c in criteria),
        criteria, s["sim_time_s"], perf_s() - wall0, s["x_realtime"] or 0.0,
        round(s["sim_time_s"] / cpu, 2) if cpu > 0 else 0.0, plot,
        diagnostics=s["diagnostics"], fault_events=tuple(s["fault_events"]))


def _worker(args: tuple[Scenario, str | None]) -> ScenarioOutcome:
    return run_scenario(args[0], args[1], stream=sys.stderr)


def run_scenarios(scenarios: list[Scenario], jobs: int = 1, report_dir: str | None = None,
                  stream: TextIO | None = sys.stderr) -> list[ScenarioOutcome]:
    """All scenarios, in input order; jobs > 1 runs each in its own worker process (same
    results as serial: every run is seeded and independent)."""
    total = len(scenarios)
    outcomes: list[ScenarioOutcome] = []
    load_kernels()  # once, before the first timed run (forked workers inherit them)

    def report(i: int, o: ScenarioOutcome) -> None:
        if stream is not None:
            verdict = "PASS" if o.passed else ("ERROR" if o.error else "FAIL")
            print(f"[{i}/{total}] {o.name}: {verdict} ({o.sim_s:g} s simulated, "
                  f"{o.x_realtime:.1f}x real time, {o.x_realtime_cpu:.1f}x per CPU second, "
                  f"{o.wall_s:.1f} s wall)"
                  + (f" - {o.error}" if o.error else ""), file=stream, flush=True)
            for c in o.failures:
                print(f"    failed: {c.name}: {c.measured} (limit {c.limit})", file=stream)

    if jobs <= 1 or total <= 1:
        for i, sc in enumerate(scenarios, 1):
            outcomes.append(run_scenario(sc, report_dir, stream))
            report(i, outcomes[-1])
        return outcomes
    methods = multiprocessing.get_all_start_methods()
    ctx = multiprocessing.get_context("fork" if "fork" in methods else "spawn")
    with ProcessPoolExecutor(max_workers=min(jobs, total), mp_context=ctx) as pool:
        for i, outcome in enumerate(pool.map(_worker, [(sc, report_dir) for sc in scenarios]), 1):
            outcomes.append(outcome)
            report(i, outcome)
    return outcomes
