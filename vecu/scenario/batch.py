"""Run scenarios on the simulated clock (serially or in worker processes) and judge them."""

from __future__ import annotations

import multiprocessing
import sys
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import TextIO

from vecu.clock import perf_s, process_s
from vecu.live.children import die_with_parent
from vecu.runner import load_kernels, run
from vecu.scenario.criteria import ScenarioOutcome, evaluate
from vecu.scenario.loader import Scenario

PROGRESS_INTERVAL_S = 2.0  # wall seconds between a running scenario's progress lines


class Progress:
    """A running scenario's progress on `stream`, paced by wall time: a line once `interval_s`
    has passed since the start or the last line (whatever the run's length), and a last line at
    the end when any came before; a scenario done within `interval_s` prints none. Called by
    vecu.runner.run after each simulated second."""

    def __init__(self, name: str, stream: TextIO, interval_s: float = PROGRESS_INTERVAL_S,
                 now: Callable[[], float] = perf_s) -> None:
        self.name = name
        self.stream = stream
        self.interval_s = interval_s
        self._now = now
        self._start = self._last = now()
        self.lines = 0

    def __call__(self, t_s: float, duration_s: float) -> None:
        now = self._now()
        if now - self._last < self.interval_s and not (t_s >= duration_s and self.lines):
            return
        self._last = now
        self.lines += 1
        print(f"  {self.name}: {t_s:.0f}/{duration_s:.0f} s simulated "
              f"({100.0 * t_s / duration_s:.0f} %, {now - self._start:.0f} s wall)",
              file=self.stream, flush=True)


def run_scenario(scenario: Scenario, report_dir: str | None = None,
                 stream: TextIO | None = None,
                 progress_interval_s: float = PROGRESS_INTERVAL_S) -> ScenarioOutcome:
    """One scenario: run, evaluate criteria, plot into report_dir (when given); progress lines
    on `stream` (when given) every progress_interval_s of wall time."""
    wall0 = perf_s()
    cpu0 = process_s()
    progress = None if stream is None else Progress(scenario.name, stream, progress_interval_s)
    try:
        if scenario.gateway is not None:  # [gateway]: its routes beside plant and ECU
            from vecu.gateway.sim import run_with_gateway
            result = run_with_gateway(scenario.config, scenario.gateway, progress,
                                      scenario.route_faults)
        else:
            result = run(scenario.config, progress=progress)
        cpu = process_s() - cpu0
        criteria = tuple(evaluate(scenario, result))
        plot = None
        if report_dir is not None and result.throttle_series is not None:
            from vecu.scenario.report import plot_file_name, plot_scenario
            plot = str(Path(report_dir) / plot_file_name(scenario.name))
            plot_scenario(scenario, result, plot)
    except Exception as exc:  # noqa: BLE001 - a crash is a failed scenario, reported, not a traceback
        return ScenarioOutcome(scenario.name, scenario.path, scenario.description, False, (),
                               scenario.config.duration_s, perf_s() - wall0, 0.0,
                               error=f"{type(exc).__name__}: {exc}")
    s = result.report
    return ScenarioOutcome(
        scenario.name, scenario.path, scenario.description, all(c.passed for c in criteria),
        criteria, s.sim_time_s, perf_s() - wall0, s.x_realtime or 0.0,
        round(s.sim_time_s / cpu, 2) if cpu > 0 else 0.0, plot,
        diagnostics=s.diagnostics, fault_events=tuple(s.fault_events))


def _worker(args: tuple[Scenario, str | None, bool, float]) -> ScenarioOutcome:
    scenario, report_dir, progress, interval_s = args
    return run_scenario(scenario, report_dir, sys.stderr if progress else None, interval_s)


def run_scenarios(scenarios: list[Scenario], jobs: int = 1, report_dir: str | None = None,
                  stream: TextIO | None = sys.stderr, progress: TextIO | bool | None = True,
                  progress_interval_s: float = PROGRESS_INTERVAL_S) -> list[ScenarioOutcome]:
    """All scenarios, in input order; jobs > 1 runs each in its own worker process (same
    results as serial: every run is seeded and independent; a worker dies with this process).

    stream: one result line per scenario (None: none). progress: where a running scenario's
    progress lines go every progress_interval_s of wall time: True follows `stream`, a stream
    of its own (e.g. stderr under --quiet on a terminal), False / None: nowhere. Worker
    processes write theirs to their stderr."""
    target = stream if progress is True else (progress or None)
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
            outcomes.append(run_scenario(sc, report_dir, target, progress_interval_s))
            report(i, outcomes[-1])
        return outcomes
    methods = multiprocessing.get_all_start_methods()
    ctx = multiprocessing.get_context("fork" if "fork" in methods else "spawn")
    work = [(sc, report_dir, target is not None, progress_interval_s) for sc in scenarios]
    # each worker dies with this process: a SIGTERM here must not leave a day-long run behind
    with ProcessPoolExecutor(max_workers=min(jobs, total), mp_context=ctx,
                             initializer=die_with_parent) as pool:
        for i, outcome in enumerate(pool.map(_worker, work), 1):
            outcomes.append(outcome)
            report(i, outcome)
    return outcomes
