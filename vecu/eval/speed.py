"""Offline accuracy of the speed/acceleration filter against simulated truth (Hernández 2005).

Each run simulates one manoeuvre (vecu.plant.longitudinal) and feeds the filter
step(wheel_k, accel_k); the estimate after step k is compared with the truth at k. The first
`burn_in_s` are skipped. Improvements are 20 log10(RMS_baseline / RMS_filter) in dB, with errors
pooled over all runs:
- speed, truth >= 5 km/h and < 5 km/h (standstill included; the moving-only part is reported
  too), baseline: the raw wheel-speed reading (dropouts read 0);
- acceleration, all samples, baseline: the raw accelerometer. The raw wheel speed differentiated
  over one 2 ms step is also reported: its noise (sigma sqrt(2) / dt ~ 250 m/s^2) makes it a
  meaningless baseline, so the accelerometer (the better raw source) is the honest one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vecu.clock import perf_s
from vecu.estimators.speed.kf import SpeedFilterConfig, SpeedKalmanFilter
from vecu.plant.longitudinal import (
    DT_S,
    ManoeuvreConfig,
    SpeedTrace,
    simulate_speed,
)
from vecu.units import MPS_PER_KMH

LOW_SPEED_KMH = 5.0


@dataclass(frozen=True)
class SpeedEvalReport:
    """RMS errors (speed in km/h, acceleration in m/s^2) and improvements in dB."""

    manoeuvre: str
    seed: int
    runs: int
    samples: int
    speed_rms_high_kmh: float  # filter, truth >= 5 km/h
    speed_rms_high_raw_kmh: float
    speed_gain_high_db: float
    speed_rms_low_kmh: float  # filter, truth < 5 km/h (standstill included)
    speed_rms_low_raw_kmh: float
    speed_gain_low_db: float
    speed_gain_low_moving_db: float  # same, 0 < truth < 5 km/h only
    accel_rms_mps2: float
    accel_rms_raw_mps2: float  # raw accelerometer: the baseline
    accel_gain_db: float
    accel_rms_diff_wheel_mps2: float  # raw wheel speed differentiated over 2 ms (for reference)
    us_per_step: float  # wall time per step() incl. the harness reading both outputs
    resets: int
    rejected: int  # rejected wheel + accel inputs over all runs


def run_filter(trace: SpeedTrace, config: SpeedFilterConfig | None = None
               ) -> tuple[np.ndarray, np.ndarray, float, SpeedKalmanFilter]:
    """Feed one trace; return v_hat_k, a_hat_k, seconds spent looping and the filter."""
    f = SpeedKalmanFilter(config if config is not None else SpeedFilterConfig())
    w = trace.wheel.tolist()
    acc = trace.accel.tolist()
    n = len(w)
    vs = [0.0] * n
    as_ = [0.0] * n
    step = f.step
    t0 = perf_s()
    for k in range(n):
        step(w[k], acc[k])
        vs[k] = f.speed_mps
        as_[k] = f.accel_mps2
    elapsed = perf_s() - t0
    return np.asarray(vs), np.asarray(as_), elapsed, f


def _rms(x: np.ndarray) -> float:
    return float(math.sqrt(float(np.mean(x * x)))) if x.size else float("nan")


def _db(raw: float, filt: float) -> float:
    if not (raw > 0.0 and filt > 0.0):
        return float("inf") if raw > 0.0 else float("nan")
    return 20.0 * math.log10(raw / filt)


def evaluate_speed(
    seed: int = 1, runs: int = 10, manoeuvre: str = "paper",
    config: SpeedFilterConfig | None = None, burn_in_s: float = 0.5,
) -> SpeedEvalReport:
    """Simulate `runs` manoeuvres (seeds seed .. seed+runs-1), run the filter, pool the errors."""
    if runs < 1:
        raise ValueError("runs must be >= 1")
    burn = round(burn_in_s / DT_S)
    ef_hi, er_hi, ef_lo, er_lo, ef_mv, er_mv, ea_f, ea_r, ea_d = ([] for _ in range(9))
    steps = 0
    elapsed = 0.0
    resets = rejected = 0
    for r in range(runs):
        tr = simulate_speed(seed + r, ManoeuvreConfig(kind=manoeuvre))
        vh, ah, dt_s, f = run_filter(tr, config)
        steps += len(tr.t)
        elapsed += dt_s
        resets += f.resets
        rejected += f.rejected_wheel + f.rejected_accel
        v = tr.v[burn:]
        hi = v >= LOW_SPEED_KMH * MPS_PER_KMH
        lo = ~hi
        mv = lo & (v > 0.0)
        ef = vh[burn:] - v
        er = tr.wheel[burn:] - v
        ef_hi.append(ef[hi])
        er_hi.append(er[hi])
        ef_lo.append(ef[lo])
        er_lo.append(er[lo])
        ef_mv.append(ef[mv])
        er_mv.append(er[mv])
        ea_f.append(ah[burn:] - tr.a[burn:])
        ea_r.append(tr.accel[burn:] - tr.a[burn:])
        ea_d.append(np.diff(tr.wheel)[burn - 1:] / DT_S - tr.a[burn:])
    c = np.concatenate
    s_hi, s_hi_r = _rms(c(ef_hi)) / MPS_PER_KMH, _rms(c(er_hi)) / MPS_PER_KMH
    s_lo, s_lo_r = _rms(c(ef_lo)) / MPS_PER_KMH, _rms(c(er_lo)) / MPS_PER_KMH
    s_mv, s_mv_r = _rms(c(ef_mv)), _rms(c(er_mv))
    a_f, a_r = _rms(c(ea_f)), _rms(c(ea_r))
    return SpeedEvalReport(
        manoeuvre=manoeuvre, seed=seed, runs=runs, samples=sum(x.size for x in ea_f),
        speed_rms_high_kmh=s_hi, speed_rms_high_raw_kmh=s_hi_r, speed_gain_high_db=_db(s_hi_r, s_hi),
        speed_rms_low_kmh=s_lo, speed_rms_low_raw_kmh=s_lo_r, speed_gain_low_db=_db(s_lo_r, s_lo),
        speed_gain_low_moving_db=_db(s_mv_r, s_mv),
        accel_rms_mps2=a_f, accel_rms_raw_mps2=a_r, accel_gain_db=_db(a_r, a_f),
        accel_rms_diff_wheel_mps2=_rms(c(ea_d)),
        us_per_step=1e6 * elapsed / steps, resets=resets, rejected=rejected,
    )
