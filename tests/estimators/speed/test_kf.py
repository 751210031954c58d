"""Speed/acceleration filter (Hernández 2005 plant, 500 Hz): accuracy, robustness, determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vecu.estimators.speed.kf import SpeedKalmanFilter
from vecu.eval.speed import evaluate_speed, run_filter
from vecu.plant.longitudinal import MANOEUVRES, ManoeuvreConfig, simulate_speed
from vecu.units import MPS_PER_KMH


@pytest.fixture(scope="module")
def paper_report():
    return evaluate_speed(seed=1, runs=10, manoeuvre="paper")


# Measured (seed 1, 10 runs, paper manoeuvre): speed +23.1 dB (0.089 vs 1.28 km/h) at >= 5 km/h,
# +28.9 dB below 5 km/h, acceleration +6.8 dB (0.278 vs 0.608 m/s^2); seeds 101 / 1001 give
# +24.7 / +27.0 / +6.5 and +22.7 / +23.9 / +6.7. Targets of the issue: 15 / 15 / 6 dB.
def test_paper_manoeuvre_meets_targets(paper_report) -> None:
    r = paper_report
    assert r.speed_gain_high_db >= 15.0
    assert r.speed_gain_low_db >= 15.0
    assert r.speed_gain_low_moving_db >= 15.0  # standstill excluded: still >= 15 dB
    assert r.accel_gain_db >= 6.0
    assert r.resets == 0 and r.rejected == 0
    assert r.accel_rms_diff_wheel_mps2 > 100.0  # why the accelerometer is the baseline


@pytest.mark.parametrize("kind, hi, lo, acc", [
    # measured seed 1, 5 runs: gentle +24.1 / +25.7 / +9.9, abs +24.7 / +12.4 / +6.4,
    # launch_brake +7.4 / +22.5 / +9.2 (leaving standstill late is the weak case, docs/models.md)
    ("gentle", 20.0, 20.0, 8.0),
    ("abs", 20.0, 9.0, 5.0),
    ("launch_brake", 5.0, 18.0, 8.0),
])
def test_other_manoeuvres(kind: str, hi: float, lo: float, acc: float) -> None:
    r = evaluate_speed(seed=1, runs=5, manoeuvre=kind)
    assert r.speed_gain_high_db >= hi
    assert r.speed_gain_low_db >= lo
    assert r.accel_gain_db >= acc
    assert r.resets == 0


def _finite(f: SpeedKalmanFilter) -> bool:
    vals = (f.speed_mps, f.accel_mps2, f.offset_mps2, f.speed_std_mps, f.accel_std_mps2)
    return all(math.isfinite(x) for x in vals)


def test_never_nan_under_bad_input() -> None:
    f = SpeedKalmanFilter()
    bad = [float("nan"), float("inf"), -float("inf"), -5.0, 1e9, -1e9, 1e308, None]
    rng = np.random.default_rng(0)
    for k in range(5000):
        w = bad[k % len(bad)] if k % 3 else float(rng.uniform(0.0, 40.0))
        a = bad[(k // 2) % len(bad)] if k % 5 else float(rng.normal(0.0, 1.0))
        f.step(w, a)
        assert _finite(f)
        assert f.speed_mps >= 0.0
    assert f.rejected_wheel > 0 and f.rejected_accel > 0
    assert f.missing_wheel > 0 and f.missing_accel > 0


def test_missing_measurements_predict_only() -> None:
    tr = simulate_speed(3, ManoeuvreConfig("paper"))
    f = SpeedKalmanFilter()
    rng = np.random.default_rng(7)
    drop_w = rng.uniform(size=len(tr.t)) < 0.3  # 30 % of each input missing at random
    drop_a = rng.uniform(size=len(tr.t)) < 0.3
    err = []
    for k in range(len(tr.t)):
        f.step(None if drop_w[k] else float(tr.wheel[k]), None if drop_a[k] else float(tr.accel[k]))
        if tr.v[k] >= 5 * MPS_PER_KMH and k > 250:
            err.append(f.speed_mps - tr.v[k])
        assert _finite(f)
    assert math.sqrt(np.mean(np.square(err))) / MPS_PER_KMH < 0.3  # ~0.1 km/h with all inputs
    assert f.missing_wheel == int(drop_w.sum()) and f.missing_accel == int(drop_a.sum())


def test_wheel_glitch_is_gated_not_followed() -> None:
    tr = simulate_speed(4, ManoeuvreConfig("paper"))
    f = SpeedKalmanFilter()
    for k in range(600):
        w = 80.0 if 400 <= k < 405 else float(tr.wheel[k])  # 5 samples of 288 km/h
        f.step(w, float(tr.accel[k]))
    assert abs(f.speed_mps - tr.v[599]) < 0.5
    assert f.gated_wheel >= 5


def test_standstill_holds_zero_and_learns_offset() -> None:
    tr = simulate_speed(5, ManoeuvreConfig("paper", standstill_s=5.0))
    vh, ah, _, f = run_filter(tr)
    rest = tr.v == 0.0
    assert np.all(vh[rest][100:] == 0.0) and np.all(ah[rest][100:] == 0.0)
    assert f.standstill
    assert abs(f.offset_mps2 - tr.accel_offset) < 0.05


def test_deterministic_and_streams_independent() -> None:
    a = simulate_speed(11, ManoeuvreConfig("abs"))
    b = simulate_speed(11, ManoeuvreConfig("abs"))
    assert all(np.array_equal(getattr(a, n), getattr(b, n)) for n in ("v", "wheel", "accel"))
    va, aa, _, _ = run_filter(a)
    vb, ab, _, _ = run_filter(b)
    assert np.array_equal(va, vb) and np.array_equal(aa, ab)
    c = simulate_speed(12, ManoeuvreConfig("abs"))
    assert not np.array_equal(a.wheel, c.wheel)
    for kind in MANOEUVRES:  # every variant stops and ends at rest
        t = simulate_speed(2, ManoeuvreConfig(kind))
        assert t.v[-1] == 0.0 and np.all(t.v >= 0.0) and np.all(t.wheel >= 0.0)
