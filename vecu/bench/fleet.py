"""Fleet replay speed, measured in one run: N recorded drives replayed with `--diff` one by one in
this process (the fleet's own per-trace task, `vecu.fleet.task.replay_trace`) against the fleet
on a LocalCluster of `workers` processes (`vecu replay DIR --workers N --diff`, the cluster's
start and its workers' kernel loading included); the two must give the same rows and the same
output traces, byte for byte.

The drives are recorded first, as `vecu run --duration S --seed i --log DRIVE.log` records them
(vecu.runner.run with that RunConfig), on the same kind of cluster (not timed)."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

from vecu.clock import perf_s

TARGET_RATIO = 1.7  # on 2 workers (issue: fleet replay)


def record_drive(path: str, duration_s: float, seed: int) -> dict[str, Any]:
    """`vecu run --duration S --seed SEED --log PATH` (the TPS dies at half the duration)."""
    from vecu.config import RunConfig
    from vecu.runner import run

    run(RunConfig(duration_s=duration_s, seed=seed, kill_tps_at_s=duration_s / 2,
                  log_path=path))
    return {"trace": path, "status": "ok"}


def bench_fleet(drives: int = 20, duration_s: float = 60.0, workers: int = 2) -> dict[str, Any]:
    from vecu.campaign.cluster import format_row, run_rows
    from vecu.fleet.diff import DiffSpec
    from vecu.fleet.engine import run_fleet
    from vecu.fleet.task import COLUMNS, FleetConfig, outputs, replay_trace
    from vecu.fleet.traces import trace_names
    from vecu.replay.engine import ReplayConfig

    with tempfile.TemporaryDirectory(prefix="vecu-bench-fleet-") as tmp:
        d = Path(tmp)
        (d / "drives").mkdir()
        paths = [str(d / "drives" / f"drive{i:02d}.log") for i in range(drives)]
        lost: list[str] = []
        t0 = perf_s()
        def failed(item: tuple[Any, ...], exc: BaseException) -> dict[str, Any]:
            lost.append(f"{item[0]}: {exc}")
            return {}

        run_rows(record_drive, [(p, duration_s, i + 1) for i, p in enumerate(paths)],
                 [f"vecu-bench-record-{i}" for i in range(drives)], lambda row: None, failed,
                 workers)
        record_s = perf_s() - t0
        if lost:
            raise RuntimeError(f"recording failed: {lost[0]}")
        fleet = FleetConfig(ReplayConfig(trace=""), "log", DiffSpec())
        names = trace_names(paths)
        # one-time loading (kernels, codecs, imports) out of the timed loop, as in a replay
        replay_trace(fleet, paths[0], "warm-up", str(d / "warm"))
        serial = d / "serial"
        t0 = perf_s()
        rows = [replay_trace(fleet, p, n, str(serial)) for p, n in zip(paths, names)]
        serial_s = perf_s() - t0
        t0 = perf_s()
        res = run_fleet(paths, fleet, d / "fleet", workers=workers)
        fleet_s = perf_s() - t0
        table = (d / "fleet" / "runs.csv").read_text().split("\n", 1)[1]
        same_rows = "".join(format_row(COLUMNS, r) for r in rows) == table
        same_out = all(outputs(serial, n, "log")["out"].read_bytes()
                       == outputs(d / "fleet", n, "log")["out"].read_bytes() for n in names)
        trace_s = sum(float(r["trace_duration_s"] or 0.0) for r in rows)
        return {"name": "fleet replay with --diff", "drives": drives, "duration_s": duration_s,
                "workers": workers, "record_s": round(record_s, 2),
                "serial_s": round(serial_s, 2), "fleet_s": round(fleet_s, 2),
                "ratio": round(serial_s / fleet_s, 2),
                "serial_x_realtime": round(trace_s / serial_s, 1),
                "fleet_x_realtime": round(trace_s / fleet_s, 1),
                "identical_rows": same_rows, "identical_outputs": same_out,
                "verdicts": res.summary["verdicts"], "errors": res.errors,
                "target_ratio": TARGET_RATIO}


def format_fleet(r: dict[str, Any]) -> str:
    ok = r["ratio"] >= r["target_ratio"]
    return (f"Fleet replay ({r['drives']} drives of {r['duration_s']:g} s, --diff, recorded in "
            f"{r['record_s']:.0f} s):\n"
            f"  one by one in one process {r['serial_s']:.1f} s ({r['serial_x_realtime']:.1f}x "
            f"real time), --workers {r['workers']} {r['fleet_s']:.1f} s incl. cluster start "
            f"({r['fleet_x_realtime']:.1f}x): ratio {r['ratio']:.2f} (target >= "
            f"{r['target_ratio']:g} on 2 cores: {'met' if ok else 'not met'})\n"
            f"  results identical: rows {r['identical_rows']}, output traces "
            f"{r['identical_outputs']}; verdicts {r['verdicts']}, errors {r['errors']}")
