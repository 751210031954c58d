"""Campaign speed, measured in one run on this machine: the manifold Table 3 campaign (batch
engine on Dask) against the ways to get the same numbers without it:

- `vecu eval manifold`, one run per draw, one after another (the issue's baseline: what a user
  repeated before campaigns; it also solves the full DARE per event and times scipy's);
- the scalar engine: the same study stepped event by event as the ECU steps, one process;
- the batch engine in one process (runs of events per compiled call, no Dask).

Baselines are timed on `baseline_runs` runs and scaled per run; the campaign on `runs` runs
including the cluster's start. The batch engine's metrics are checked against the scalar ones
on the baseline runs (max relative difference printed)."""

from __future__ import annotations

import math
import os
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any

from vecu.clock import perf_s
from vecu.shipped import shipped_files

TABLE3 = "manifold-table3"  # shipped campaign (vecu/data/campaigns/)


def bench_campaign(runs: int = 40, duration_s: float = 80.0, workers: int | None = None,
                   baseline_runs: int = 3, spec_path: Path | None = None) -> dict[str, Any]:
    from vecu.campaign.draws import draw, load_campaign
    from vecu.campaign.engine import run_campaign
    from vecu.campaign.studies import MANIFOLD_METRICS, manifold_study
    from vecu.eval.manifold import evaluate_manifold

    spec = load_campaign(str(spec_path or shipped_files("campaign")[TABLE3]))
    stride = int(spec.run.get("stride", 1))
    spec = replace(spec, runs=runs, run={**spec.run, "duration_s": duration_s, "engine": "batch"})
    nb = max(1, min(baseline_runs, runs))
    draws = [draw(spec, i) for i in range(nb)]
    for engine in ("batch", "scalar"):  # imports and compiled kernels loaded before timing
        manifold_study(draws[0], min(duration_s, 2.0), stride, engine)
    evaluate_manifold(seed=0, runs=1, duration_s=min(duration_s, 2.0), scipy_events=5)

    t0 = perf_s()
    for i in range(nb):
        evaluate_manifold(seed=draws[i].sim_seed, runs=1, stride=stride, duration_s=duration_s)
    eval_s = (perf_s() - t0) / nb
    results: dict[str, list[dict[str, Any]]] = {}
    per_run: dict[str, float] = {}
    for engine in ("scalar", "batch"):
        t0 = perf_s()
        results[engine] = [manifold_study(d, duration_s, stride, engine) for d in draws]
        per_run[engine] = (perf_s() - t0) / nb
    rel = max(abs(b[k] - s[k]) / max(abs(s[k]), 1e-300)
              for s, b in zip(results["scalar"], results["batch"]) for k in MANIFOLD_METRICS)
    n = workers or os.cpu_count() or 1
    with tempfile.TemporaryDirectory() as tmp:
        t0 = perf_s()
        res = run_campaign(spec, Path(tmp) / "out", workers=n)
        dask_s = perf_s() - t0
    camp = dask_s / runs
    return {"name": "manifold Table 3 campaign", "runs": runs, "duration_s": duration_s,
            "stride": stride, "workers": n, "baseline_runs": nb,
            "eval_manifold_s_per_run": round(eval_s, 3),
            "scalar_s_per_run": round(per_run["scalar"], 3),
            "batch_s_per_run": round(per_run["batch"], 3),
            "campaign_s": round(dask_s, 2), "campaign_s_per_run": round(camp, 4),
            "speedup_vs_eval_manifold": round(eval_s / camp, 2),
            "speedup_vs_scalar": round(per_run["scalar"] / camp, 2),
            "batch_vs_scalar_one_process": round(per_run["scalar"] / per_run["batch"], 2),
            "batch_vs_scalar_max_rel_diff": rel if math.isfinite(rel) else None,
            "failed": res.failed, "target_speedup": 20.0}


def format_campaign(r: dict[str, Any]) -> str:
    ok = r["speedup_vs_eval_manifold"] >= r["target_speedup"]
    return (f"Campaign ({r['name']}, {r['runs']} runs of {r['duration_s']:g} s, stride "
            f"{r['stride']}, {r['workers']} Dask workers incl. cluster start; baselines on "
            f"{r['baseline_runs']} runs):\n"
            f"  vecu eval manifold {r['eval_manifold_s_per_run']:.2f} s/run, scalar engine "
            f"{r['scalar_s_per_run']:.2f} s/run, batch engine {r['batch_s_per_run']:.3f} s/run "
            f"(x{r['batch_vs_scalar_one_process']:.1f} in one process, max rel diff "
            f"{r['batch_vs_scalar_max_rel_diff']:.1e})\n"
            f"  campaign {r['campaign_s']:.1f} s = {r['campaign_s_per_run']:.3f} s/run: "
            f"{r['speedup_vs_eval_manifold']:.1f}x sequential `vecu eval manifold` (target >= "
            f"{r['target_speedup']:g}x: {'met' if ok else 'not met'}), "
            f"{r['speedup_vs_scalar']:.1f}x the scalar engine; failed runs {r['failed']}")
