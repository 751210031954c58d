"""`vecu bench`: speed benchmarks, each printed as a ratio against a baseline from the same run."""

from __future__ import annotations

import argparse
import json
import platform
from typing import Any

from vecu import argtypes


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="run the speed benchmarks (ratios against same-run baselines)",
                       description="Benchmarks: paper UKF step (fast vs straightforward numpy), "
                                   "virtual bus (vecu vs python-can), whole pipeline x real time.")
    p.add_argument("--quick", action="store_true",
                   help="the smallest sizes (seconds per group; noisy figures, a smoke test)")
    p.add_argument("--only", type=_groups, metavar="GROUP[,GROUP…]",
                   help=f"run these benchmark groups only ({', '.join(GROUPS)})")
    p.add_argument("--live-seconds", type=argtypes.bounded(0.5, 3600.0), default=None, metavar="S",
                   help="live group: seconds of the plant + ECU processes run (default 10, "
                        "--quick 1; 0.5..3600; target: 60)")
    p.add_argument("--memory-minutes", type=argtypes.bounded(0.05, 600.0), default=None, metavar="M",
                   help="live group: simulated minutes of the memory-flatness run (default 10, "
                        "--quick 0.25; 0.05..600; target: 60)")
    p.add_argument("--replay-seconds", type=argtypes.bounded(1.0, 3600.0), default=None, metavar="S",
                   help="replay group: length of the recorded drive replayed (default 60, "
                        "--quick 4; 1..3600)")
    p.add_argument("--estimator", default="production",
                   help="ECU estimator for the pipeline run (default production; try arm)")
    p.add_argument("--json", action="store_true", help="print JSON instead of tables")
    p.set_defaults(func=main)


GROUPS = ("campaign", "ukf", "bus", "pipeline", "live", "replay", "ecu", "breakdown", "kernels",
          "uds", "restbus", "xcp", "gateway", "fleet")


_groups = argtypes.name_list(GROUPS)  # --only: one group or several, comma-separated (pipeline,replay)


# group sizes: (full, --quick); --quick keeps every group to a few seconds (tests/bench/test_smoke)
SIZES: dict[str, tuple[Any, Any]] = {
    "ukf_steps": (20_000, 2_000), "ukf_repeats": (5, 2), "filter_steps": (5_000, 1_000),
    "manifold_s": (80.0, 3.0), "production_steps": (20_000, 2_000), "smoother_steps": (2_000, 300),
    "manifold_fn_s": (40.0, 3.0), "bus_frames": (20_000, 5_000), "pipeline_s": (10.0, 1.0),
    "ecu_s": (10.0, 1.0), "breakdown_s": (5.0, 1.0), "kernels_s": (5.0, 1.0),
    "replay_s": (60.0, 4.0), "replay_live_s": (10.0, 1.5), "live_s": (10.0, 1.0),
    "memory_min": (10.0, 0.25), "throughput_s": (5.0, 1.0), "campaign_runs": (60, 4),
    "campaign_s": (80.0, 2.0), "campaign_baseline_runs": (3, 1),
    "run_backends_s": (60.0, 1.0), "scenario_limit": (0, 1),  # 0: every shipped scenario
    "log_memory_s": ((60.0, 300.0), (0.5, 1.0)),
    "uds_requests": (200, 20), "restbus_s": (10.0, 1.0),
    "xcp_commands": (200, 20), "xcp_daq_s": (5.0, 0.5),
    "gateway_requests": (300, 40), "gateway_s": (3.0, 1.0),
    "routing_frames": (20_000, 2_000), "routing_latency_frames": (1_000, 200),
    "fleet_drives": (20, 3), "fleet_s": (60.0, 3.0),
}


def collect(quick: bool, only: str | frozenset[str] | None, estimator: str,
            live_seconds: float | None = None, memory_minutes: float | None = None,
            replay_seconds: float | None = None) -> dict[str, Any]:
    from vecu import kernels
    from vecu.bench.estimators import (
        bench_manifold,
        bench_speed_and_steering,
        bench_throttle_ukf,
    )
    from vecu.bench.pipeline import bench_pipeline, bench_virtual_bus

    groups = frozenset([only]) if isinstance(only, str) else only

    def want(group: str) -> bool:
        return groups is None or group in groups

    def size(name: str, given: float | None = None) -> Any:
        return given if given is not None else SIZES[name][1 if quick else 0]

    out: dict[str, Any] = {"python": platform.python_version(), "machine": platform.machine(),
                           "kernel_backend": kernels.backend(), "quick": quick}
    if want("ukf"):
        out["ukf"] = bench_throttle_ukf(steps=int(size("ukf_steps")),
                                        repeats=int(size("ukf_repeats")))
        out["filters"] = bench_speed_and_steering(steps=int(size("filter_steps")))
        out["manifold"] = bench_manifold(duration_s=size("manifold_s"))
        from vecu.bench.estimators import (
            bench_manifold_function,
            bench_steering_smoother,
            bench_throttle_production,
        )
        out["estimators"] = [  # the four ECU estimators against straightforward numpy versions
            bench_throttle_production(steps=int(size("production_steps"))),
            out["filters"][0],
            bench_steering_smoother(steps=int(size("smoother_steps"))),
            bench_manifold_function(duration_s=size("manifold_fn_s"))]
    if want("bus"):
        out["bus"] = bench_virtual_bus(frames=int(size("bus_frames")))
    if want("pipeline"):
        out["pipeline"] = bench_pipeline(duration_s=size("pipeline_s"), estimator=estimator)
        from vecu.bench.pipeline import bench_run_backends, bench_scenarios
        out["run_backends"] = bench_run_backends(duration_s=size("run_backends_s"))
        out["scenarios"] = bench_scenarios(limit=int(size("scenario_limit")) or None)
        from vecu.bench.pipeline import bench_log_memory
        out["log_memory"] = bench_log_memory(tuple(SIZES["log_memory_s"][1 if quick else 0]))
    if want("ecu"):
        from vecu.bench.ecu import bench_ecu
        out["ecu"] = bench_ecu(duration_s=size("ecu_s"))
    if want("breakdown"):
        from vecu.bench.breakdown import breakdown
        out["breakdown"] = breakdown(duration_s=size("breakdown_s"))
    if want("kernels"):
        from vecu.bench.kernels import bench_kernels
        out["kernels"] = bench_kernels(duration_s=size("kernels_s"))
    if want("replay"):
        from vecu.bench.replay import bench_replay
        out["replay"] = bench_replay(size("replay_s", replay_seconds), size("replay_live_s"),
                                     estimator)
    if want("uds"):
        from vecu.bench.uds import bench_uds
        out["uds"] = bench_uds(requests=int(size("uds_requests")))
    if want("restbus"):
        from vecu.bench.restbus import bench_restbus
        out["restbus"] = bench_restbus(size("restbus_s"))
    if groups is not None and "campaign" in groups:  # minutes at full size: only when asked for
        from vecu.bench.campaign import bench_campaign
        out["campaign"] = bench_campaign(runs=int(size("campaign_runs")),
                                         duration_s=size("campaign_s"),
                                         baseline_runs=int(size("campaign_baseline_runs")))
    if groups is not None and "fleet" in groups:  # minutes at full size: only when asked for
        from vecu.bench.fleet import bench_fleet
        out["fleet"] = bench_fleet(drives=int(size("fleet_drives")), duration_s=size("fleet_s"))
    if groups is not None and "xcp" in groups:  # needs pyxcp (vecu[test]): only when asked for
        from vecu.bench.xcp import bench_xcp
        out["xcp"] = bench_xcp(commands=int(size("xcp_commands")), daq_s=size("xcp_daq_s"))
    if groups is not None and "gateway" in groups:  # live processes in a namespace: when asked
        from vecu.bench.gateway import bench_gateway
        from vecu.bench.routing import bench_routing
        out["gateway"] = bench_gateway(requests=int(size("gateway_requests")),
                                       seconds=size("gateway_s"))
        out["gateway"]["routing"] = bench_routing(int(size("routing_frames")),
                                                  int(size("routing_latency_frames")))
    if want("live"):
        from vecu.bench.live import bench_live
        out["live"] = bench_live(size("live_s", live_seconds), size("memory_min", memory_minutes),
                                 size("throughput_s"))
    return out


def main(args: argparse.Namespace) -> int:
    res = collect(args.quick, args.only, args.estimator, args.live_seconds, args.memory_minutes,
                  args.replay_seconds)
    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    if "ukf" in res:
        print("Paper UKF step (n = 3, scalar y): plain-Python vs straightforward numpy baseline")
        print(f"  {'set':<6}{'points':>7}{'vecu us':>10}{'numpy us':>10}{'speedup':>9}  target <= 10 us, >= 10x")
        for r in res["ukf"]:
            print(f"  {r['sigma_set']:<6}{r['points']:>7}{r['fast_us']:>10.2f}{r['numpy_us']:>10.1f}"
                  f"{r['ratio']:>8.1f}x")
    if "filters" in res:
        print("Speed and steering filters (same-run baselines):")
        for r in res["filters"]:
            print(f"  {r['filter']:<28}{r['us']:>7.1f} us  vs {r['baseline']} {r['baseline_us']:.1f} us "
                  f"({r['ratio']:.1f}x), budget {r['budget_us']:.0f} us")
    if "manifold" in res:
        print("Manifold filters per engine event (same-run baseline: SDKF solving the DARE every event):")
        for r in res["manifold"]:
            print(f"  {r['filter']:<8}{r['us_per_event']:>8.0f} us  vs {r['baseline_us']:.0f} us "
                  f"({r['ratio']:.1f}x), budget {r['budget_us']:.0f} us, {r['events']} events")
    if "estimators" in res:
        print("ECU estimators, us per step (per engine event for the manifold) vs straightforward numpy:")
        for r in res["estimators"]:
            print(f"  {r['filter']:<40}{r['us']:>8.1f} us  vs {r['baseline']} {r['baseline_us']:.1f} us "
                  f"({r['ratio']:.1f}x)")
    if "bus" in res:
        b = res["bus"]
        print(f"Virtual bus send+recv: vecu {b['vecu_us']} us vs python-can VirtualBus "
              f"{b['baseline_us']} us ({b['speedup']}x)")
    if "pipeline" in res:
        target = res["pipeline"][0]["target_x_realtime"] if res["pipeline"] else 0.0
        print(f"Whole pipeline, simulated clock (plant + injector + ECU + probe), "
              f"target >= {target:g}x:")
        for r in res["pipeline"]:
            print(f"  {r['name']:<32} {r['x_realtime']:>7.1f}x real time  ({r['us_per_tick']} us/tick: "
                  f"estimator {r['estimator_us_per_tick']}, CAN/bus/scheduler {r['rest_us_per_tick']})")
    if "run_backends" in res:
        from vecu.bench.pipeline import format_targets
        print(format_targets(res["run_backends"], res.get("scenarios", {})))
    if "log_memory" in res:
        from vecu.bench.pipeline import format_log_memory
        print(format_log_memory(res["log_memory"]))
    if "ecu" in res:
        from vecu.bench.ecu import format_ecu
        print(format_ecu(res["ecu"]))
    if "breakdown" in res:
        from vecu.bench.breakdown import format_breakdown
        print(format_breakdown(res["breakdown"]))
    if "kernels" in res:
        from vecu.bench.kernels import format_kernels
        print(format_kernels(res["kernels"]))
    if "replay" in res:
        from vecu.bench.replay import format_replay
        print(format_replay(res["replay"]))
    if "uds" in res:
        from vecu.bench.uds import format_uds
        print(format_uds(res["uds"]))
    if "restbus" in res:
        from vecu.bench.restbus import format_restbus
        print(format_restbus(res["restbus"]))
    if "xcp" in res:
        from vecu.bench.xcp import format_xcp
        print(format_xcp(res["xcp"]))
    if "gateway" in res:
        from vecu.bench.gateway import format_gateway
        from vecu.bench.routing import format_routing
        print(format_gateway(res["gateway"]))
        print(format_routing(res["gateway"]["routing"]))
    if "campaign" in res:
        from vecu.bench.campaign import format_campaign
        print(format_campaign(res["campaign"]))
    if "fleet" in res:
        from vecu.bench.fleet import format_fleet
        print(format_fleet(res["fleet"]))
    if "live" in res:
        from vecu.bench.live import format_live
        print(format_live(res["live"]))
    return 0
