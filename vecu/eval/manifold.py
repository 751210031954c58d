"""Offline manifold-estimator evaluation: the Table 1 analogue of Dutka 2006 (Section IV).

Each run: seeded 80 s US06-like profile (vecu.plant.drive_profile.us06_like(seed)), the noisy
truth plant (Section IV's Q and R, vecu.plant.manifold.simulate(seed)), then the four CAC sources
(direct, direct + open-loop temperature, EKF, SDKF) and the 6-event-ahead CAC prediction
(vecu.estimators.manifold.cac_predict). Sums over events of |CAC_actual - CAC_pred| (mg) and of its square
(mg^2), pooled over runs (seeds seed, seed+1, ...), and their ratio to "direct".

Also: wall-clock microseconds per event of each filter's step() (the live SDKF with one Riccati
iteration per event, the EKF, the full-DARE SDKF by doubling, and the paper's scipy DARE on the
first `scipy_events` events of the first run), the cheap-vs-full-DARE SDKF agreement, P_im ranges
(truth and estimates) and the filters' reset / reject counters.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vecu.clock import perf_s
from vecu.estimators.manifold.cac_predict import (
    CacPredictionConfig,
    open_loop_temperatures,
    prediction_errors,
)
from vecu.estimators.manifold.factory import make_filter
from vecu.estimators.manifold.filters import ManifoldFilterConfig
from vecu.models.manifold_params import V8_5L7, EngineInput, ManifoldParams
from vecu.plant.drive_profile import DriveProfile, us06_like
from vecu.plant.manifold import ManifoldTrace, simulate

DEFAULT_FILTER_CONFIG = ManifoldFilterConfig()
P_IM_RANGE_KPA = (10.0, 105.0)  # physically sensible for this engine (floor ~18, WOT ~100)


@dataclass(frozen=True)
class MethodResult:
    method: str
    abs_sum_mg: float  # sum over events of |CAC_actual - CAC_pred|, mg per cylinder event
    sq_sum_mg2: float  # sum of squares, mg^2
    abs_ratio: float  # to "direct"
    sq_ratio: float
    mean_abs_pct: float  # mean |epsilon| = 100 |pred - actual| / actual, %


@dataclass(frozen=True)
class FilterStats:
    name: str
    us_per_event: float
    events: int
    resets: int
    rejected: int
    gated: int
    p_im_min: float  # posterior P_im range, kPa
    p_im_max: float
    finite: bool


@dataclass(frozen=True)
class ManifoldEvalReport:
    seeds: tuple[int, ...]
    events: int
    predictions: int  # predicted events per method (all runs)
    stride: int
    methods: tuple[MethodResult, ...]  # direct, direct_ol, ekf, sdkf (cheap), adaptive [, sdkf_dare]
    filters: tuple[FilterStats, ...]
    scipy_dare_us_per_event: float  # NaN when not measured
    scipy_dare_events: int
    cheap_vs_dare_abs_rel: float  # |abs_sum(cheap) / abs_sum(full DARE) - 1|, NaN if no DARE
    cheap_vs_dare_p_rms_kpa: float  # RMS of the P_im posterior difference
    cheap_vs_dare_t_rms_k: float
    p_im_true_min: float
    p_im_true_max: float
    p_im_range_ok: bool  # truth and every filter posterior inside P_IM_RANGE_KPA

    def method(self, name: str) -> MethodResult:
        for m in self.methods:
            if m.method == name:
                return m
        raise KeyError(name)

    def filter(self, name: str) -> FilterStats:
        for s in self.filters:
            if s.name == name:
                return s
        raise KeyError(name)


def trace_input_array(trace: ManifoldTrace, params: ManifoldParams = V8_5L7) -> np.ndarray:
    """trace_inputs as rows (TA_SP, N, P_a, T_a, T_cool), for ManifoldKF.run_events."""
    n = len(trace.t)
    return np.column_stack([trace.ta_sp, trace.n_rpm, np.full(n, params.p_a_kpa),
                            np.full(n, params.t_a_k), np.full(n, params.t_cool_k)])


def trace_inputs(trace: ManifoldTrace, params: ManifoldParams = V8_5L7) -> list[EngineInput]:
    return [EngineInput(float(sp), float(n), params.p_a_kpa, params.t_a_k, params.t_cool_k)
            for sp, n in zip(trace.ta_sp, trace.n_rpm)]


def run_filter(name: str, trace: ManifoldTrace, inputs: list[EngineInput],
               config: ManifoldFilterConfig = DEFAULT_FILTER_CONFIG,
               events: int | None = None) -> tuple[np.ndarray, float, object]:
    """Posteriors x_n|n (events x states), seconds spent in step(), the filter (its
    run_variances: the posterior variances per event)."""
    flt = make_filter(name, config)
    ys = trace.y.tolist()
    n_ev = len(ys) if events is None else min(events, len(ys))
    xs = np.empty((n_ev, len(flt.x)))  # 6 states, 11 for the adaptive filter
    vs = np.empty((n_ev, len(flt.x)))
    step = flt.step
    elapsed = 0.0
    clock = perf_s
    for n in range(n_ev):
        t0 = clock()
        xs[n] = step(ys[n], inputs[n])
        elapsed += clock() - t0
        vs[n] = np.diag(flt.P_post)
    flt.run_variances = vs  # as FilterRuns.run_events
    return xs, elapsed, flt


def direct_states(trace: ManifoldTrace) -> np.ndarray:
    """x_n from the readings alone at every event: (TA_SP,n-1, TA_n, TA_n-1, P_n, T_out,n,
    T_out,n) (event 0 uses itself as n-1)."""
    y = trace.y
    k = np.maximum(np.arange(len(y)) - 1, 0)
    return np.column_stack([trace.ta_sp[k], y[:, 0], y[k, 0], y[:, 1], y[:, 2], y[:, 2]])


def direct_ol_states(trace: ManifoldTrace, inputs: list[EngineInput] | None,
                     params: ManifoldParams = V8_5L7) -> np.ndarray:
    """direct_states with T_im from the open-loop observer driven by the measured angle (the
    ambient and coolant conditions of `inputs`; None: the nominal ones of params, as
    trace_inputs(trace, params) gives)."""
    out = direct_states(trace)
    out[:, 4] = open_loop_temperatures(trace.y[:, 0], trace.n_rpm, trace.y[0, 1],
                                       trace.y[0, 2], params, inputs)
    return out


def _sums(err_mg: np.ndarray, actual_mg: np.ndarray, stride: int) -> tuple[float, float, float]:
    return (stride * float(np.abs(err_mg).sum()), stride * float((err_mg ** 2).sum()),
            float(np.mean(100.0 * np.abs(err_mg) / actual_mg)))


def evaluate_manifold(seed: int = 0, runs: int = 1, stride: int = 1, full_dare: bool = True,
                      scipy_events: int = 300, duration_s: float | None = None,
                      config: ManifoldFilterConfig = DEFAULT_FILTER_CONFIG,
                      prediction: CacPredictionConfig | None = None) -> ManifoldEvalReport:
    """Table 1 analogue over `runs` seeded 80 s profiles (seeds seed .. seed + runs - 1).

    stride > 1 predicts the CAC at every stride-th event only (sums scaled by stride; the filters
    still run every event). duration_s truncates the profile (tests). full_dare also runs the
    SDKF with the DARE solved per event (doubling) as the accuracy baseline.
    """
    params = config.params
    pc = prediction if prediction is not None else CacPredictionConfig(stride=stride)
    names = ["ekf", "sdkf", "adaptive"] + (["sdkf_doubling"] if full_dare else [])
    methods = ["direct", "direct_ol"] + names
    err: dict[str, list[np.ndarray]] = {m: [] for m in methods}
    act: list[np.ndarray] = []
    t_spent = {n: 0.0 for n in names}
    stats = {n: {"events": 0, "resets": 0, "rejected": 0, "gated": 0, "pmin": math.inf,
                 "pmax": -math.inf, "finite": True} for n in names}
    p_true = [math.inf, -math.inf]
    post: dict[str, list[np.ndarray]] = {"sdkf": [], "sdkf_doubling": []}
    scipy_us, scipy_n = math.nan, 0
    events = 0
    seeds = tuple(seed + r for r in range(runs))
    for r, s in enumerate(seeds):
        prof = us06_like(s, params=params)
        if duration_s is not None:
            k = round(duration_s / prof.dt_s) + 1
            prof = DriveProfile(prof.dt_s, prof.n_rpm[:k], prof.ta_sp[:k])
        trace = simulate(prof, seed=s, params=params)
        inputs = trace_inputs(trace, params)
        events += len(trace.t)
        p_true = [min(p_true[0], float(trace.x[:, 3].min())),
                  max(p_true[1], float(trace.x[:, 3].max()))]
        states = {"direct": direct_states(trace),
                  "direct_ol": direct_ol_states(trace, inputs, params)}
        eta = None
        for name in names:
            xs, sec, flt = run_filter(name, trace, inputs, config)
            states[name] = xs
            if name == "adaptive":
                eta = flt.eta_used(xs[:, 6], flt.run_variances[:, 6])
            t_spent[name] += sec
            st = stats[name]
            st["events"] += len(xs)
            st["resets"] += flt.resets
            st["rejected"] += sum(flt.rejected)
            st["gated"] += sum(flt.gated)
            st["finite"] = st["finite"] and bool(np.all(np.isfinite(xs)))
            st["pmin"] = min(st["pmin"], float(xs[:, 3].min()))
            st["pmax"] = max(st["pmax"], float(xs[:, 3].max()))
            if name in post:
                post[name].append(xs)
        if r == 0 and scipy_events > 0:
            _, sec, _ = run_filter("sdkf_scipy", trace, inputs, config, events=scipy_events)
            scipy_n = min(scipy_events, len(trace.t))
            scipy_us = 1e6 * sec / scipy_n
        for m in methods:
            _, pred, actual = prediction_errors(
                states[m], trace.ta_sp, trace.n_rpm, trace.cac, params, pc,
                eta_scale=eta if m == "adaptive" else None)
            err[m].append(1e6 * (pred - actual))
        act.append(1e6 * actual)
    actual_mg = np.concatenate(act)
    sums = {m: _sums(np.concatenate(err[m]), actual_mg, pc.stride) for m in methods}
    base_abs, base_sq = sums["direct"][0], sums["direct"][1]
    results = tuple(
        MethodResult(m, sums[m][0], sums[m][1], sums[m][0] / base_abs, sums[m][1] / base_sq,
                     sums[m][2]) for m in methods)
    fstats = tuple(
        FilterStats(n, 1e6 * t_spent[n] / max(stats[n]["events"], 1), stats[n]["events"],
                    stats[n]["resets"], stats[n]["rejected"], stats[n]["gated"],
                    stats[n]["pmin"], stats[n]["pmax"], stats[n]["finite"]) for n in names)
    if full_dare:
        a = np.concatenate(post["sdkf"])
        b = np.concatenate(post["sdkf_doubling"])
        rel = abs(sums["sdkf"][0] / sums["sdkf_doubling"][0] - 1.0)
        p_rms = float(np.sqrt(np.mean((a[:, 3] - b[:, 3]) ** 2)))
        t_rms = float(np.sqrt(np.mean((a[:, 4] - b[:, 4]) ** 2)))
    else:
        rel = p_rms = t_rms = math.nan
    lo, hi = P_IM_RANGE_KPA
    ok = lo <= p_true[0] and p_true[1] <= hi and all(
        lo <= f.p_im_min and f.p_im_max <= hi for f in fstats)
    return ManifoldEvalReport(
        seeds=seeds, events=events, predictions=len(actual_mg), stride=pc.stride,
        methods=results, filters=fstats, scipy_dare_us_per_event=scipy_us,
        scipy_dare_events=scipy_n, cheap_vs_dare_abs_rel=rel, cheap_vs_dare_p_rms_kpa=p_rms,
        cheap_vs_dare_t_rms_k=t_rms, p_im_true_min=p_true[0], p_im_true_max=p_true[1],
        p_im_range_ok=ok)


def format_report(rep: ManifoldEvalReport) -> str:
    lines = [(f"seeds {list(rep.seeds)}, {rep.events} events, CAC predicted every {rep.stride} "
              f"event(s) ({rep.predictions} predictions), horizon 6 events"),
             (f"{'method':<14}{'sum|dCAC| mg':>14}{'ratio':>8}{'sum dCAC^2 mg2':>16}"
              f"{'ratio':>8}{'mean|eps| %':>12}")]
    for m in rep.methods:
        lines.append(f"{m.method:<14}{m.abs_sum_mg:>14.0f}{m.abs_ratio:>8.3f}{m.sq_sum_mg2:>16.0f}"
                     f"{m.sq_ratio:>8.3f}{m.mean_abs_pct:>12.2f}")
    for f in rep.filters:
        lines.append(f"{f.name:<14} {f.us_per_event:7.0f} us/event, resets {f.resets}, rejected "
                     f"{f.rejected}, gated {f.gated}, P_im {f.p_im_min:.1f}..{f.p_im_max:.1f} kPa")
    lines.append(f"scipy DARE SDKF: {rep.scipy_dare_us_per_event:.0f} us/event "
                 f"({rep.scipy_dare_events} events)")
    lines.append(f"cheap vs full-DARE SDKF: |sum|dCAC| ratio - 1| = {rep.cheap_vs_dare_abs_rel:.2e},"
                 f" P_im RMS diff {rep.cheap_vs_dare_p_rms_kpa:.2e} kPa, T_im "
                 f"{rep.cheap_vs_dare_t_rms_k:.2e} K")
    lines.append(f"true P_im {rep.p_im_true_min:.1f}..{rep.p_im_true_max:.1f} kPa, range ok "
                 f"{rep.p_im_range_ok}")
    return "\n".join(lines)
