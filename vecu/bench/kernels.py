"""Compiled kernels (numba) against the plain Python/numpy backend, measured in the same run.

For each backend: the whole simulated `vecu run` (default configuration: all plant parts and
all four estimators, TPS killed half way) in x real time, the ECU alone fed captured plant
frames (vecu.bench.ecu) in us per 1 ms tick, and the production throttle particle filter
alone (vecu.bench.pipeline.throttle_estimator_alone_us) in us per tick. Runs alternate between the backends and the best of
`repeats` is kept (the machine is noisy; alternation keeps drift out of the ratio). The first
numba run in a process also reports how long the kernels took to load or compile.
"""

from __future__ import annotations

from typing import Any

from vecu import kernels
from vecu.bench.ecu import TARGET_ECU_US
from vecu.bench.pipeline import (
    TARGET_PF_US,
    TARGET_RUN_X,
    pf_alone_seconds,
    throttle_estimator_alone_us,
)
from vecu.clock import perf_s

BACKEND_ORDER = ("python", "numba")


def _whole_run(duration_s: float) -> float:
    from vecu.runner import RunConfig, run

    cfg = RunConfig(duration_s=duration_s, kill_tps_at_s=duration_s / 2, seed=0)
    return float(run(cfg).report.x_realtime or 0.0)


def bench_kernels(duration_s: float = 5.0, repeats: int = 2) -> dict[str, Any]:
    """x real time (whole run) and ECU us/tick under each backend; {} notes if numba is absent."""
    if not kernels.numba_available():
        return {"numba": False, "note": "numba not installed (pip install 'vecu[fast]')"}
    from vecu.bench.ecu import capture_plant_frames, run_ecu

    with kernels.using("python"):  # the backend active before comes back afterwards
        frames = capture_plant_frames(duration_s)
        kernels.set_backend("numba")
        t0 = perf_s()
        run_ecu(frames[:200])  # loads (or compiles) every kernel the ECU uses
        _whole_run(0.2)  # and the plant's
        warm_s = perf_s() - t0
        best_run: dict[str, float] = {}
        best_ecu: dict[str, float] = {}
        best_pf: dict[str, float] = {}
        pf_s = pf_alone_seconds(duration_s)  # the pipeline group's trace
        for _ in range(repeats):
            for name in BACKEND_ORDER:
                kernels.set_backend(name)
                best_run[name] = max(best_run.get(name, 0.0), _whole_run(duration_s))
                us = run_ecu(frames)["us_per_tick"]
                best_ecu[name] = min(best_ecu.get(name, float("inf")), us)
                pf = throttle_estimator_alone_us(pf_s)
                best_pf[name] = min(best_pf.get(name, float("inf")), pf)
    return {
        "numba": True,
        "sim_s": duration_s,
        "first_use_s": round(warm_s, 2),
        "run_x_realtime": {k: round(v, 2) for k, v in best_run.items()},
        "run_ratio": round(best_run["numba"] / best_run["python"], 2),
        "ecu_us_per_tick": {k: round(v, 1) for k, v in best_ecu.items()},
        "ecu_x_realtime": {k: round(1000.0 / v, 2) for k, v in best_ecu.items()},
        "ecu_ratio": round(best_ecu["python"] / best_ecu["numba"], 2),
        "pf_us_per_tick": {k: round(v, 2) for k, v in best_pf.items()},
        "pf_ratio": round(best_pf["python"] / best_pf["numba"], 2),
        "target_pf_us_per_tick": TARGET_PF_US,
        "target_run_x_realtime": TARGET_RUN_X["numba"],
        "target_ecu_us_per_tick": TARGET_ECU_US,
    }


def format_kernels(r: dict[str, Any]) -> str:
    if not r.get("numba"):
        return f"Compiled kernels: skipped, {r.get('note', 'numba not available')}"
    run, ecu, pf = r["run_x_realtime"], r["ecu_us_per_tick"], r["pf_us_per_tick"]
    return (f"Compiled kernels (numba) vs the Python/numpy backend, {r['sim_s']} s simulated, "
            f"same run (kernels loaded in {r['first_use_s']} s):\n"
            f"  vecu run, all four estimators: {run['numba']}x real time vs {run['python']}x "
            f"({r['run_ratio']}x; target >= {r['target_run_x_realtime']:.0f}x real time: "
            f"{_met(run['numba'] >= r['target_run_x_realtime'])})\n"
            f"  ECU alone: {ecu['numba']} us/tick vs {ecu['python']} us/tick "
            f"({r['ecu_ratio']}x; {r['ecu_x_realtime']['numba']}x real time, target <= "
            f"{r['target_ecu_us_per_tick']:.0f} us/tick: "
            f"{_met(ecu['numba'] <= r['target_ecu_us_per_tick'])})\n"
            f"  throttle particle filter alone: {pf['numba']} us/tick vs {pf['python']} us/tick "
            f"({r['pf_ratio']}x; target <= {r['target_pf_us_per_tick']:.0f} us/tick: "
            f"{_met(pf['numba'] <= r['target_pf_us_per_tick'])})")


def _met(ok: bool) -> str:
    return "met" if ok else "not met"
