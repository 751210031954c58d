"""Steering-wheel angle / side-slip (Khalid): plant, model Jacobians, UKF/EKF, smoothers, eval.

Tolerances are stated at each test; measured numbers are in docs/models.md ('Steering-wheel angle
and side-slip (Khalid)'). Only the accuracy test runs the nominal 300 s manoeuvre (its targets are
defined on it); the others use 20-100 s runs, enough for what they check.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from vecu.estimators.common.sigma_sets import moment_errors
from vecu.estimators.steering import model as sm
from vecu.estimators.steering.filters import (
    SteeringEKF,
    SteeringUKF,
    default_sigma_set,
    matrix_from_p10,
    p10_from_matrix,
)
from vecu.estimators.steering.model import SteeringModel
from vecu.estimators.steering.smoothers import FixedLagSmoother, rts_smooth
from vecu.eval.steering import evaluate_steering
from vecu.models import lateral as lat
from vecu.models.lateral import VehicleParams
from vecu.plant.lateral import (
    LateralSensors,
    ManoeuvreConfig,
    SensorModel,
    simulate_lateral,
)
from vecu.units import G_MPS2, RAD_PER_DEG

SHORT = ManoeuvreConfig(duration_s=20.0)


@pytest.fixture(scope="module")
def nominal():
    return evaluate_steering(seed=1)


@pytest.fixture(scope="module")
def short_trace():
    return simulate_lateral(7, SHORT)


def _feed(filt, tr) -> None:
    for v, r, a in zip(tr.meas_vx.tolist(), tr.meas_r.tolist(), tr.meas_ay.tolist()):
        filt.step(v, r, a)


# --- accuracy on the nominal manoeuvre ----------------------------------------------------------
# Measured seed 1 (300 s): SWA RMS EKF 0.92, UKF 0.93, fixed-lag (0.25 s) 0.21, full smoother
# 0.21 deg; inverse baseline 2.6 deg; side slip 0.029 / 0.020 deg (max |beta| 1.2 deg).
# Targets of the issue: UKF <= 1.3, smoothers <= 0.4 deg (reference re-implementation 1.07 / 0.28).
def test_nominal_accuracy_meets_targets(nominal) -> None:
    r = nominal
    assert r.duration_s == 300.0 and r.samples == 30001
    assert r.swa_rms_ukf_deg <= 1.3
    assert r.swa_rms_ekf_deg <= 1.3
    assert r.swa_rms_fixed_lag_deg <= 0.4
    assert r.swa_rms_smoother_deg <= 0.4
    assert r.swa_rms_smoother_deg < 0.5 * r.swa_rms_ukf_deg  # the gain is the smoothing
    assert abs(r.swa_rms_fixed_lag_deg - r.swa_rms_smoother_deg) < 0.02  # 0.25 s lag suffices
    assert r.swa_rms_inverse_deg > 2.0 * r.swa_rms_ukf_deg  # the filter beats the raw inverse
    assert r.beta_rms_ukf_deg < 0.1 and r.beta_rms_smoother_deg < 0.05
    assert r.resets == 0 and r.rejected == 0 and r.clipped == 0


# Model mismatch (filter C_alpha -15 %, gyro bias 0.3 deg/s), 100 s suffice for the ordering.
# Measured seed 1 (300 s): UKF 1.87, smoother 1.20 deg (reference: 1.45 / 1.18).
def test_mismatch_degrades_gracefully() -> None:
    r = evaluate_steering(seed=1, duration_s=100.0, mismatch=True)
    assert r.swa_rms_ukf_deg < 2.5
    assert r.swa_rms_smoother_deg < r.swa_rms_ukf_deg
    assert r.resets == 0


# --- plant -------------------------------------------------------------------------------------
def test_vehicle_parameters_match_design_note() -> None:
    p = VehicleParams()
    assert p.understeer_rad_per_mps2 * G_MPS2 / RAD_PER_DEG == pytest.approx(1.78, abs=0.01)
    assert math.sqrt(p.wheelbase_m / p.understeer_rad_per_mps2) == pytest.approx(28.7, abs=0.05)


def test_steady_state_and_small_angle_gain() -> None:
    p = VehicleParams()
    t = lat.tyre_consts(p)
    v, d = 25.0, 0.2 * RAD_PER_DEG
    x = lat.steady_state(d, v, p)
    assert max(abs(g) for g in lat.f(x, (d, v), p, t)) < 1e-9
    # Small angle: linear yaw gain v / (L + K v^2) within 0.5 %.
    assert x[1] == pytest.approx(v * d / (p.wheelbase_m + p.understeer_rad_per_mps2 * v * v),
                                 rel=5e-3)
    _, ay = lat.h(x, (d, v), p, t)
    assert ay == pytest.approx(v * x[1], rel=1e-9)  # a_y = v_y' + v_x r with v_y' = 0


def test_manoeuvre_ranges(short_trace) -> None:
    tr = simulate_lateral(1)
    assert tr.t.size == 30001
    assert 20.0 <= tr.v_x.min() and tr.v_x.max() <= 30.0
    assert np.abs(tr.a_y).max() < 7.0  # below mu g: tyres nonlinear, never saturated
    assert np.abs(tr.swa).max() > 15.0 * RAD_PER_DEG
    assert abs(tr.swa[0]) > 3.0 * RAD_PER_DEG  # starts in a curve
    np.testing.assert_allclose(tr.swa, tr.params.steering_ratio * tr.delta)


def test_sensor_model_eq3() -> None:
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError):
        SensorModel(sigma=0.1, gain=1.5)
    dead = SensorModel(sigma=0.0, gain=0.0).measure(np.ones(5), rng)
    np.testing.assert_array_equal(dead, 0.0)
    half = SensorModel(sigma=0.0, gain=0.5, bias=0.1).measure(np.full(3, 2.0), rng)
    np.testing.assert_allclose(half, 1.1)
    sens = dataclasses.replace(LateralSensors(),
                               steering_wheel=SensorModel(sigma=0.1 * RAD_PER_DEG, gain=0.0))
    tr = simulate_lateral(7, SHORT, sensors=sens)
    assert np.abs(tr.meas_swa).max() < 0.6 * RAD_PER_DEG  # a killed SWA sensor reads noise only


def test_determinism() -> None:
    a = simulate_lateral(5, SHORT)
    b = simulate_lateral(5, SHORT)
    c = simulate_lateral(6, SHORT)
    for name in ("v_x", "swa", "r", "a_y", "meas_r", "meas_ay", "meas_vx", "meas_swa"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.swa, c.swa)
    f1, f2 = SteeringUKF(record=True), SteeringUKF(record=True)
    _feed(f1, a)
    _feed(f2, b)
    np.testing.assert_array_equal(f1.history().x, f2.history().x)


# --- model Jacobians vs finite differences -----------------------------------------------------
STATES = [(0.0, 0.0, 0.0, 0.0, 25.0), (0.3, 0.2, 0.03, 0.1, 20.0), (-0.5, -0.3, -0.06, 0.4, 30.0),
          (0.8, 0.5, 0.12, -1.0, 8.0)]  # the last well into the nonlinear tyre region


def _fd(fun, x: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    cols = []
    for j in range(x.size):
        e = np.zeros(x.size)
        e[j] = eps
        cols.append((np.asarray(fun(tuple(x + e))) - np.asarray(fun(tuple(x - e)))) / (2 * eps))
    return np.column_stack(cols)


def _heun(x, vx, cst):
    """Oracle: the Heun step written plainly with deriv, x + dt/2 (g(x) + g(x + dt g(x)))."""
    dt = cst[sm.DT]
    g1 = sm.deriv(x, vx, cst)
    x1 = tuple(x[i] + dt * g1[i] for i in range(4))
    g2 = sm.deriv(x1, vx, cst)
    return tuple(x[i] + 0.5 * dt * (g1[i] + g2[i]) for i in range(4))


@pytest.mark.parametrize("state", STATES)
def test_jacobians_match_finite_differences(state) -> None:
    """Central differences, eps 1e-6: agreement to 1e-6 relative to the Jacobian's scale; the
    model's transition is the Heun step of deriv (to rounding)."""
    k = sm.constants(SteeringModel())
    x, vx = np.array(state[:4]), state[4]
    for jac, fun in ((sm.jacobian_g, lambda z: sm.deriv(z, vx, k)),
                     (sm.jacobian_f, lambda z: sm.transition.py(*z, vx, k)),
                     (sm.jacobian_h, lambda z: sm.h(z, vx, k))):
        J = jac(tuple(x), vx, k)
        Jn = _fd(fun, x)
        assert np.abs(J - Jn).max() <= 1e-6 * max(1.0, np.abs(J).max())
    np.testing.assert_allclose(sm.transition.py(*x.tolist(), vx, k), _heun(tuple(x), vx, k),
                               rtol=1e-12, atol=1e-15)


def test_filter_model_matches_plant() -> None:
    """The filter's continuous dynamics are the plant's, with delta a state."""
    p = VehicleParams()
    k = sm.constants(SteeringModel(params=p))
    x = (0.2, 0.15, 0.04, 0.3)
    g = sm.deriv(x, 22.0, k)
    gp = lat.f((x[0], x[1]), (x[2], 22.0), p)
    np.testing.assert_allclose(g[:2], gp, rtol=1e-12)
    assert sm.h(x, 22.0, k)[1] == pytest.approx(lat.h((x[0], x[1]), (x[2], 22.0), p)[1])


def test_sigma_set_choice() -> None:
    s = default_sigma_set()
    assert s.n == 4 and s.points == 9 and s.w[0] == 0.0 and np.all(s.w[1:] == 1.0 / 8.0)
    assert max(moment_errors(s)) < 1e-12
    with pytest.raises(ValueError):
        from vecu.estimators.common.sigma_sets import ahsm
        SteeringUKF(sigma_set=ahsm(3))
    P = np.arange(16.0).reshape(4, 4)
    P = P + P.T
    np.testing.assert_array_equal(matrix_from_p10(p10_from_matrix(P)), P)


# --- robustness --------------------------------------------------------------------------------
BAD = [float("nan"), float("inf"), -float("inf"), 1e308, -1e308, 1e6, None]


@pytest.mark.parametrize("cls", [SteeringUKF, SteeringEKF])
def test_never_nan_under_bad_input(cls, short_trace) -> None:
    """Bad readings in every combination with good ones: outputs finite, counters add up."""
    f = cls()
    tr = short_trace
    vx, r, ay = tr.meas_vx.tolist(), tr.meas_r.tolist(), tr.meas_ay.tolist()
    rng = np.random.default_rng(0)
    for k in range(len(vx)):
        v = BAD[k % 7] if k % 5 == 0 else vx[k]
        y1 = BAD[(k // 3) % 7] if k % 3 == 0 else r[k]
        y2 = BAD[(k // 2) % 7] if k % 2 == 0 else ay[k]
        if k % 97 == 0:  # absurd but within the range check (15 m/s^2): a spike, gated
            y2 = float(rng.choice([-12.0, 12.0]))  # k = 0: before any good reading
        f.step(v, y1, y2)
        assert math.isfinite(f.swa_rad) and math.isfinite(f.side_slip_rad)
        assert math.isfinite(f.swa_std_rad) and np.all(np.isfinite(f.P))
    assert f.rejected_r > 0 and f.rejected_ay > 0 and f.rejected_vx > 0
    assert f.missing_r > 0 and f.missing_ay > 0 and f.missing_vx > 0
    assert f.gated_ay > 0  # spikes gated
    assert f.resets == 0
    # Still tracking: half the readings were bad, the error stays moderate.
    assert abs(f.swa_rad - tr.swa[-1]) < 5.0 * RAD_PER_DEG


def test_missing_readings_predict_only() -> None:
    f = SteeringUKF()
    f.step(25.0, 0.05, 1.0)
    tr0 = np.trace(f.P)
    for _ in range(50):
        f.step(None, None, None)
    assert f.missing_r == f.missing_ay == f.missing_vx == 50
    assert np.trace(f.P) > tr0 and np.all(np.isfinite(f.x))
    assert f.v_x == 25.0  # last good speed kept


def test_all_bad_from_the_start() -> None:
    for cls in (SteeringUKF, SteeringEKF):
        f = cls()
        for b in BAD * 30:
            f.step(b, b, b)
        assert np.all(np.isfinite(f.x)) and np.all(np.isfinite(f.P))


# --- smoothers ---------------------------------------------------------------------------------
def test_fixed_lag_equals_full_smoother_on_the_data_so_far(short_trace) -> None:
    """Fixed-lag output at step k == rts_smooth over steps 0..k at index k - lag (bit for bit:
    the same gain and backward-pass kernels, the window's gains kept as the rows arrive)."""
    tr = short_trace
    lag_s = 0.25
    fl = FixedLagSmoother(lag_s, SteeringUKF())
    ref = SteeringUKF(record=True)
    checks = 0
    for k, (v, r, a) in enumerate(zip(tr.meas_vx.tolist(), tr.meas_r.tolist(),
                                      tr.meas_ay.tolist())):
        le = fl.step(v, r, a)
        ref.step(v, r, a)
        if k < fl.lag:
            assert le is None
            continue
        assert le.step == k - fl.lag and le.t_s == pytest.approx(le.step * 0.01)
        if k % 400 == 0 or k == tr.t.size - 1:
            s = rts_smooth(ref.history(), covariance=False)
            np.testing.assert_array_equal(le.x, s.x[k - fl.lag])
            checks += 1
    assert checks >= 5
    tail = fl.flush()
    full = rts_smooth(ref.history(), covariance=False)
    assert [e.step for e in tail] == list(range(tr.t.size - fl.lag, tr.t.size))
    np.testing.assert_array_equal(np.array([e.x for e in tail]), full.x[-fl.lag:])


def test_fixed_lag_covering_the_run_is_the_full_smoother(short_trace) -> None:
    tr = short_trace
    n = tr.t.size
    fl = FixedLagSmoother(n * 0.01 + 1.0, SteeringUKF())
    ref = SteeringUKF(record=True)
    for v, r, a in zip(tr.meas_vx.tolist(), tr.meas_r.tolist(), tr.meas_ay.tolist()):
        assert fl.step(v, r, a) is None
        ref.step(v, r, a)
    out = fl.flush()
    assert [e.step for e in out] == list(range(n))
    full = rts_smooth(ref.history(), covariance=False)
    np.testing.assert_array_equal(np.array([e.x for e in out]), full.x)


def test_full_smoother_covariance_shrinks(short_trace) -> None:
    f = SteeringUKF(record=True)
    _feed(f, short_trace)
    run = f.history()
    s = rts_smooth(run)
    assert s.P is not None and np.all(np.isfinite(s.P))
    # Smoothed variances never exceed the filtered ones (up to rounding).
    d = np.diagonal(s.P, axis1=1, axis2=2) - np.diagonal(run.P, axis1=1, axis2=2)
    assert d.max() <= 1e-12
    np.testing.assert_allclose(s.x[-1], run.x[-1])


def test_ekf_run_smooths_too(short_trace) -> None:
    """The same backward pass on an EKF run (C = P F^T) is the extended RTS smoother."""
    f = SteeringEKF(record=True)
    _feed(f, short_trace)
    s = rts_smooth(f.history(), covariance=False)
    i_s = short_trace.params.steering_ratio
    e_f = np.sqrt(np.mean((f.history().x[:, 2] * i_s - short_trace.swa) ** 2))
    e_s = np.sqrt(np.mean((s.x[:, 2] * i_s - short_trace.swa) ** 2))
    assert e_s < e_f
