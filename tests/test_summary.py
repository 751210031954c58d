"""The typed summaries' one JSON path (vecu.summary.to_json): the JSON a user sees keeps its
keys, their order and values; typed fields and their JSON agree."""

from __future__ import annotations

import json
from dataclasses import dataclass, field

from vecu.runner import RunConfig, run
from vecu.summary import FLATTEN, OMIT_NONE, to_json

RUN_KEYS = ["config", "ticks", "overruns", "tasks", "sim_time_s", "wall_time_s", "x_realtime",
            "kernels", "throttle", "frames", "fault_events", "kernel_load_s", "bus",
            "diagnostics", "uds", "xcp", "speed", "manifold", "steering"]
THROTTLE_KEYS = ["estimator", "estimator_resets", "estimator_faults", "kill_time_s", "detected",
                 "detection_time_s", "detection_latency_ms", "detected_as", "false_alarm", "dtc",
                 "fault", "final_status", "final_source", "nan_outputs", "missing_broadcasts",
                 "before_kill", "after_kill"]


@dataclass(frozen=True)
class _Inner:
    a: int
    b: tuple[int, ...]


@dataclass(frozen=True)
class _Outer:
    inner: _Inner = field(metadata=FLATTEN)
    gone: int | None = field(default=None, metadata=OMIT_NONE)
    kept: int | None = None


def test_to_json_flattens_omits_and_keeps_tuples():
    assert to_json(_Outer(_Inner(1, (2, 3)))) == {"a": 1, "b": (2, 3), "kept": None}
    assert to_json(_Outer(_Inner(1, ()), gone=4)) == {"a": 1, "b": (), "gone": 4, "kept": None}


def test_run_summary_json_has_todays_keys_in_order_and_matches_the_typed_fields():
    result = run(RunConfig(duration_s=1.2, seed=5, kill_tps_at_s=0.6, kill_swa_at_s=0.7))
    s, r = result.summary, result.report
    assert list(s) == RUN_KEYS
    assert list(s["throttle"]) == THROTTLE_KEYS
    assert s["throttle"]["detected"] is r.throttle.detection.detected is True
    assert s["throttle"]["after_kill"]["broadcast_error_deg"]["rms"] == \
        r.throttle.after_kill.broadcast_error_deg.rms
    assert s["steering"]["kill_time_s"] == r.functions["steering"].detection.kill_time_s == 0.7
    assert s["frames"]["sent"] == r.frames.plant_sent + r.frames.ecu_sent
    json.dumps(s)  # JSON-ready as it is
