"""Campaign speed: the manifold Table 3 campaign on Dask against the same runs one after the
other in this process (what repeating `vecu eval manifold` would cost), measured in one run."""

from __future__ import annotations

import os
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any

from vecu.clock import perf_s

TABLE3 = Path(__file__).resolve().parents[2] / "campaigns" / "manifold-table3.toml"


def bench_campaign(runs: int = 8, duration_s: float = 80.0, workers: int | None = None,
                   spec_path: Path = TABLE3) -> dict[str, Any]:
    from vecu.campaign.draws import load_campaign
    from vecu.campaign.engine import run_campaign
    from vecu.campaign.studies import run_one

    spec = load_campaign(str(spec_path))
    spec = replace(spec, runs=runs, run={**spec.run, "duration_s": duration_s})
    run_one(spec, 0)  # imports and compiled kernels loaded before timing
    t0 = perf_s()
    for i in range(runs):
        run_one(spec, i)
    sequential = perf_s() - t0
    n = workers or os.cpu_count() or 1
    with tempfile.TemporaryDirectory() as tmp:
        t0 = perf_s()
        res = run_campaign(spec, Path(tmp) / "out", workers=n)
        dask_s = perf_s() - t0
    return {"name": "manifold Table 3 campaign", "runs": runs, "duration_s": duration_s,
            "workers": n, "sequential_s": round(sequential, 2), "campaign_s": round(dask_s, 2),
            "speedup": round(sequential / dask_s, 2), "s_per_run_sequential":
            round(sequential / runs, 3), "failed": res.failed, "target_speedup": 20.0}


def format_campaign(r: dict[str, Any]) -> str:
    return (f"Campaign ({r['name']}, {r['runs']} runs of {r['duration_s']:g} s, "
            f"{r['workers']} Dask workers incl. cluster start):\n"
            f"  sequential {r['sequential_s']:.1f} s ({r['s_per_run_sequential']:.2f} s/run), "
            f"campaign {r['campaign_s']:.1f} s: {r['speedup']:.2f}x  (target >= "
            f"{r['target_speedup']:g}x: {'met' if r['speedup'] >= r['target_speedup'] else 'not met'})")
