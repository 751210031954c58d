"""The manifold function (Dutka 2006: P_im, T_im and cylinder air charge per engine event, the
6-event CAC prediction) as a registry entry: its plant part (on the engine-event chain), ECU
function, probe and typed summary, replay inputs and scoring."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.codec import DbcCodec
from vecu.config import RunConfig
from vecu.ecu.manifold_function import ManifoldFunction
from vecu.estimators.registry import ESTIMATORS
from vecu.faults import FaultInjector
from vecu.functions.base import EcuFunctionSpec, EcuInput, TruthChannel, TruthPair
from vecu.plant.drive import Drive
from vecu.plant.node import ManifoldPart
from vecu.stats import ErrorStats, RunningStats


@dataclass(frozen=True)
class ManifoldSummary:
    """The manifold function's section of a run summary (Dutka 2006 Table 3 errors)."""

    filter: str
    events: int
    lost_events: int
    implausible_inputs: int  # events refused (e.g. 0 rpm)
    # under numba the usual event's filter, CAC and prediction are one call, timed in the
    # first (ManifoldFunction); their sum is the event's cost under both backends
    filter_us_per_event: float
    cac_prediction_us_per_event: float
    p_im_error_kpa: ErrorStats
    t_im_error_k: ErrorStats
    cac_error_mg: ErrorStats
    cac_pred6_error_mg: ErrorStats
    cac_pred6_abs_error_pct: ErrorStats
    p_im_estimate_range_kpa: list[float] | None
    filter_resets: int
    estimator_faults: int

    def lines(self) -> list[str]:
        """For `vecu run`'s printed summary."""
        return [(f"manifold ({self.filter}, {self.events} engine events, "
                 f"{self.lost_events} lost), RMS error against the true value: "
                 f"P_im {self.p_im_error_kpa.rms:.3f} kPa, T_im {self.t_im_error_k.rms:.2f} K, "
                 f"CAC {self.cac_error_mg.rms:.2f} mg per cylinder; 6-event CAC prediction "
                 f"{self.cac_pred6_abs_error_pct.mean:.2f} % mean |error|; "
                 f"{self.filter_us_per_event + self.cac_prediction_us_per_event:.0f} us per event "
                 "(filter, CAC and prediction)")]


class ManifoldProbe:
    """Per engine event: posterior P_im / T_im and CAC against the plant's truth at that event,
    and each 6-event CAC prediction against the truth when that event comes."""

    period_ns = NS_PER_MS

    def __init__(self, part: ManifoldPart, fn: ManifoldFunction, keep_series: bool,
                 horizon: int = 6) -> None:
        self.part, self.fn, self.horizon = part, fn, horizon
        self._series: list[tuple[float, float, float]] | None = [] if keep_series else None
        self.p_err = RunningStats()
        self.t_err = RunningStats()
        self.cac_err = RunningStats()
        self.pred_err = RunningStats()
        self.pred_rel = RunningStats()
        self.p_min, self.p_max = math.inf, -math.inf
        self._pending: dict[int, float] = {}
        self._seen = -1

    def tick(self, t_ns: int) -> None:
        last = self.fn.last
        if last is None or last[0] == self._seen:
            return
        idx, p, t, cac, cac6 = last
        self._seen = idx
        truth = self.part.truth.get(idx)
        if truth is not None:
            p_true, t_true, cac_true = truth
            self.p_err.add(p - p_true)
            self.t_err.add(t - t_true)
            self.cac_err.add((cac - cac_true) * 1e6)
            self.p_min, self.p_max = min(self.p_min, p), max(self.p_max, p)
            if self._series is not None:
                self._series.append((t_ns / NS_PER_S, p_true, p))
            pred = self._pending.pop(idx, None)
            if pred is not None:
                self.pred_err.add((pred - cac_true) * 1e6)
                self.pred_rel.add(100.0 * abs(pred - cac_true) / cac_true)
        self._pending[idx + self.horizon] = cac6
        for old in [k for k in self._pending if k < idx]:
            del self._pending[old]

    def series(self) -> np.ndarray | None:
        """Rows (t_s, true P_im, estimated P_im), one per engine event."""
        return None if self._series is None else np.array(self._series).reshape(-1, 3)

    def summary(self) -> ManifoldSummary:
        fn = self.fn
        return ManifoldSummary(
            filter=fn.filter_name, events=fn.events, lost_events=fn.lost_events,
            implausible_inputs=fn.implausible_inputs,
            filter_us_per_event=round(fn.filter_seconds / max(fn.events, 1) * 1e6, 1),
            cac_prediction_us_per_event=round(fn.predict_seconds / max(fn.events, 1) * 1e6, 1),
            p_im_error_kpa=self.p_err.summary(), t_im_error_k=self.t_err.summary(),
            cac_error_mg=self.cac_err.summary(), cac_pred6_error_mg=self.pred_err.summary(),
            cac_pred6_abs_error_pct=self.pred_rel.summary(),
            p_im_estimate_range_kpa=([round(self.p_min, 2), round(self.p_max, 2)]
                                     if self.p_err.n else None),
            filter_resets=fn.filter.resets, estimator_faults=fn.estimator_faults)
def _part(config: RunConfig, codec: DbcCodec, injector: FaultInjector,
          rngs: Mapping[str, np.random.Generator], drive: Drive) -> ManifoldPart:
    return ManifoldPart(codec, config.seed, config.params.plant.manifold, drive)


def _plot(rows: np.ndarray, ax: Any) -> None:
    ax.plot(rows[:, 0], rows[:, 1], color="black", lw=1.0, label="true manifold pressure")
    ax.plot(rows[:, 0], rows[:, 2], color="tab:purple", lw=0.8, ls="--",
            label="SDKF estimate (per engine event)")
    ax.set_ylabel("P_im (kPa)")
    ax.legend(loc="upper right", fontsize=8, ncol=2)


SPEC = EcuFunctionSpec(
    name="manifold", enabled=lambda config: config.manifold,
    build=lambda config, codec, seam: ManifoldFunction(codec, config.params.ecu.manifold),
    part_name="manifold", plant_part=_part, events=True,
    probe=lambda part, fn, config, n_ticks: ManifoldProbe(part, fn, config.keep_series),
    probe_task="manifold-probe",
    inputs={
        "engine_speed": EcuInput("ENG_Event", "ENG_Speed", "rpm"),
        "throttle_setpoint": EcuInput("ENG_Event", "ENG_ThrottleSetpoint", "deg"),
        "throttle_angle": EcuInput("ENG_Event", "ENG_ThrottleAngle", "deg"),
        "map": EcuInput("ENG_Event", "ENG_MAP", "kPa"),
        "iat": EcuInput("ENG_Intake", "ENG_IAT", "degC", required=False),
    },
    truth=TruthChannel("ECU_ManifoldEstimate", "TRUTH_Manifold", 50 * NS_PER_MS, (
        TruthPair("map_error_kpa", "MFD_Pressure", "TRU_MAP"),
        TruthPair("imt_error_k", "MFD_Temperature", "TRU_IMT"),
        TruthPair("cac_error_mg", "MFD_CAC", "TRU_CAC"),
    ), validity=("ECU_ManifoldSigma", "MFD_Validity"), describe=lambda e: (
        f"MAP RMS {e['map_error_kpa'].rms:.3f} kPa, IMT {e['imt_error_k'].rms:.2f} K, "
        f"CAC {e['cac_error_mg'].rms:.2f} mg")),
    plot=_plot, report_rank=2, label="manifold pressure [kPa]",
    profile=(
        ("vecu.plant.node", "ManifoldPart", "event", "plant: manifold part (event)"),
        ("vecu.plant.manifold", "EventsAhead", "fill", "plant: manifold events ahead"),
        ("vecu.ecu.manifold_function", "ManifoldFunction", "run", "ecu: manifold function"),
        ("vecu.estimators.manifold.filters", "_ManifoldKF", "step", "estimator: manifold SDKF"),
        ("vecu.estimators.manifold.cac_predict", None, "predict_cac",
         "estimator: manifold CAC prediction"),
        ("vecu.functions.manifold", "ManifoldProbe", "tick", "probes"),
    ),
    estimators=ESTIMATORS["manifold"].names)
