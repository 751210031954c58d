"""What one campaign run computes, as a flat dict of metrics.

- "manifold": the estimator-level study of Dutka 2006 Section V (Table 3): the simulated engine
  and its sensors are `plant.manifold.*` (the truth, drawn per run), the filters and the 6-event
  CAC predictor believe `ecu.manifold.kf.params` (the calibration). Metrics: integrated absolute
  (iae, mg) and squared (ise, mg^2) 6-event CAC prediction error for direct (all measured),
  direct_ol (P_im and alpha measured, open-loop T), EKF and SDKF (vecu.eval.manifold); and the
  filters' consistency under the drawn calibration errors: {ekf,sdkf}_nees_{p_im,t_im}, the
  mean over events (after 0.5 s) of e^2 / sigma^2 with the reported variance
  (ManifoldFilterConfig.report_var_scale x P_post), 1 for an honest sigma (vecu eval
  consistency, docs/models.md "Consistency").
- "drive": a full simulated-bus run (plant -> frames -> ECU) with the run's fault; metrics are
  read from the run summary (vecu.runner).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from vecu.campaign.draws import RunDraw, tree_for
from vecu.campaign.spec import CampaignSpec

if TYPE_CHECKING:
    from vecu.summary import RunSummary

METHODS = ("direct_ol", "direct", "ekf", "sdkf", "adaptive")
FILTERS = ("ekf", "sdkf", "adaptive")
NEES_FILTERS = ("ekf", "sdkf")
NEES_STATES = {"p_im": 3, "t_im": 4}  # state index
NEES_BURN_IN_S = 0.5
MANIFOLD_METRICS = tuple(f"{m}_{k}" for k in ("iae", "ise") for m in METHODS) + (
    "events", "ekf_resets", "sdkf_resets", "adaptive_resets", "adaptive_eta", "true_eta") + tuple(
    f"{f}_nees_{s}" for f in NEES_FILTERS for s in NEES_STATES)
DRIVE_METRICS: dict[str, Callable[[RunSummary], Any]] = {  # metric -> its run-summary field
    "detected": lambda s: s.throttle.detection.detected,
    "detection_latency_ms": lambda s: s.throttle.detection.detection_latency_ms,
    "false_alarm": lambda s: s.throttle.detection.false_alarm,
    "after_kill_rms_deg": lambda s: s.throttle.after_kill.broadcast_error_deg.rms,
    "after_kill_max_deg": lambda s: s.throttle.after_kill.broadcast_error_deg.max_abs,
    "missing_broadcasts": lambda s: s.throttle.missing_broadcasts,
    "nan_outputs": lambda s: s.throttle.nan_outputs,
}


def metric_names(spec: CampaignSpec) -> tuple[str, ...]:
    if spec.kind == "manifold":
        return MANIFOLD_METRICS
    return spec.metrics or (*DRIVE_METRICS, "dtc_confirmations", "dtcs_per_hour")


def manifold_study(d: RunDraw, duration_s: float = 80.0, stride: int = 1,
                   engine: str = "batch") -> dict[str, Any]:
    """One Table 3 run: the plant's truth_events, the open-loop observer and all predictions
    in one kernel call each; the filters' events in runs (engine "batch": run_events) or
    event by event as the ECU steps them ("scalar": filter.step()). Same seeds, same numbers
    (tests/campaign/test_batch.py)."""
    from vecu.estimators.manifold.cac_predict import (
        CacPredictionConfig,
        prediction_errors,
    )
    from vecu.estimators.manifold.factory import make_filter
    from vecu.eval.manifold import (
        direct_ol_states,
        direct_states,
        run_filter,
        trace_input_array,
        trace_inputs,
    )
    from vecu.plant.drive_profile import DriveProfile, us06_like
    from vecu.plant.manifold import simulate

    if engine not in ("batch", "scalar"):
        raise ValueError(f"engine must be 'batch' or 'scalar', got {engine!r}")
    batch = engine == "batch"
    tree = tree_for(d)
    truth = tree.plant.manifold
    kf = tree.ecu.manifold.kf
    belief = kf.params
    prof = us06_like(d.sim_seed, params=truth.engine)
    k = round(duration_s / prof.dt_s) + 1
    prof = DriveProfile(prof.dt_s, prof.n_rpm[:k], prof.ta_sp[:k])
    trace = simulate(prof, seed=d.sim_seed, params=truth.engine, config=truth)
    # the ECU's nominal ambient and coolant conditions
    inputs = None if batch else trace_inputs(trace, belief)
    states = {"direct": direct_states(trace),
              "direct_ol": direct_ol_states(trace, inputs, belief)}
    out: dict[str, Any] = {"events": len(trace.t)}
    eta = None
    for name in FILTERS:
        if inputs is None:
            flt = make_filter(name, kf)
            states[name] = flt.run_events(trace.y, trace_input_array(trace, belief))
        else:
            states[name], _, flt = run_filter(name, trace, inputs, kf)
        out[f"{name}_resets"] = flt.resets
        if name in NEES_FILTERS:
            keep = trace.t >= NEES_BURN_IN_S
            var = kf.report_var_scale * flt.run_variances[keep]
            for st, i in NEES_STATES.items():
                e = states[name][keep, i] - trace.x[keep, i]
                out[f"{name}_nees_{st}"] = float(np.mean(e * e / var[:, i]))
        if name == "adaptive":  # the eta correction the CAC uses, per event
            eta = flt.eta_used(states[name][:, 6], flt.run_variances[:, 6])
    out["adaptive_eta"] = float(states["adaptive"][-1, 6])
    # what c should converge to: eta_N(plant) / eta_N(calibration) at the drive's median speed
    n_med = float(np.median(trace.n_rpm))
    out["true_eta"] = float(np.interp(n_med, truth.engine.eta_n_rpm, truth.engine.eta_n_val)
                            / np.interp(n_med, belief.eta_n_rpm, belief.eta_n_val))
    pc = CacPredictionConfig(stride=stride)
    for m in METHODS:
        _, pred, actual = prediction_errors(states[m], trace.ta_sp, trace.n_rpm, trace.cac,
                                            belief, pc, eta_scale=eta if m == "adaptive" else None)
        err = 1e6 * (pred - actual)  # mg per cylinder event
        out[f"{m}_iae"] = stride * float(np.abs(err).sum())
        out[f"{m}_ise"] = stride * float((err ** 2).sum())
    return out


def _get(summary: dict[str, Any], path: str) -> Any:
    """A user's metric: a dotted path into the run summary's JSON (None: not there)."""
    node: Any = summary
    for part in path.split("."):
        if not isinstance(node, dict) or part not in node:
            return None
        node = node[part]
    return node


def drive_study(spec: CampaignSpec, d: RunDraw) -> dict[str, Any]:
    from vecu.config import RunConfig
    from vecu.functions import OPTIONAL
    from vecu.runner import run

    r = spec.run
    duration = float(r.get("duration_s", 10.0))
    kind = d.fault.get("kind")
    at = d.fault.get("at_s")
    if kind is not None and at is None:
        at = duration / 2
    cfg = RunConfig(duration_s=duration, seed=d.sim_seed, kill_tps_at_s=None if kind is None else
                    float(at), fault=str(kind or "dead"), fault_value=d.fault.get("value"),
                    params=tree_for(d),
                    **{name: bool(r.get(name, True)) for name in OPTIONAL})  # type: ignore[arg-type]  # the functions' bool switches
    cfg.validate()
    if r.get("gateway"):  # the run beside the routing between the buses of this gateway config
        from vecu.gateway.routes_config import load_routing_config
        from vecu.gateway.sim import run_with_gateway
        result = run_with_gateway(cfg, load_routing_config(r["gateway"]))
    else:
        result = run(cfg)
    report = result.report
    out: dict[str, Any] = {}
    for name in metric_names(spec):
        if name in DRIVE_METRICS:
            out[name] = DRIVE_METRICS[name](report)
        elif name not in ("dtc_confirmations", "dtcs_per_hour"):
            out[name] = _get(result.summary, name)
    conf = sum(int(v.get("confirmations", 0)) for v in report.diagnostics.values())
    out["dtc_confirmations"] = conf
    out["dtcs_per_hour"] = conf * 3600.0 / duration
    return out


def run_one(spec: CampaignSpec, run_id: int) -> dict[str, Any]:
    """One run's row: run id, its seed, the drawn values, the metrics, status (ok / error)."""
    from vecu.campaign.draws import draw

    d = draw(spec, run_id)
    row: dict[str, Any] = {"run_id": run_id, "sim_seed": d.sim_seed, "status": "ok", "error": ""}
    row.update({f"draw:{k}": v for k, v in d.drawn.items()})
    try:
        if spec.kind == "manifold":
            metrics = manifold_study(d, float(spec.run.get("duration_s", 80.0)),
                                     int(spec.run.get("stride", 1)),
                                     str(spec.run.get("engine", "batch")))
        else:
            metrics = drive_study(spec, d)
        bad = [k for k, v in metrics.items() if isinstance(v, float) and not math.isfinite(v)]
        if bad:
            raise FloatingPointError(f"non-finite metrics: {', '.join(bad)}")
    except Exception as exc:  # noqa: BLE001 (recorded with its seed; the campaign goes on)
        row.update(status="error", error=f"{type(exc).__name__}: {exc}"[:300])
        metrics = {}
    row.update({name: metrics.get(name) for name in metric_names(spec)})
    return row
