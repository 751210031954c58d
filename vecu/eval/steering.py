"""Offline accuracy of the steering-wheel angle / side-slip estimators against simulated truth.

One seeded manoeuvre (vecu.plant.lateral.simulate_lateral, 300 s at 100 Hz by default) is fed to
the EKF, the UKF, the fixed-lag smoother (live, its lagged output compared with the truth at the
step it refers to) and the full unscented RTS smoother (offline over the recorded UKF run). Every
filter step gets step(v_x, r, a_y) from the sensors; the filters start at 0 (the run starts in a
curve) and no burn-in is skipped unless asked. The steering-wheel-angle sensor is not an input:
it is what is estimated (its reading is only reported, as the accuracy a healthy sensor gives).
Baseline: the no-filter steady-state inverse SWA = i_s (L + K v_x^2) r / v_x from the raw gyro.

mismatch=True: the filter's cornering stiffnesses -15 % and a gyro bias of 0.3 deg/s in the plant.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from vecu.clock import perf_s
from vecu.estimators.steering.filters import SteeringEKF, SteeringUKF
from vecu.estimators.steering.model import SteeringModel
from vecu.estimators.steering.smoothers import FixedLagSmoother, rts_smooth
from vecu.models.lateral import DT_S
from vecu.plant.lateral import (
    LateralSensors,
    LateralTrace,
    ManoeuvreConfig,
    SensorModel,
    simulate_lateral,
)
from vecu.units import RAD_PER_DEG

TIMING_STEPS = 3000  # bare UKF / EKF steps timed separately (no recording, no harness)


@dataclass(frozen=True)
class SteeringEvalReport:
    """RMS errors over the evaluated samples: steering-wheel angle and side slip in degrees."""

    seed: int
    duration_s: float
    samples: int
    mismatch: bool
    lag_s: float
    swa_rms_ekf_deg: float
    swa_rms_ukf_deg: float
    swa_rms_fixed_lag_deg: float
    swa_rms_smoother_deg: float
    swa_rms_inverse_deg: float  # no-filter steady-state inverse from the raw gyro
    swa_rms_sensor_deg: float  # the healthy SWA sensor itself (for scale)
    beta_rms_ekf_deg: float
    beta_rms_ukf_deg: float
    beta_rms_fixed_lag_deg: float
    beta_rms_smoother_deg: float
    beta_max_abs_deg: float  # largest true side slip of the run (for scale)
    us_per_step_ukf: float  # bare step(), no recording
    us_per_step_ekf: float
    us_per_step_fixed_lag: float  # UKF step + fixed-lag backward pass, incl. harness
    us_per_sample_rts: float  # full smoother backward pass (means and covariances)
    resets: int  # divergence resets, all filters
    rejected: int  # rejected readings, all filters
    clipped: int  # state projections onto the physical limits, all filters


def _rms(e: np.ndarray) -> float:
    return float(math.sqrt(float(np.mean(e * e)))) if e.size else float("nan")


def _bare_us(filt, tr: LateralTrace, steps: int) -> float:
    vx, r, ay = tr.meas_vx.tolist(), tr.meas_r.tolist(), tr.meas_ay.tolist()
    n = min(steps, len(vx))
    step = filt.step
    t0 = perf_s()
    for k in range(n):
        step(vx[k], r[k], ay[k])
    return 1e6 * (perf_s() - t0) / n


def mismatch_setup(model: SteeringModel) -> tuple[SteeringModel, LateralSensors]:
    """Filter C_f, C_r -15 %; plant gyro bias +0.3 deg/s (design note's robustness case)."""
    p = model.params
    fp = dataclasses.replace(p, c_f_n_per_rad=0.85 * p.c_f_n_per_rad,
                             c_r_n_per_rad=0.85 * p.c_r_n_per_rad)
    base = LateralSensors()
    sens = dataclasses.replace(base, yaw_rate=SensorModel(sigma=base.yaw_rate.sigma,
                                                          bias=0.3 * RAD_PER_DEG))
    return dataclasses.replace(model, params=fp), sens


def evaluate_steering(
    seed: int = 1, duration_s: float = 300.0, model: SteeringModel | None = None,
    lag_s: float = 0.25, mismatch: bool = False, burn_in_s: float = 0.0,
) -> SteeringEvalReport:
    """Simulate one manoeuvre and compare EKF, UKF, fixed-lag and full smoother with the truth."""
    m = model if model is not None else SteeringModel()
    sensors = LateralSensors()
    if mismatch:
        m, sensors = mismatch_setup(m)
    tr = simulate_lateral(seed, ManoeuvreConfig(duration_s=duration_s), sensors=sensors)
    n = tr.t.size
    vx, r, ay = tr.meas_vx.tolist(), tr.meas_r.tolist(), tr.meas_ay.tolist()
    i_s = tr.params.steering_ratio

    ekf = SteeringEKF(m)
    swa_e = np.empty(n)
    beta_e = np.empty(n)
    for k in range(n):
        ekf.step(vx[k], r[k], ay[k])
        swa_e[k] = ekf.swa_rad
        beta_e[k] = ekf.side_slip_rad

    ukf = SteeringUKF(m, record=True)
    swa_u = np.empty(n)
    beta_u = np.empty(n)
    for k in range(n):
        ukf.step(vx[k], r[k], ay[k])
        swa_u[k] = ukf.swa_rad
        beta_u[k] = ukf.side_slip_rad
    run = ukf.history()
    t0 = perf_s()
    sm = rts_smooth(run)
    us_rts = 1e6 * (perf_s() - t0) / n
    swa_s = i_s * sm.x[:, 2]
    beta_s = np.arctan2(sm.x[:, 0], run.v_x)

    fl = FixedLagSmoother(lag_s, SteeringUKF(m))
    swa_l = np.full(n, np.nan)
    beta_l = np.full(n, np.nan)
    t0 = perf_s()
    for k in range(n):
        le = fl.step(vx[k], r[k], ay[k])
        if le is not None:
            swa_l[le.step] = le.swa_rad
            beta_l[le.step] = le.side_slip_rad
    us_fl = 1e6 * (perf_s() - t0) / n
    for le in fl.flush():
        swa_l[le.step] = le.swa_rad
        beta_l[le.step] = le.side_slip_rad

    p = tr.params
    v = np.maximum(tr.meas_vx, 3.0)
    swa_inv = i_s * (p.wheelbase_m + p.understeer_rad_per_mps2 * v * v) * tr.meas_r / v

    sl = slice(round(burn_in_s / DT_S), n)
    d = 1.0 / RAD_PER_DEG

    def e_swa(est: np.ndarray) -> float:
        return _rms((est[sl] - tr.swa[sl]) * d)

    def e_beta(est: np.ndarray) -> float:
        return _rms((est[sl] - tr.beta[sl]) * d)

    return SteeringEvalReport(
        seed=seed, duration_s=duration_s, samples=n - sl.start, mismatch=mismatch, lag_s=lag_s,
        swa_rms_ekf_deg=e_swa(swa_e), swa_rms_ukf_deg=e_swa(swa_u),
        swa_rms_fixed_lag_deg=e_swa(swa_l), swa_rms_smoother_deg=e_swa(swa_s),
        swa_rms_inverse_deg=e_swa(swa_inv), swa_rms_sensor_deg=e_swa(tr.meas_swa),
        beta_rms_ekf_deg=e_beta(beta_e), beta_rms_ukf_deg=e_beta(beta_u),
        beta_rms_fixed_lag_deg=e_beta(beta_l), beta_rms_smoother_deg=e_beta(beta_s),
        beta_max_abs_deg=float(np.abs(tr.beta).max()) * d,
        us_per_step_ukf=_bare_us(SteeringUKF(m), tr, TIMING_STEPS),
        us_per_step_ekf=_bare_us(SteeringEKF(m), tr, TIMING_STEPS),
        us_per_step_fixed_lag=us_fl, us_per_sample_rts=us_rts,
        resets=ekf.resets + ukf.resets + fl.filter.resets,
        rejected=ekf.rejected + ukf.rejected + fl.filter.rejected,
        clipped=ekf.clipped + ukf.clipped + fl.filter.clipped,
    )
